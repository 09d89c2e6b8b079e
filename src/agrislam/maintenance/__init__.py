"""Map maintenance (sec. 2.6.3): young objects confirmed from the frames that saw them
(existence.py), near objects merged (merger.py), rarely seen uncertain ones pruned
(pruning.py), all run by the maintenance stage (maintainer.py)."""

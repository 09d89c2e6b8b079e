"""A refine's whole history folded onto the live nodes at the batch solution
(incremental/refine.py): the record's factors among the live nodes stay as they are
(nonlinear), the rest is marginalised onto them exactly.

The marginal ties together every live node one eliminated node's factors reach: with
several robots sharing landmarks, every keyframe of every robot, in one dense factor that
iSAM2 then re-eliminates at every step. The caller can refuse such a fold
(`Refolded.widest`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam

from agrislam.backend.graph import SurveyGraph
from agrislam.backend.values import insert_value, value_array


@dataclass
class Refolded:
    """The live graph after a refine: its factors, the record's factor id of each (None:
    folded history), and the nodes the history folds onto."""

    graph: gtsam.NonlinearFactorGraph = field(default_factory=gtsam.NonlinearFactorGraph)
    fids: list[int | None] = field(default_factory=list)
    folded: list[int] = field(default_factory=list)
    widest: int = 0  # keys of the widest folded factor


def refold(
    record: SurveyGraph, built: gtsam.NonlinearFactorGraph, solution: gtsam.Values, live: set[int]
) -> Refolded:
    """`record`'s factors (`built`: each made once, in the record's order) folded onto
    the nodes `live` at `solution`."""
    out = Refolded()
    history = gtsam.NonlinearFactorGraph()
    gone: set[int] = set()
    for n, (fid, factor) in enumerate(record.factors.items()):
        if live.issuperset(factor.keys):
            out.fids.append(fid)
            out.graph.push_back(built.at(n))
        else:
            history.push_back(built.at(n))
            gone.update(k for k in factor.keys if k not in live)
    kept = gtsam.Values()
    for key in history.keyVector():
        if key not in gone:
            insert_value(kept, key, value_array(solution, key))
    _, remaining = history.linearize(solution).eliminatePartialMultifrontal(sorted(gone))
    folded = gtsam.LinearContainerFactor.ConvertLinearGraph(remaining, kept)
    out.widest = max((folded.at(n).size() for n in range(folded.size())), default=0)
    out.graph.push_back(folded)
    out.fids.extend([None] * folded.size())
    out.folded = list(folded.keyVector())
    return out

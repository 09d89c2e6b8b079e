"""Refine (part of `IncrementalBackend`, backend.py): the whole recorded graph solved again,
and the back end carried on from that solution, by one of three paths:

- the whole history solved in one batch and folded onto the keyframes again, exactly at
  the solution (refold.py);
- past a bound on the factors (a batch costs memory, and stalls the step it runs in), or
  a fold onto more keys than a bound, Gauss-Newton on the keyframe graph alone;
- with `slam.window = 0`, the batch solution handed to a fresh iSAM2 of every factor.

A refine starts by itself once a keyframe has turned `slam.refine_turn_deg` since history
was folded onto it (a loop closure): the folded factors are linear in its heading.
"""

from __future__ import annotations

import math
from collections import Counter

import gtsam
import numpy as np

from agrislam.backend.batch import solve
from agrislam.backend.graph import POSE, SurveyGraph, key_kind, make_factor
from agrislam.backend.incremental.isam_state import Entry, SlotTable, isam2
from agrislam.backend.incremental.marginal_cache import MarginalCache
from agrislam.backend.incremental.nodes import NodeTable
from agrislam.backend.incremental.refold import refold
from agrislam.backend.values import insert_value, value_array, values_at
from agrislam.config import SlamConfig

# a refine during the survey whose history would fold into a dense factor over more keys,
# or with several robots (the fold ties all their keyframes together), relinearises the
# keyframe graph instead: iSAM2 would re-eliminate that factor at every step after
REFOLD_MAX_KEYS = 100
# the factors a refine that a turn starts during the survey solves in one batch at most:
# beyond, it relinearises the keyframe graph and the full batch waits for the end
TURN_REFINE_MAX_FACTORS = 50_000


class Refining:
    """The whole record solved again; the three paths of the module docstring."""

    slam: SlamConfig
    graph: SurveyGraph
    issues: Counter[str]
    _nodes: NodeTable
    window: int
    refines: int
    whole_refine: int
    _isam: gtsam.ISAM2
    _slots: SlotTable
    _marginals: MarginalCache
    _folded_heading: dict[int, float]

    def refine(self, max_factors: int | None = None, max_keys: int = 0) -> None:
        """Solve the whole recorded graph (batch, warm-started from the current estimates)
        and carry on from that solution: with keyframes, the whole history is folded onto
        them again, exactly at the solution; with more than `max_factors` factors
        (`slam.refine_max_factors` by default), or a history that would fold into a factor
        over more than `max_keys` (if given), only the keyframe graph is relinearised."""
        self._solve_pending()
        if self.window:
            self._fold()  # the current window retires too: only keyframes and rows live
            limit = self.slam.refine_max_factors if max_factors is None else max_factors
            if len(self.graph.factors) > limit:
                self._refine_folded()
                return
        graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for factor in self.graph.factors.values():
            graph.push_back(make_factor(factor, self.slam))
            for key in factor.keys:
                if not initial.exists(key):
                    insert_value(initial, key, self.estimate(key))
        try:
            solution = solve(graph, initial, self.slam)
            fresh = isam2(self.slam)
            if not self.window:
                fresh.update(graph, solution)
            elif not self._refold(solution, fresh, graph, max_keys):
                self._refine_folded()
                return
        except RuntimeError as err:  # degenerate: carry on from the incremental estimate
            self.issues[f"refine skipped: {str(err).strip().splitlines()[0]}"] += 1
            return
        self._isam = fresh
        self._marginals.clear()
        self.refines += 1
        self.whole_refine = self.refines
        if not self.window:
            self._slots.reset(Entry(f.keys, fid) for fid, f in self.graph.factors.items())
            return
        self._nodes.moved_to(solution)

    def _refine_if_turned(self) -> None:
        """A refine once a keyframe has turned more than `slam.refine_turn_deg`; with
        several robots only of the keyframe graph (a refold would tie all their keyframes)."""
        if self.slam.refine_turn_deg and self._turned() > math.radians(self.slam.refine_turn_deg):
            alone = len(self.graph.robots) == 1
            self.refine(TURN_REFINE_MAX_FACTORS if alone else 0, REFOLD_MAX_KEYS)

    def _turned(self) -> float:
        """Largest heading change of a keyframe since history was folded onto it: the
        folded factors are linear in it, so past a few degrees they no longer hold."""
        keys = np.fromiter(self._folded_heading, dtype=np.uint64)
        headings = values_at(self._isam.calculateEstimate(), keys, 3)[:, 2]  # all at once
        folded = np.fromiter(self._folded_heading.values(), dtype=float)
        turned = np.remainder(headings - folded + np.pi, math.tau) - np.pi
        return float(np.max(np.abs(turned), initial=0.0))

    def _refine_folded(self) -> None:
        """A graph too large for one batch: Gauss-Newton on the keyframe graph the history
        is folded onto (bounded by the keyframes, not the plants); the headings the folded
        factors were linearised at are taken as they are now."""
        self._converge()
        self._marginals.clear()
        self._folded_heading = {k: self.estimate(k)[2] for k in self._folded_heading}
        self.refines += 1

    def _refold(
        self,
        solution: gtsam.Values,
        fresh: gtsam.ISAM2,
        graph: gtsam.NonlinearFactorGraph,
        max_keys: int = 0,
    ) -> bool:
        """Live graph (in `fresh`) = keyframes and rows with the whole history folded onto
        them at `solution` (refold.py); `graph` holds the record's factors, built once, in
        its order. False (nothing done) if a folded factor would have over `max_keys` keys."""
        out = refold(self.graph, graph, solution, self._nodes.kept())
        if max_keys and out.widest > max_keys:
            return False
        values = gtsam.Values()
        for key in self._nodes.live():
            insert_value(values, key, value_array(solution, key))
        fresh.update(out.graph, values)  # may raise: nothing of this back end has changed yet
        self._slots.reset(Entry(tuple(out.graph.at(n).keys()), f) for n, f in enumerate(out.fids))
        self._folded_heading = {
            k: solution.atPose2(k).theta() for k in out.folded if key_kind(k) == POSE
        }
        return True

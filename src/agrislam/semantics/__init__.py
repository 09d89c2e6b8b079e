"""Semantic beliefs of the map's objects (paper sec. 2.1, 2.3, 2.5, 2.7, App. B)."""

from agrislam.semantics.beliefs import BeliefInputError, BeliefTable, UpdateReport
from agrislam.semantics.continuous import entropy_normalised, kalman_update
from agrislam.semantics.discrete import bayes_update, kl_normalised
from agrislam.semantics.growth import transition_matrix
from agrislam.semantics.heuristic import InterestSurface, interest, interest_surface

__all__ = [
    "BeliefInputError",
    "BeliefTable",
    "InterestSurface",
    "UpdateReport",
    "bayes_update",
    "entropy_normalised",
    "interest",
    "interest_surface",
    "kalman_update",
    "kl_normalised",
    "transition_matrix",
]

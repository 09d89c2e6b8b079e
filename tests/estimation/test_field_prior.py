"""The field prior learned from a survey's first plants when its log gives none
(estimation/field_prior.py): rows and their spacing from plants in rows, nothing from
landmarks that are not, or too few to tell."""

from __future__ import annotations

import numpy as np
import pytest

from agrislam.estimation.field_prior import MIN_PLANTS, field_of

AMBIGUOUS = 0.5  # the row fit's first_fit_ambiguity


def rows(n_rows: int, per_row: int, spacing: float = 1.0, seed: int = 0) -> np.ndarray:
    """Plants along x, 0.4-0.5 m apart, on rows `spacing` apart, 1 cm off their rows."""
    rng = np.random.default_rng(seed)
    along = np.cumsum(rng.uniform(0.4, 0.5, (n_rows, per_row)), axis=1).ravel()
    across = np.repeat(np.arange(n_rows) * spacing, per_row)
    return np.column_stack([along, across]) + rng.normal(0.0, 0.01, (n_rows * per_row, 2))


@pytest.mark.parametrize("spacing", [0.75, 1.0, 1.5])
def test_plants_in_rows_give_the_rows_spacing_and_the_plants(spacing: float) -> None:
    prior = field_of(rows(3, 9, spacing), AMBIGUOUS)
    assert prior is not None
    assert prior.row_spacing == pytest.approx(spacing, rel=0.02)
    assert 0.38 < prior.min_plant_distance < 0.45
    assert prior.row_angle_deg is None  # the row fit finds it


def test_landmarks_not_in_rows_or_too_few_give_nothing() -> None:
    scattered = np.random.default_rng(1).uniform(0.0, 8.0, (40, 2))
    assert field_of(scattered, AMBIGUOUS) is None
    few = rows(2, MIN_PLANTS // 2 - 1)
    assert field_of(few, AMBIGUOUS) is None
    assert field_of(rows(2, MIN_PLANTS // 2), AMBIGUOUS) is not None

"""A field prior learned from a survey's first plants when its log gives none (no meta, or a
meta without `field`): if they stand in rows, the rows' spacing and the plants' spacing;
else nothing, and the survey is mapped as point landmarks (config/effective.py). A crop log
that lost its meta line is then mapped as the crop field it is, not as landmarks, whose
safeguards take a row shift for a lost robot rejoining the map."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from agrislam.estimation.rows import ambiguity, periodicity
from agrislam.geometry.noise import row_normal
from agrislam.records import FieldPrior

MIN_PLANTS = 20  # plants (seen twice) a decision needs: fewer lie on some lattice by chance
PERIODIC = 0.9  # the rows: every plant within about a sixth of the spacing of its row
SPACINGS = np.geomspace(0.25, 5.0, 121)  # m, rows' spacings tried
ANGLES = np.radians(np.arange(-90.0, 90.0, 1.0))
PLANTS_CLOSER = 1.5  # the plants of a row stand this much closer than the rows at least
PLANT_PERCENTILE = 10  # of the nearest-neighbour distances: the plants' least spacing


def field_of(plants: np.ndarray, ambiguous: float) -> FieldPrior | None:
    """The field prior of the plants (k, 2), or None if they are not in rows: periodic
    (PERIODIC) across one direction, rivalled by no other more than `ambiguous` (as the
    row fit's first fit), the largest such spacing (half of it is as periodic), and closer
    along the rows than across."""
    if len(plants) < MIN_PLANTS:
        return None
    periodic = np.stack([periodicity(plants, ANGLES, s) for s in SPACINGS])
    i, j = np.unravel_index(np.argmax(periodic), periodic.shape)
    if periodic[i, j] < PERIODIC:
        return None
    angle, spacing = float(ANGLES[j]), float(SPACINGS[i])
    while periodicity(plants, np.array([angle]), 2.0 * spacing)[0] >= PERIODIC:
        spacing *= 2.0  # every other row missed, or a harmonic
    if ambiguity(plants, angle, spacing) > ambiguous:
        return None
    spacing = _spacing(plants @ row_normal(angle), spacing)
    nearest = cKDTree(plants).query(plants, k=2)[0][:, 1]
    plant = float(np.percentile(nearest, PLANT_PERCENTILE))
    if plant * PLANTS_CLOSER > spacing:
        return None
    return FieldPrior(row_spacing=spacing, min_plant_distance=plant)


def _spacing(across: np.ndarray, spacing: float) -> float:
    """The rows' spacing refined by least squares: `across` (k,) the plants' positions
    across the rows, each on the row the coarse `spacing` puts it on."""
    for _ in range(2):
        row = np.round((across - across.min()) / spacing)
        if np.ptp(row) == 0:
            break
        design = np.column_stack([np.ones_like(row), row])
        spacing = float(np.linalg.lstsq(design, across, rcond=None)[0][1])
    return spacing

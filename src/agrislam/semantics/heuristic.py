"""Interest heuristic h (sec. 2.7, eq. 2) and the field interest surface."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import convolve1d
from scipy.special import expit

from agrislam.config import SemanticsConfig
from agrislam.semantics.discrete import kl_normalised

BLOCK_CELLS = 1 << 20  # cells the surface's blur convolves at a time


@dataclass(frozen=True, slots=True)
class InterestSurface:
    """h spread over a regular grid covering the field; cell (i, j) has its centre at
    (x0 + (j + 0.5) * resolution, y0 + (i + 0.5) * resolution)."""

    x0: float
    y0: float
    resolution: float
    values: np.ndarray  # (ny, nx), each in [0, 1]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax), as matplotlib's imshow takes it."""
        ny, nx = self.values.shape
        return (self.x0, self.x0 + nx * self.resolution, self.y0, self.y0 + ny * self.resolution)


def sigmoid(x: np.ndarray, alpha: float, beta: float) -> np.ndarray:
    """l(x) = 1 / (1 + e^{-alpha (x - beta)}) (sec. 2.7)."""
    return expit(alpha * (np.asarray(x, dtype=float) - beta))


def interest(
    n_meas: np.ndarray,
    discrete: Iterable[np.ndarray],
    continuous_entropy: Iterable[np.ndarray],
    config: SemanticsConfig,
) -> np.ndarray:
    """h per object (k,) from its measurement count, its discrete beliefs (each (k, n_i))
    and the normalised entropies H_N (each (k,)) of its continuous attributes."""
    n_meas = np.asarray(n_meas, dtype=float)
    certainty = np.zeros_like(n_meas)
    n_attributes = 0
    for belief in discrete:
        certainty += kl_normalised(belief)  # 1 - E_N = D_KLN
        n_attributes += 1
    for h_n in continuous_entropy:
        certainty += 1.0 - sigmoid(h_n, config.heuristic_alpha, config.heuristic_beta)  # 1 - l(H_N)
        n_attributes += 1
    # no attributes at all (pure geometric mapping): the probability term is 1
    certainty = certainty / n_attributes if n_attributes else np.ones_like(n_meas)
    # eq. (2): h = 1 - n/(n+1) * 1/N sum_i (1 - E_N,i)
    return 1.0 - n_meas / (n_meas + 1.0) * certainty


def _grid(
    xy: np.ndarray,
    bounds: tuple[float, float, float, float] | None,
    resolution: float,
    margin: float,
    max_cells: int,
) -> tuple[float, float, float, int, int]:
    """x0, y0, resolution, nx, ny of a grid over `bounds` (xmin, xmax, ymin, ymax), or over
    the objects plus a margin; the cells grow when the grid would exceed `max_cells`."""
    if bounds is None:
        if len(xy) == 0:
            raise ValueError("interest surface: no objects and no bounds, nothing to cover")
        x, y = xy[:, 0], xy[:, 1]
        xmin, xmax = x.min() - margin, x.max() + margin
        ymin, ymax = y.min() - margin, y.max() + margin
    else:
        xmin, xmax, ymin, ymax = (float(b) for b in bounds)
        if not (xmax > xmin and ymax > ymin):
            raise ValueError(f"interest surface: empty bounds {bounds!r}")
    width, height = xmax - xmin, ymax - ymin
    resolution = max(resolution, float(np.sqrt(width * height / max_cells)))
    nx, ny = max(1, int(np.ceil(width / resolution))), max(1, int(np.ceil(height / resolution)))
    return float(xmin), float(ymin), resolution, nx, ny


def _splat(
    col: np.ndarray, row: np.ndarray, weights: tuple[np.ndarray, ...], nx: int, ny: int
) -> list[np.ndarray]:
    """Point weights summed into their nearest cells of (ny, nx) float32 grids, one grid per
    weight array (a point moves at most half a cell, small against sigma); off-grid points
    drop. Summed over the occupied cells only: no float64 grid of the whole field."""
    c, r = np.rint(col).astype(np.int64), np.rint(row).astype(np.int64)
    on = (c >= 0) & (c < nx) & (r >= 0) & (r < ny)
    cells, point_cell = np.unique((r * nx + c)[on], return_inverse=True)
    grids = []
    for w in weights:
        grid = np.zeros((ny, nx), dtype=np.float32)
        grid.flat[cells] = np.bincount(point_cell, w[on], minlength=len(cells))
        grids.append(grid)
    return grids


def _gaussian_blur(grid: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Separable convolution of a sparse splat, in place and a block of lines at a time (a
    whole field's grid is never copied): along x only the rows holding a point, then y."""
    rows = np.flatnonzero(grid.any(axis=1))
    per = max(1, BLOCK_CELLS // grid.shape[1])
    for start in range(0, len(rows), per):
        block = rows[start : start + per]
        grid[block] = convolve1d(grid[block], kernel, axis=1, mode="constant")
    per = max(1, BLOCK_CELLS // grid.shape[0])
    for start in range(0, grid.shape[1], per):
        block = grid[:, start : start + per]
        block[...] = convolve1d(block, kernel, axis=0, mode="constant")
    return grid


def interest_surface(
    xy: np.ndarray,
    h: np.ndarray,
    config: SemanticsConfig,
    bounds: tuple[float, float, float, float] | None = None,
    max_cells: int = 20_000_000,
) -> InterestSurface:
    """h of k objects at `xy` (k, 2) spread over a grid covering the field.

    Object k weighs w_k(x) = exp(-|x - xy_k|^2 / (2 sigma^2)) at point x (sigma =
    config.surface_sigma). A cell reads

        v(x) = 1 - sum_k w_k (1 - h_k) / max(1, sum_k w_k),

    i.e. 1 ("unknown, worth a look") where no object is near, h_k on an isolated object,
    the w-weighted mean of h where objects crowd (sum_k w_k >= 1), and in between a blend
    of both; always in [0, 1]. The two sums are point splats (each object into its nearest
    cell) convolved with a separable Gaussian cut at 3 sigma: cost ~ cells x kernel width,
    nearly independent of k. Grid: `bounds` (xmin, xmax, ymin, ymax), objects outside left
    out, or the objects plus 3 sigma; cells of config.surface_resolution, coarsened if there
    would be more than `max_cells`. Values are float32.
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    h = np.asarray(h, dtype=float)
    if h.shape != (len(xy),):
        raise ValueError(f"interest surface: {len(xy)} positions but h of shape {h.shape}")
    sigma = config.surface_sigma
    x0, y0, res, nx, ny = _grid(xy, bounds, config.surface_resolution, 3.0 * sigma, max_cells)
    col, row = (xy[:, 0] - x0) / res - 0.5, (xy[:, 1] - y0) / res - 0.5  # cell-centre coords
    weight, knowledge = _splat(col, row, (np.ones(len(h)), 1.0 - h), nx, ny)
    s = sigma / res
    radius = max(1, int(np.ceil(3.0 * s)))
    kernel = np.exp(-0.5 * (np.arange(-radius, radius + 1) / s) ** 2).astype(np.float32)
    # the kernel's peak is 1 (not unit sum): a lone object on a cell centre has w = 1 there
    weight, knowledge = _gaussian_blur(weight, kernel), _gaussian_blur(knowledge, kernel)
    # v = 1 - knowledge / max(1, weight), in place: a whole field's grid is held twice, not 5x
    values = np.divide(knowledge, np.maximum(weight, 1.0, out=weight), out=knowledge)
    np.subtract(1.0, values, out=values)
    return InterestSurface(x0, y0, res, np.clip(values, 0.0, 1.0, out=values))

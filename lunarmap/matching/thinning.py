"""Thinning a pair's interest points to a spatially uniform set of a given size, before matching.

A full-size image holds hundreds of thousands of interest points (one or two per 32-pixel cell of a
52,224 x 5,064 LRO NAC image: about 500,000), far more than an adjustment needs to tie two images
together, and matching costs per point. :func:`thin_points` keeps at most ``max_points`` of them,
one per cell of a square grid over image 1 (the strongest), restricted to where image 2 can see
them, so that the kept points cover the overlap evenly:

1. the overlap: a coarse grid of square cells of image 1 (32 across its shorter side, at most 4,096) is
   predicted into image 2 at the prediction height; cells whose centre or a corner lands inside image
   2, and their neighbours (the overlap's edge runs through them), hold the candidates;
2. the cell size: the smallest of ``cell * 2^(k/2)`` (k = 0, 1, ...) whose occupied cells number at
   most ``max_points``; the grid is anchored at image 1's origin, so pairs of one image with similar
   overlaps choose the same cells and the same points, which become anchors of multi-image tracks.

Thinning happens before prediction and matching, so a pair's cost is that of ``max_points``
points whatever the image size.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidInputError

__all__ = ["thin_points", "overlap_cells"]

Array = NDArray[np.float64]
_GRID = 32


def overlap_cells(sensor1: Any, sensor2: Any, shape1: tuple[int, int], shape2: tuple[int, int],
                  height: float, grid: int = _GRID, max_cells: int = 4096) -> tuple[float, NDArray[np.bool_]]:
    """Cell size (pixels) and ``(rows, cols)`` mask of the square cells of image 1 that image 2 sees.

    Cells are ``1 / grid`` of image 1's shorter side (larger when that would make more than
    ``max_cells``), so a narrow overlap along a long image (LRO NAC-L and NAC-R side by side) still
    spans cells. A cell is in when its centre or a corner is predicted inside image 2 at ``height``
    metres; the mask is then dilated by one cell (the overlap's edge runs through the cells around it).
    """
    h1, w1 = shape1
    h2, w2 = shape2
    size = min(h1, w1) / float(grid)
    size = max(size, float(np.sqrt(h1 * w1 / max_cells)))
    rows, cols = max(1, int(np.ceil(h1 / size))), max(1, int(np.ceil(w1 / size)))
    # centre and the four corners of every cell (corners shared between neighbours)
    lc, sc = (np.arange(rows) + 0.5) * size, (np.arange(cols) + 0.5) * size
    le, se = np.arange(rows + 1) * size, np.arange(cols + 1) * size
    pts = [np.meshgrid(lc, sc, indexing="ij"), np.meshgrid(le, se, indexing="ij")]
    L = np.concatenate([np.minimum(p[0].ravel(), h1 - 0.5) for p in pts])
    S = np.concatenate([np.minimum(p[1].ravel(), w1 - 0.5) for p in pts])
    g = sensor1.image_to_ground(np.maximum(L, 0.5), np.maximum(S, 0.5), height=float(height), on_miss="nan")
    ok = np.all(np.isfinite(g), axis=1)
    inside = np.zeros(L.size, bool)
    if ok.any():
        l2, s2 = sensor2.ground_to_image(g[ok], on_miss="nan")
        l2, s2 = np.asarray(l2, float), np.asarray(s2, float)
        inside[ok] = np.isfinite(l2) & np.isfinite(s2) & (l2 >= 0) & (l2 <= h2) & (s2 >= 0) & (s2 <= w2)
    m = inside[:rows * cols].reshape(rows, cols)
    corner = inside[rows * cols:].reshape(rows + 1, cols + 1)
    m |= corner[:-1, :-1] | corner[1:, :-1] | corner[:-1, 1:] | corner[1:, 1:]
    grown = m.copy()
    grown[1:] |= m[:-1]
    grown[:-1] |= m[1:]
    grown[:, 1:] |= grown[:, :-1].copy()
    grown[:, :-1] |= grown[:, 1:].copy()
    return size, grown


def thin_points(line: Array, sample: Array, strength: Array, max_points: int, sensor1: Any = None,
                sensor2: Any = None, shape1: tuple[int, int] | None = None, shape2: tuple[int, int] | None = None,
                height: float = 0.0, cell: float = 32.0) -> NDArray[np.intp]:
    """Indices (ascending) of at most ``max_points`` points, one per grid cell, the strongest (module docstring).

    Parameters
    ----------
    line, sample, strength : ndarray (n,)
        Interest points of image 1 (pixels, CSM) and their strength (larger is better).
    max_points : int
        Most points to keep (>= 1).
    sensor1, sensor2, shape1, shape2 : optional
        Sensor models and ``(lines, samples)`` of both images: candidates are restricted to the cells
        of image 1 that image 2 sees (:func:`overlap_cells`). Without them every point is a candidate.
    height : float
        Prediction height of the overlap test, metres.
    cell : float
        Smallest grid cell, pixels (the detector's cell).

    Raises
    ------
    InvalidInputError
        ``max_points < 1`` or ``cell <= 0``.
    """
    if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)) or max_points < 1:
        raise InvalidInputError(f"max_points must be an integer >= 1, got {max_points!r}")
    if not (np.isfinite(cell) and cell > 0):
        raise InvalidInputError(f"thinning cell must be > 0 pixels, got {cell}")
    line = np.asarray(line, dtype=float)
    sample = np.asarray(sample, dtype=float)
    strength = np.asarray(strength, dtype=float)
    cand = np.flatnonzero(np.isfinite(line) & np.isfinite(sample))
    if sensor1 is not None and sensor2 is not None and shape1 is not None and shape2 is not None and cand.size:
        size, mask = overlap_cells(sensor1, sensor2, shape1, shape2, height)
        r = np.clip((line[cand] // size).astype(np.intp), 0, mask.shape[0] - 1)
        c = np.clip((sample[cand] // size).astype(np.intp), 0, mask.shape[1] - 1)
        cand = cand[mask[r, c]]
    if cand.size <= max_points:
        return cand
    # strongest first, so the first point of each cell in this order is the cell's strongest
    order = cand[np.lexsort((cand, -np.nan_to_num(strength[cand], nan=-np.inf)))]
    k = 0
    while True:
        size = cell * 2.0 ** (k / 2.0)
        r = (line[order] // size).astype(np.int64)
        c = (sample[order] // size).astype(np.int64)
        key = r * (int(1e9 // size) + 2) + c
        _, first = np.unique(key, return_index=True)
        if first.size <= max_points:
            return np.sort(order[first])
        k += 1

"""Image pyramids by 2 x 2 block averaging.

Level ``k`` has pixels ``2^k`` times larger; with the CSM convention a point at
``(line, sample)`` on level 0 sits at ``(line, sample) / 2^k`` on level ``k``
(pixel edges, not centres, line up). NaN pixels make their block NaN so that
invalid data stays flagged at every level.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidInputError

__all__ = ["build_pyramid", "downsample"]


def downsample(image: NDArray) -> NDArray[np.float64]:
    """One pyramid step: mean of 2 x 2 blocks (an odd last row/column is dropped)."""
    h, w = image.shape[0] // 2 * 2, image.shape[1] // 2 * 2
    if h < 2 or w < 2:
        raise InvalidInputError(f"image of shape {image.shape} is too small to downsample")
    a = np.asarray(image[:h, :w], dtype=float)
    return 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])


def build_pyramid(image: NDArray, levels: int) -> list[NDArray[np.float64]]:
    """``[level 0, level 1, ...]`` with ``levels`` reductions (stops early at images under 16 px)."""
    if levels < 0:
        raise InvalidInputError(f"pyramid levels must be >= 0, got {levels}")
    out = [np.asarray(image, dtype=float)]
    for _ in range(levels):
        if min(out[-1].shape[:2]) < 32:
            break
        out.append(downsample(out[-1]))
    return out

"""The 20 cubic terms of the RPC00B polynomial order and their derivatives.

The order is that of the NITF RPC00B tagged record extension, as used by
GDAL (``RPCComputeTerms`` in ``alg/gdal_rpc.cpp``) and by the LROC
multi-image study (``seeds/001``, Eq. 12, with X = longitude, Y = latitude,
Z = height, all normalised)::

    1, L, P, H, LP, LH, PH, L^2, P^2, H^2,
    PLH, L^3, LP^2, LH^2, L^2P, P^3, PH^2, L^2H, P^2H, H^3
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["N_TERMS", "TERM_NAMES", "rpc_terms", "rpc_term_gradients"]

#: Number of terms of one cubic RPC00B polynomial.
N_TERMS = 20
#: Names of the terms (L = normalised longitude, P = latitude, H = height).
TERM_NAMES = ("1", "L", "P", "H", "LP", "LH", "PH", "LL", "PP", "HH",
              "PLH", "LLL", "LPP", "LHH", "LLP", "PPP", "PHH", "LLH", "PPH", "HHH")


def rpc_terms(x: ArrayLike, y: ArrayLike, z: ArrayLike) -> NDArray[np.float64]:
    """The 20 RPC00B terms of normalised coordinates (Eq. 12 of ``seeds/001``).

    Parameters
    ----------
    x, y, z : array_like
        Normalised longitude, latitude and height (dimensionless), broadcast together.

    Returns
    -------
    ndarray, shape (..., 20)
    """
    x, y, z = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float),
                                  np.asarray(z, dtype=float))
    xx, yy, zz = x * x, y * y, z * z
    return np.stack([np.ones_like(x), x, y, z, x * y, x * z, y * z, xx, yy, zz,
                     x * y * z, xx * x, x * yy, x * zz, xx * y, yy * y, y * zz, xx * z, yy * z, zz * z],
                    axis=-1)


def rpc_term_gradients(x: ArrayLike, y: ArrayLike, z: ArrayLike) -> NDArray[np.float64]:
    """Partial derivatives of the 20 terms with respect to ``x``, ``y``, ``z``.

    Returns
    -------
    ndarray, shape (..., 3, 20)
        ``[..., k, j]`` is d(term j)/d(coordinate k), coordinates in the
        order (x = longitude, y = latitude, z = height), normalised.
    """
    x, y, z = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float),
                                  np.asarray(z, dtype=float))
    o, i = np.zeros_like(x), np.ones_like(x)
    dx = np.stack([o, i, o, o, y, z, o, 2 * x, o, o, y * z, 3 * x * x, y * y, z * z, 2 * x * y, o, o,
                   2 * x * z, o, o], axis=-1)
    dy = np.stack([o, o, i, o, x, o, z, o, 2 * y, o, x * z, o, 2 * x * y, o, x * x, 3 * y * y, z * z, o,
                   2 * y * z, o], axis=-1)
    dz = np.stack([o, o, o, i, o, x, y, o, o, 2 * z, x * y, o, o, 2 * x * z, o, o, 2 * y * z, x * x,
                   y * y, 3 * z * z], axis=-1)
    return np.stack([dx, dy, dz], axis=-2)

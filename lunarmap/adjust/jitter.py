"""The smoothness prior of line-scan jitter splines (issue 30, item 3): an observation group of its own.

Every line-scan image whose corrections carry a jitter spline
(:class:`~lunarmap.camera.corrections.LineScanCorrections` with ``jitter_lines``) gets, per attitude
axis, the second differences of its B-spline knot coefficients ``s = Q z`` (radians) as
pseudo-observations of zero:

    v_(j, axis) = (s_(j-1) - 2 s_j + s_(j+1)) / sigma,        j = 1 .. n_knots - 2

and, optionally, a weak zero prior ``z / zero_sigma`` on the spline parameters (``|s| = |z|``, ``Q``
being orthonormal). Second differences leave constant and linear knot sequences free; the
spline's parametrisation already removes the polynomial's degree (for degree >= 1 the second
differences then fix every spline parameter; for degree 0 the linear trend is left to the tie points
or to ``zero_sigma``).

``sigma`` is a prior on the jitter's spectrum at the knot spacing ``h`` (lines, time ``dt``): a
sinusoid of amplitude ``A`` and frequency ``f`` has second differences of amplitude
``A (2 - 2 cos(2 pi f dt))``; 2 urad at 5 Hz with knots every 100 NAC lines (34 ms) gives ~1.6 urad.
Smaller sigmas smooth the jitter out, larger ones let the spline follow the tie points' noise.

The rows form one observation group (``variance_group``: its own variance component in
:func:`~lunarmap.adjust.variance.observation_groups`, its residuals in the reports), named ``name``.
Nothing here calls SPICE.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from ..camera.corrections import LineScanCorrections
from ..errors import AdjustmentInputError

__all__ = ["JitterSmoothness", "JitterSpec"]


@dataclass(frozen=True)
class JitterSpec:
    """Jitter splines of a block's line-scan images (:func:`~lunarmap.adjust.build_block` ``jitter=``).

    Attributes
    ----------
    knot_lines : float
        Knot spacing, image lines (>= 1).
    sigma : float
        Smoothness prior: sigma of a second difference of knot coefficients, radians.
    zero_sigma : float or None
        Weak zero prior of the spline parameters, radians (None: none).
    images : sequence of str or None
        The images that get a spline (None: every line-scan image).
    """

    knot_lines: float
    sigma: float
    zero_sigma: float | None = None
    images: Sequence[str] | None = None


class JitterSmoothness:
    """Second differences of the jitter splines' knot coefficients as pseudo-observations (module docstring).

    A camera-level term of :class:`~lunarmap.adjust.problem.BundleProblem` (``terms=[...]``).

    Parameters
    ----------
    model : SensorImageModel
        The block's image model; its line-scan corrections with a jitter spline get rows.
    sigma : float
        Sigma of a second difference of knot coefficients, radians.
    zero_sigma : float, optional
        Sigma of a zero prior on every spline parameter, radians (``None``: none).
    name : str
        Observation-group name.

    Raises
    ------
    AdjustmentInputError
        Non-positive or non-finite sigmas, or no image with a jitter spline.
    """

    variance_group = True
    n_extra = 0

    def __init__(self, model: Any, sigma: float, zero_sigma: float | None = None,
                 name: str = "jitter smoothness") -> None:
        sigma = float(sigma)
        if not (np.isfinite(sigma) and sigma > 0):
            raise AdjustmentInputError(f"jitter smoothness sigma must be finite and > 0 radians, got {sigma!r}")
        if zero_sigma is not None:
            zero_sigma = float(zero_sigma)
            if not (np.isfinite(zero_sigma) and zero_sigma > 0):
                raise AdjustmentInputError(f"jitter zero-prior sigma must be finite and > 0 radians, got {zero_sigma!r}")
        self.sigma = sigma
        self.zero_sigma = zero_sigma
        self.name = str(name)
        p = int(model.n_params)
        self._n_img = int(model.n_images)
        rows: list[NDArray] = []
        cols: list[NDArray] = []
        vals: list[NDArray] = []
        image_of: list[NDArray] = []
        kind_of: list[NDArray] = []
        nrow = 0
        self.images = []
        for i, c in enumerate(model.corrections):
            if not isinstance(c, LineScanCorrections) or c.jitter_lines is None:
                continue
            self.images.append(i)
            K, m = c.n_knots, c.n_jitter
            D = np.diff(np.eye(K), n=2, axis=0)                      # (K - 2, K) second differences
            blocks = [(D @ c.jitter_projector) / sigma]              # (K - 2, m) on z of one axis
            kinds = [0]
            if zero_sigma is not None:
                blocks.append(np.eye(m) / zero_sigma)
                kinds.append(1)
            for B, kd in zip(blocks, kinds):
                r_loc, z_loc = np.nonzero(np.abs(B) > 0)
                for axis in range(3):
                    rows.append(nrow + r_loc)
                    cols.append(i * p + c.n_poly + 3 * z_loc + axis)
                    vals.append(B[r_loc, z_loc])
                    image_of.append(np.full(B.shape[0], i))
                    kind_of.append(np.full(B.shape[0], kd))
                    nrow += B.shape[0]
        if not self.images:
            raise AdjustmentInputError("jitter smoothness: no image of the model has a jitter spline")
        self.n_obs_scalar = nrow
        self._J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                shape=(nrow, self._n_img * p))
        self.row_image = np.concatenate(image_of)
        self.row_kind = np.concatenate(kind_of)      # 0 second difference, 1 zero prior

    def __repr__(self) -> str:
        return (f"JitterSmoothness({len(self.images)} images, sigma={self.sigma:g} rad, "
                f"zero_sigma={self.zero_sigma}, {self.n_obs_scalar} rows)")

    def initial_extra(self) -> NDArray[np.float64]:
        return np.zeros(0)

    def extra_free(self) -> NDArray[np.bool_]:
        return np.zeros(0, dtype=bool)

    def observed_images(self) -> NDArray[np.bool_]:
        seen = np.zeros(self._n_img, dtype=bool)
        seen[self.images] = True
        return seen

    def linearize(self, cam_params: NDArray, extra: NDArray) -> tuple[NDArray[np.float64], sp.csr_matrix]:
        """Whitened residuals ``(n_obs_scalar,)`` (second differences / sigma, zero-prior rows) and their Jacobian."""
        x = np.asarray(cam_params, dtype=float).ravel()
        return self._J @ x, self._J

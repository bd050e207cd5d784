"""RFM image model with a per-image affine correction in image space (LROC study, ``seeds/001``, Eq. 13).

Eq. 13 of the LROC multi-image study::

    F_r = p_r0 + p_r1 c' + p_r2 r' + r' - r = 0
    F_c = p_c0 + p_c1 c' + p_c2 r' + c' - c = 0

with ``(r, c)`` the measured (line, sample), ``(r', c') = RFM(lon, lat, h)`` the RFM
projection of the object point and ``p_r*, p_c*`` six affine parameters per image.  So the
predicted measurement is::

    line   = r' + a0 + a1 (c' - c_0) + a2 (r' - r_0)
    sample = c' + b0 + b1 (c' - c_0) + b2 (r' - r_0)

``(r_0, c_0)`` is the origin of the affine terms: ``(0, 0)`` reproduces Eq. 13 exactly
(``origin="image"``); ``origin="center"`` uses the RFM's ``LINE_OFF, SAMP_OFF`` (image
centre), the same affine family but with ``a0, b0`` decorrelated from the slopes, which is the
better-conditioned choice for long line-scan images.  Image parameters per image
``[a0, a1, a2, b0, b1, b2]``: ``a0, b0`` in pixels, the others dimensionless.

Object points are body-fixed ``(x, y, z)`` in metres; the RFM takes planetocentric
``(lon, lat, h)`` and the chain rule to ``xyz`` is analytic
(:meth:`lunarmap.rpc.RationalFunctionModel.jacobian_xyz`).  Image coordinates are
``(line, sample)`` in pixels, CSM convention (the RFM's).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from ..errors import AdjustmentInputError
from ..rpc.model import RationalFunctionModel

__all__ = ["AffineRFMModel", "apply_affine"]

PARAM_NAMES = ("a0", "a1", "a2", "b0", "b1", "b2")


def apply_affine(params: NDArray, rc: NDArray, origin: NDArray) -> NDArray:
    """Eq. 13 forward: ``(line, sample)`` pixels from RFM ``(r', c')`` ``(n, 2)`` and affine ``params (n, 6)``."""
    d = rc - origin
    line = rc[:, 0] + params[:, 0] + params[:, 1] * d[:, 1] + params[:, 2] * d[:, 0]
    samp = rc[:, 1] + params[:, 3] + params[:, 4] * d[:, 1] + params[:, 5] * d[:, 0]
    return np.column_stack([line, samp])


class AffineRFMModel:
    """Image model: one RFM per image plus six affine image-space parameters (Eq. 13 of ``seeds/001``).

    Parameters
    ----------
    rfms : sequence of RationalFunctionModel
        The RFM of every image (ground ``(lon, lat, h)`` -> ``(line, sample)`` pixels).
    origin : {"center", "image"}
        Origin ``(r_0, c_0)`` of the affine terms: the RFM's line/sample offsets, or
        ``(0, 0)`` (Eq. 13 literally).
    """

    n_params = 6
    param_names = PARAM_NAMES

    def __init__(self, rfms: Sequence[RationalFunctionModel], origin: str = "center"):
        self.rfms = list(rfms)
        if not self.rfms:
            raise AdjustmentInputError("AffineRFMModel needs at least one RFM")
        if origin not in ("center", "image"):
            raise AdjustmentInputError(f"origin must be 'center' or 'image', got {origin!r}")
        radii = {m.radius for m in self.rfms}
        if len(radii) != 1:
            # one object space: the xyz <-> (lon, lat, h) conversion must be the same for all images
            raise AdjustmentInputError(f"the RFMs use different reference radii {sorted(radii)} m")
        self.radius = radii.pop()
        self.origin_kind = origin
        self.origin = np.array([[m.offsets[0], m.offsets[1]] if origin == "center" else [0.0, 0.0]
                                for m in self.rfms])

    @property
    def n_images(self) -> int:
        return len(self.rfms)

    def initial_params(self) -> NDArray[np.float64]:
        """Zero corrections ``(n_img, 6)``: the RFMs as given."""
        return np.zeros((self.n_images, 6))

    def _rfm(self, cam_idx: NDArray, X: NDArray, with_jacobian: bool):
        cam_idx = np.asarray(cam_idx, dtype=np.int64)
        rc = np.empty((cam_idx.size, 2))
        J = np.empty((cam_idx.size, 2, 3)) if with_jacobian else None
        # one RFM per image: evaluate image by image (few images, many points)
        for i in np.unique(cam_idx):
            m = cam_idx == i
            if with_jacobian:
                li, sa, jac = self.rfms[i].jacobian_xyz(X[m])
                J[m] = jac
            else:
                li, sa = self.rfms[i].ground_to_image_xyz(X[m])
            rc[m, 0] = li
            rc[m, 1] = sa
        return rc, J

    def project(self, params: NDArray, cam_idx: NDArray, X: NDArray) -> NDArray[np.float64]:
        """Predicted ``(line, sample)`` pixels ``(n, 2)`` of points ``X (n, 3)`` (metres) in images ``cam_idx``."""
        rc, _ = self._rfm(cam_idx, X, False)
        return apply_affine(params[cam_idx], rc, self.origin[cam_idx])

    def linearize(self, params: NDArray, cam_idx: NDArray, X: NDArray):
        """Predicted pixels ``(n, 2)``, ``d/d params (n, 2, 6)`` and ``d/d X (n, 2, 3)`` (pixels per metre)."""
        cam_idx = np.asarray(cam_idx, dtype=np.int64)
        rc, Jrc = self._rfm(cam_idx, X, True)
        p = params[cam_idx]
        x = apply_affine(p, rc, self.origin[cam_idx])
        d = rc - self.origin[cam_idx]
        n = cam_idx.size
        Jc = np.zeros((n, 2, 6))
        Jc[:, 0, 0] = 1.0
        Jc[:, 0, 1] = d[:, 1]
        Jc[:, 0, 2] = d[:, 0]
        Jc[:, 1, 3] = 1.0
        Jc[:, 1, 4] = d[:, 1]
        Jc[:, 1, 5] = d[:, 0]
        # d(line, sample)/d(r', c') = [[1 + a2, a1], [b2, 1 + b1]]
        A = np.empty((n, 2, 2))
        A[:, 0, 0] = 1.0 + p[:, 2]
        A[:, 0, 1] = p[:, 1]
        A[:, 1, 0] = p[:, 5]
        A[:, 1, 1] = 1.0 + p[:, 4]
        Jp = np.einsum("nij,njk->nik", A, Jrc)
        return x, Jc, Jp

    def initial_points(self, params: NDArray, cam_idx: NDArray, pt_idx: NDArray, xy: NDArray, n_pt: int,
                       height: float = 0.0) -> NDArray[np.float64]:
        """Start values of the points (metres): the mean of the monoplotted rays at ``height`` metres.

        Each measurement, with the current affine correction removed to first order, is projected
        to the sphere of radius ``radius + height`` through its image's RFM; the points are then
        refined by :func:`lunarmap.adjust.intersection.intersect_points`.
        """
        cam_idx = np.asarray(cam_idx, np.int64)
        pt_idx = np.asarray(pt_idx, np.int64)
        xyz = np.empty((cam_idx.size, 3))
        for i in np.unique(cam_idx):
            m = cam_idx == i
            a = params[i]
            o = self.origin[i]
            # invert line = r' + a0 + a1 (c'-c0) + a2 (r'-r0) (same for sample): a 2x2 linear system
            M = np.array([[1.0 + a[2], a[1]], [a[5], 1.0 + a[4]]])
            rhs = xy[m] - a[[0, 3]] + np.array([a[2] * o[0] + a[1] * o[1], a[5] * o[0] + a[4] * o[1]])
            rc = np.linalg.solve(M, rhs.T).T
            xyz[m] = self.rfms[i].image_to_ground_xyz(rc[:, 0], rc[:, 1], height)
        cnt = np.bincount(pt_idx, minlength=n_pt).astype(float)
        out = np.column_stack([np.bincount(pt_idx, weights=xyz[:, k], minlength=n_pt) for k in range(3)])
        return out / np.maximum(cnt, 1.0)[:, None]

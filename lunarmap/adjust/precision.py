"""Posterior precision of an adjusted block: covariances of images, points and extra parameters,
redundancy numbers of the image observations.

With the reduced camera system ``S = U - W V^-1 W^T`` at the solution (undamped) and
``Q_cc = S^-1``, the cofactor blocks follow from the Schur complement (the inverse of
the normal matrix of the DLR paper's Eq. 4, block-wise)::

    Q_pp,j    = V_j^-1 + sum_{a,b in track j} F_a^T Q_{c_a c_b} F_b,     F_i = W_i V_j^-1
    Q_c,j     = -sum_{b in track j} Q_{c c_b} F_b

and covariances are ``sigma0^2 Q``. ``Q_cc`` is formed densely by LAPACK (``potrf`` +
``potri``): one O(n^3) step on the 6 n_img (+ extra) reduced unknowns; every other block is
gathered from it with index arrays over the observation pairs of each point.

Redundancy numbers (``r_i = 1 - (A Q A^T P)_ii``, for data snooping and variance-component
estimation) are computed per image coordinate with ``redundancy=True``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from numpy.typing import NDArray

from ..errors import DatumDefectError
from .schur import inv_sym3

__all__ = ["Precision", "posterior_precision", "ordered_track_pairs"]


@dataclass
class Precision:
    """Posterior covariances (units of the parameters squared), scaled by ``sigma0**2``.

    Attributes
    ----------
    cam_cov : (n_img, p, p)
    pt_cov : (n_pt, 3, 3)  (zero for fixed points)
    extra_cov : (n_extra, n_extra)
    Q_red : (n_red, n_red) cofactor matrix of the reduced unknowns (free ones; unscaled)
    redundancy_numbers : (n_obs, 2) or None
    sigma0 : float
    method : str
    """

    cam_cov: NDArray
    pt_cov: NDArray
    extra_cov: NDArray
    Q_red: NDArray
    redundancy_numbers: NDArray | None
    sigma0: float
    method: str


def ordered_track_pairs(pt_idx: NDArray, n_pt: int, active=None):
    """All ordered observation pairs ``(a, b)`` of the same point (including ``a == b``)."""
    order = np.argsort(pt_idx, kind="stable")
    s = pt_idx[order]
    starts = np.searchsorted(s, np.arange(n_pt))
    track = np.bincount(pt_idx, minlength=n_pt)
    if active is not None:
        track = np.where(active, track, 0)
    pos = np.arange(pt_idx.size) - starts[s]
    k = track[s]
    A, B = [], []
    for d in range(-int(track.max(initial=1)) + 1, int(track.max(initial=1))):
        ok = (pos + d >= 0) & (pos + d < k)
        i = np.nonzero(ok)[0]
        A.append(order[i])
        B.append(order[i + d])
    return np.concatenate(A), np.concatenate(B)


def posterior_precision(result, method: str = "auto", redundancy: bool = False,
                        scale_by_sigma0: bool = True) -> Precision:
    """Covariances of all adjusted parameters of ``result`` (an ``AdjustmentResult``).

    Parameters
    ----------
    redundancy : bool
        Also compute the redundancy numbers of the image observations.
    scale_by_sigma0 : bool
        Scale cofactors by the a-posteriori ``sigma0**2`` (else by 1, a-priori).

    Raises
    ------
    DatumDefectError
        If the normal equations at the solution are singular.
    """
    from .solver import _Terms, linearize, reduced_system

    pb = result.problem
    st = result.structure
    p = st.p
    terms = _Terms(pb)
    fixed_pt = pb.point_fixed()
    lin = linearize(pb, result.state, st, terms, fixed_pt)
    S, _, Vinv, _ = reduced_system(lin, st, terms, 0.0, result.free_red)
    F = np.matmul(lin.W, Vinv[pb.obs.pt_idx])
    # Jacobi scaling keeps the dense factorisation well conditioned (metres vs radians)
    Sd = S.toarray()
    d = 1.0 / np.sqrt(np.diag(Sd))
    Sd *= d[:, None]
    Sd *= d[None, :]
    c, info = sla.lapack.dpotrf(Sd, lower=True, overwrite_a=True, clean=False)
    if info != 0:
        raise DatumDefectError(f"the normal matrix at the solution is not positive definite (LAPACK info {info})")
    Qs, info = sla.lapack.dpotri(c, lower=True, overwrite_c=True)
    if info != 0:
        raise DatumDefectError(f"inverting the normal matrix failed (LAPACK info {info})")
    il = np.tril_indices_from(Qs, -1)
    Qs[il[::-1]] = Qs[il]  # mirror lower -> upper
    Qs *= d[:, None]
    Qs *= d[None, :]
    n_red = result.free_red.size
    Q = np.zeros((n_red, n_red))
    fi = np.nonzero(result.free_red)[0]
    if fi.size == n_red:
        Q = Qs
    else:
        Q[np.ix_(fi, fi)] = Qs
    s2 = result.sigma0 ** 2 if scale_by_sigma0 else 1.0
    n_cam_red = terms.n_cam_red
    idx = np.arange(n_cam_red).reshape(-1, p)
    cam_cov = Q[idx[:, :, None], idx[:, None, :]] * s2
    extra_cov = Q[n_cam_red:, n_cam_red:] * s2

    o = pb.obs
    a, b = ordered_track_pairs(o.pt_idx, pb.n_points, active=~fixed_pt)
    ca, cb = o.cam_idx[a], o.cam_idx[b]
    ia = idx[ca]
    ib = idx[cb]
    Qab = Q[ia[:, :, None], ib[:, None, :]]                       # (P, p, p)
    QFb = np.matmul(Qab, F[b])                                     # Q_{ca cb} F_b, (P, p, 3)
    FtQF = np.matmul(F[a].transpose(0, 2, 1), QFb)                 # (P, 3, 3)
    pt_q = Vinv.copy()
    np.add.at(pt_q, o.pt_idx[a], FtQF)
    pt_q[fixed_pt] = 0.0
    pt_cov = pt_q * s2
    red = None
    if redundancy:
        # Q_c,j for each observation a: -sum_b Q_{ca cb} F_b
        Qcp = np.zeros((o.n, p, 3))
        np.add.at(Qcp, a, -QFb)
        Qcc_i = Q[idx[o.cam_idx][:, :, None], idx[o.cam_idx][:, None, :]]
        Ac, Ap = lin.Ac, lin.Ap
        var = (np.einsum("nki,nij,nkj->nk", Ac, Qcc_i, Ac)
               + 2.0 * np.einsum("nki,nij,nkj->nk", Ac, Qcp, Ap)
               + np.einsum("nki,nij,nkj->nk", Ap, pt_q[o.pt_idx], Ap))
        red = 1.0 - var  # A is whitened, so (A Q A^T P)_ii = var
    return Precision(cam_cov, pt_cov, extra_cov, Q, red, result.sigma0, "dense-lapack")

"""Theoretical precision of a stereo pair (the study's Eq. 15) and the matching error it needs.

Eq. 15 of the LROC multi-image study (``seeds/001``, after Wang 1990, Fig. 8) is garbled in the
extracted text; it is reconstructed here from its stated assumptions: a symmetric convergent pair
(both looking angles ``theta`` = half the convergence angle, on opposite sides of nadir, the
baseline across track), flying height ``H`` over flat ground, image measurement errors
``sigma_x`` (across track, the baseline direction) and ``sigma_y`` (along track) in pixels of
angular size ``1 / f`` (``f`` the focal length in pixels). Each ray's error perpendicular to
itself is ``(H / cos(theta)) sigma / f``; intersecting two such rays at ``+-theta`` gives::

    sigma_X = H sigma_x / (sqrt(2) f cos^2(theta))                 cross track
    sigma_Y = H sigma_y / (sqrt(2) f cos(theta))                   along track (frame camera)
    sigma_Z = H sigma_x / (sqrt(2) f sin(theta) cos(theta))        height
            = sqrt(2) (H / B) (H / f) sigma_x / cos^2(theta),  B = 2 H tan(theta)
    sigma_T = sqrt(sigma_X^2 + sigma_Y^2 + sigma_Z^2)

which reduce to the normal case (``sigma_Z = sqrt(2) (H/B)(H/f) sigma_x``) as ``theta -> 0``. For a
push-broom camera the along-track pixel is set by the scan (ground speed x line time), not by the
look angle, so ``sigma_Y = p sigma_y / sqrt(2)`` with ``p`` the along-track ground pixel (``H / f``
for square pixels at nadir; ``along="linescan"``).

With a constant matching error ``sigma_Z`` falls as ``1 / sin(2 theta)`` (a power of the
convergence) and ``sigma_T`` turns at a convergence of about 70 degrees; with the matching error
growing linearly with the convergence (the study's Fig. 7, :class:`MatchingErrorModel`) the turn
moves to smaller angles (the study's Fig. 9).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..errors import EvaluationInputError

__all__ = ["eq15_precision", "pair_precision", "MatchingErrorModel", "fit_matching_error", "simulate_matching_errors",
           "NAC_MATCHING_ERROR"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class MatchingErrorModel:
    """Matching error of a stereo pair as a linear function of its convergence angle (the study's Fig. 7).

    ``rms(c) = intercept + slope * c`` pixels (RMS of the 2-D matching error of the pair, ``c`` in
    degrees). Per coordinate the error is ``rms / sqrt(2)``; split over the two images of a pair
    it is ``rms / 2`` per image and coordinate.
    """

    intercept: float
    slope: float

    def rms(self, convergence_deg: ArrayLike) -> Array:
        """2-D RMS matching error of a pair, pixels."""
        return self.intercept + self.slope * np.asarray(convergence_deg, float)

    def per_coordinate(self, convergence_deg: ArrayLike) -> Array:
        """RMS matching error of one image coordinate of the pair's conjugate, pixels."""
        return self.rms(convergence_deg) / np.sqrt(2.0)

    def per_image(self, convergence_deg: ArrayLike) -> Array:
        """Sigma of one coordinate in one image when the pair's error is shared by both images, pixels."""
        return self.rms(convergence_deg) / 2.0

    def per_image_emission(self, emission_deg: ArrayLike) -> Array:
        """Sigma of one coordinate of an image matched against a nadir reference (e.g. an orthoimage), pixels.

        The image and the reference converge by the image's emission angle ``e``; a symmetric pair
        at convergence ``2 e`` is two such images, so this is :meth:`per_image` at ``2 e``.
        """
        return self.per_image(2.0 * np.asarray(emission_deg, float))


#: Linear fit of the NAC-like line-scan matching errors of ``bench/matching_convergence_table.py``
#: (README, issue 4: 0.034 px at 0 degrees to 0.257 px at 50 degrees, noise sigma 2 grey levels).
NAC_MATCHING_ERROR = MatchingErrorModel(intercept=0.0257, slope=0.00425)


def fit_matching_error(convergence_deg: ArrayLike, rms_px: ArrayLike, weights: ArrayLike | None = None) -> MatchingErrorModel:
    """Least-squares line through matching errors (pixels) against convergence (degrees)."""
    c = np.asarray(convergence_deg, float).ravel()
    r = np.asarray(rms_px, float).ravel()
    ok = np.isfinite(c) & np.isfinite(r)
    if ok.sum() < 2 or np.ptp(c[ok]) == 0:
        raise EvaluationInputError("fitting the matching error needs two or more distinct convergence angles")
    w = np.ones_like(c) if weights is None else np.asarray(weights, float).ravel()
    A = np.column_stack([np.ones(int(ok.sum())), c[ok]]) * np.sqrt(w[ok])[:, None]
    sol = np.linalg.lstsq(A, r[ok] * np.sqrt(w[ok]), rcond=None)[0]
    return MatchingErrorModel(float(sol[0]), float(sol[1]))


def eq15_precision(convergence_deg: ArrayLike, height_m: float, focal_px: float,
                   sigma_px: float | MatchingErrorModel = 0.3, sigma_along_px: float | None = None,
                   along: str = "frame", along_pixel_m: float | None = None) -> xr.Dataset:
    """Standard deviations of a point intersected from a symmetric convergent pair (Eq. 15, module docstring).

    Parameters
    ----------
    convergence_deg : array_like
        Convergence angles, degrees (``theta`` = half of it).
    height_m : float
        Flying height ``H``, metres.
    focal_px : float
        Focal length in pixels (focal length / pixel pitch).
    sigma_px : float or MatchingErrorModel
        Image measurement error across track, pixels; a :class:`MatchingErrorModel` gives it as a
        function of the convergence (its :meth:`~MatchingErrorModel.per_coordinate` value).
    sigma_along_px : float, optional
        Along-track error, pixels (default: the same as across track).
    along : {"frame", "linescan"}
        Along-track pixel of a frame camera (grows with ``1 / cos(theta)``) or of a push-broom.
    along_pixel_m : float, optional
        Along-track ground pixel of a push-broom, metres (ground speed x line time); default
        ``H / f`` (square pixels at nadir).

    Returns
    -------
    xarray.Dataset
        Over ``convergence`` (degrees): ``sigma_x`` (cross track), ``sigma_y`` (along track),
        ``sigma_z`` (height), ``sigma_t`` (overall), metres; ``sigma_image`` pixels; ``base_height`` (B/H).
    """
    if along not in ("frame", "linescan"):
        raise EvaluationInputError(f"along must be 'frame' or 'linescan', got {along!r}")
    c = np.atleast_1d(np.asarray(convergence_deg, float))
    if np.any(~np.isfinite(c)) or np.any(c <= 0) or np.any(c >= 180):
        raise EvaluationInputError("convergence angles must be in (0, 180) degrees")
    if not (np.isfinite(height_m) and height_m > 0 and np.isfinite(focal_px) and focal_px > 0):
        raise EvaluationInputError("height and focal length must be finite and positive")
    th = np.radians(c / 2.0)
    sx = sigma_px.per_coordinate(c) if isinstance(sigma_px, MatchingErrorModel) else np.full_like(c, float(sigma_px))
    sy = sx if sigma_along_px is None else np.full_like(c, float(sigma_along_px))
    k = height_m / (np.sqrt(2.0) * focal_px)
    sig_x = k * sx / np.cos(th) ** 2
    if along == "frame":
        sig_y = k * sy / np.cos(th)
    else:
        sig_y = (k if along_pixel_m is None else float(along_pixel_m) / np.sqrt(2.0)) * sy
    sig_z = k * sx / (np.sin(th) * np.cos(th))
    sig_t = np.sqrt(sig_x ** 2 + sig_y ** 2 + sig_z ** 2)
    return xr.Dataset({"sigma_x": ("convergence", sig_x, {"units": "m", "long_name": "cross-track"}),
                       "sigma_y": ("convergence", sig_y, {"units": "m", "long_name": "along-track"}),
                       "sigma_z": ("convergence", sig_z, {"units": "m", "long_name": "height"}),
                       "sigma_t": ("convergence", sig_t, {"units": "m", "long_name": "overall"}),
                       "sigma_image": ("convergence", sx, {"units": "pixel"}),
                       "base_height": ("convergence", 2.0 * np.tan(th))},
                      coords={"convergence": ("convergence", c, {"units": "degree"})},
                      attrs={"height_m": float(height_m), "focal_px": float(focal_px), "along": along,
                             "source": "lunarmap.evaluate.eq15_precision (seeds/001 Eq. 15, reconstructed)"})


def simulate_matching_errors(convergence_deg: Sequence[float], kind: str = "linescan", size: int = 200,
                             noise: float = 2.0, seed: int = 1, supersample: int = 2,
                             scheduler: Any = "sync") -> xr.Dataset:
    """Matching error against truth of rendered symmetric pairs (the study's section 3.4, Fig. 7).

    For each convergence a symmetric pair (:func:`~lunarmap.simulate.stereo_pair`) is rendered from
    one synthetic DTM + albedo with independent Gaussian noise; Foerstner points of image 1 are
    matched into image 2 (prediction at height 0, pyramid NCC, least-squares matching, RANSAC) and
    compared with their true conjugates.

    Parameters
    ----------
    convergence_deg : sequence of float
    kind : {"linescan", "frame"}
        NAC-like line scanner (0.5 m pixels at 50 km) or Clementine-like frame (12.8 m).
    size : int
        Line-scan image size, pixels (the frame camera is 384 x 288).
    noise : float
        Grey levels.
    seed : int
    supersample : int
        Rays per pixel along each axis when rendering.
    scheduler : str
        Dask scheduler for the renders.

    Returns
    -------
    xarray.Dataset
        Over ``convergence``: ``rms`` (2-D), ``rms_line``, ``rms_sample`` pixels, ``matches``,
        ``correlation`` (median LSM correlation).
    """
    from ..camera.intersect import DtmSampler
    from ..matching import MatchParams, TiePointParams, foerstner, match_pair
    from ..matching.predict import predict_conjugates
    from ..simulate import matching_errors, render_image, stereo_pair, synthetic_scene

    gsd = {"linescan": 0.5, "frame": 12.8}.get(kind)
    if gsd is None:
        raise EvaluationInputError(f"kind must be 'linescan' or 'frame', got {kind!r}")
    rows = []
    for conv in convergence_deg:
        kw: dict[str, Any] = dict(n_lines=size, n_samples=size) if kind == "linescan" else {}
        cam1, cam2 = stereo_pair(kind, float(conv), **kw)   # type: ignore[arg-type]
        extent = 1.6 * max(cam1.n_lines, cam1.n_samples) * gsd
        dtm, alb = synthetic_scene(30.0, 0.0, extent, gsd, seed=seed)
        img1 = render_image(cam1, dtm, alb, noise_sigma=noise, sun="eo", seed=2 * seed + 1,
                            supersample=supersample).compute(scheduler=scheduler).values
        img2 = render_image(cam2, dtm, alb, noise_sigma=noise, sun="eo", seed=2 * seed + 2,
                            supersample=supersample).compute(scheduler=scheduler).values
        pts = foerstner(img1, cell=16, per_cell=1)
        e = predict_conjugates(cam1, cam2, [img1.shape[0] / 2], [img1.shape[1] / 2], 0.0).epipolar[0]
        search = float(np.hypot(*e) * np.nanmax(np.abs(dtm.values)) + 4.0)
        m = match_pair(img1, img2, cam1, cam2, pts, 0.0, TiePointParams(match=MatchParams(search=search)),
                       f"{kind} {conv} deg")
        ok = m.ok
        dl, ds = matching_errors(cam1, cam2, m.line1[ok], m.sample1[ok], m.line2[ok], m.sample2[ok], DtmSampler(dtm))
        corr = getattr(m, "correlation", None)
        rows.append((float(np.sqrt(np.mean(dl ** 2 + ds ** 2))), float(np.sqrt(np.mean(dl ** 2))),
                     float(np.sqrt(np.mean(ds ** 2))), int(ok.sum()),
                     float(np.median(np.asarray(corr)[ok])) if corr is not None and ok.any() else float("nan")))
    a = np.array(rows, float).reshape(-1, 5)
    return xr.Dataset({"rms": ("convergence", a[:, 0], {"units": "pixel"}),
                       "rms_line": ("convergence", a[:, 1], {"units": "pixel"}),
                       "rms_sample": ("convergence", a[:, 2], {"units": "pixel"}),
                       "matches": ("convergence", a[:, 3].astype(int)),
                       "correlation": ("convergence", a[:, 4])},
                      coords={"convergence": ("convergence", np.asarray(convergence_deg, float), {"units": "degree"})},
                      attrs={"kind": kind, "noise_sigma": float(noise), "size": int(size), "seed": int(seed)})


def pair_precision(convergence_deg: Sequence[float], kind: str = "frame", sigma_px: float | MatchingErrorModel = 0.3,
                   altitude: float = 50e3, n_lines: int = 512, n_samples: int = 512) -> xr.Dataset:
    """Eq. 15 beside the adjustment's propagated precision of the same symmetric pairs.

    For each convergence a symmetric pair (:func:`~lunarmap.simulate.stereo_pair`) sees the point
    at the image centres; the point's covariance is propagated from the image measurement sigma
    through the rigorous cameras by the adjustment's forward intersection
    (:func:`~lunarmap.adjust.intersect_points`, ``N^-1``), and rotated to cross-track, along-track
    and height. Eq. 15 is evaluated with the same flying height and focal length (and, for the
    push-broom, its along-track ground pixel).

    Parameters
    ----------
    convergence_deg : sequence of float
    kind : {"frame", "linescan"}
        Clementine-like frame camera (f = 3907 px) or NAC-like push-broom (f = 99,946 px).
    sigma_px : float or MatchingErrorModel
        Measurement sigma per image coordinate, pixels (a model: its per-coordinate value at
        each convergence, in both images).
    altitude : float
        Metres.
    n_lines, n_samples : int
        Push-broom image size.

    Returns
    -------
    xarray.Dataset
        Over ``convergence``: ``eq15_x``, ``eq15_y``, ``eq15_z``, ``eq15_t`` and ``adjust_x``,
        ``adjust_y``, ``adjust_z``, ``adjust_t`` (metres; x cross-track, y along-track, z height) and
        ``ratio_*`` = adjust / Eq. 15.
    """
    from ..adjust.intersection import intersect_points
    from ..adjust.sensors import SensorImageModel
    from ..simulate import stereo_pair
    from .checkpoints import along_track_azimuth, track_basis

    if kind not in ("frame", "linescan"):
        raise EvaluationInputError(f"kind must be 'frame' or 'linescan', got {kind!r}")
    conv = np.asarray(convergence_deg, float)
    rows, pixels = [], []
    focal_px = float("nan")
    for c in conv:
        kw: dict[str, Any] = dict(altitude=altitude)
        if kind == "linescan":
            kw.update(n_lines=n_lines, n_samples=n_samples)
        cams = stereo_pair(kind, float(c), **kw)   # type: ignore[arg-type]
        io = cams[0].interior
        focal_px = io.focal_length / io.pixel_pitch
        P = cams[0].image_to_ground(io.n_lines / 2.0, io.n_samples / 2.0, height=0.0)
        model = SensorImageModel(list(cams), degree=0)
        xy = np.array([np.ravel(cam.ground_to_image(P)) for cam in cams])
        s = float(sigma_px.per_coordinate(c)) if isinstance(sigma_px, MatchingErrorModel) else float(sigma_px)
        res = intersect_points(model, model.initial_params(), np.array([0, 1]), np.array([0, 0]), xy, s, n_pt=1)
        if kind == "linescan":
            from .geometry import view_geometry

            pixels.append(float(view_geometry(cams[0], P).pixel_height))
        T = track_basis(P, along_track_azimuth(list(cams), P) or 0.0)
        C = T @ res.cov_apriori[0] @ T.T
        sa, sx, sz = np.sqrt(np.diag(C))
        rows.append((sx, sa, sz, float(np.sqrt(np.trace(C)))))
    a = np.array(rows)
    eq = eq15_precision(conv, altitude, focal_px, sigma_px, along=kind,
                        along_pixel_m=float(np.mean(pixels)) if pixels else None)
    ds = xr.Dataset({"eq15_x": eq.sigma_x, "eq15_y": eq.sigma_y, "eq15_z": eq.sigma_z, "eq15_t": eq.sigma_t},
                    attrs={"kind": kind, "altitude_m": float(altitude), "focal_px": focal_px})
    for j, n in enumerate("xyzt"):
        ds[f"adjust_{n}"] = ("convergence", a[:, j], {"units": "m"})
        ds[f"ratio_{n}"] = ds[f"adjust_{n}"] / ds[f"eq15_{n}"]
    return ds

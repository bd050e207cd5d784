"""A simulated LROC-NAC multi-image site with known truth (the study's Apollo-11 set-up, ``seeds/001``).

:func:`lroc_site` places NAC-like push-broom images (:func:`~lunarmap.simulate.pointed_camera`,
``lrolrocnac`` distortion) over one site from different orbits: each image has its own slew
(roll across track), time of day (Sun incidence and azimuth at the site, carried in the
exterior orientation's Sun position) and resolution (altitude; line time for the along-track
pixel). The default :data:`APOLLO11_LIKE` copies the slews, incidences and pixel scales of the
study's Table 2 (seven images, 1.0-1.05 m pixels, slews -20 to +18 degrees, incidences 43-75
degrees, Sun from the west).

Each image has a TRUE camera and a NAVIGATION camera (position error, attitude bias and drift
per image, as :func:`~lunarmap.simulate.linescan_site`). Ground points on a smooth synthetic
terrain inside the common overlap are split into tie, control and check points (the study: 119
tie points in all seven images, 7 control and 15 check points); every image measures every point
with the TRUE camera plus Gaussian noise whose sigma may depend on the image's emission angle
(a matching-error model: images looking more obliquely match worse against the others).
Everything is plain data (cameras, arrays); :func:`lunarmap.evaluate.site_network` turns the
measurements into a :class:`~lunarmap.adjust.ControlNetwork`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from ..camera import LineScanCamera
from ..camera.geodesy import enu_basis, lonlat_height_to_xyz
from ..camera.shape import MOON_RADIUS
from ..errors import InvalidInputError
from ..orientation.exterior import ExteriorOrientation
from ..orientation.rotation import matrix_to_quat, quat_to_matrix, rotvec_to_matrix
from .orbits import GM_MOON, nac_like_interior
from .stereo import pointed_camera

__all__ = ["SiteImageSpec", "APOLLO11_LIKE", "SimulatedSite", "lroc_site", "NAC_FOCAL_PX"]

Array = NDArray[np.float64]

#: NAC focal length in pixels (699.62 mm / 7 um).
NAC_FOCAL_PX = 699.62 / 0.007


@dataclass(frozen=True)
class SiteImageSpec:
    """One image of a simulated site.

    Attributes
    ----------
    name : str
    slew_deg : float
        Roll across track, degrees; positive looks to the right of the (northbound) ground track.
    incidence_deg : float
        Sun incidence angle at the site, degrees.
    sun_azimuth_deg : float
        Sub-solar ground azimuth at the site, degrees clockwise from north (270: Sun in the west).
    pixel_m : float
        Along-track pixel at the site and nadir pixel scale, metres (sets the altitude,
        ``pixel_m * f / pitch``, and the line time).
    """

    name: str
    slew_deg: float
    incidence_deg: float
    sun_azimuth_deg: float
    pixel_m: float


#: The seven images of the study's Apollo-11 site (Table 2): slews, incidence angles, pixel heights;
#: the Sun is in the west (images taken after local noon), its azimuth 90 degrees from the table's
#: in-image sub-solar azimuth (north up).
APOLLO11_LIKE: tuple[SiteImageSpec, ...] = (
    SiteImageSpec("A1", 16.35, 42.61, 269.60, 1.00),
    SiteImageSpec("A2", -2.53, 43.60, 269.62, 1.00),
    SiteImageSpec("A3", -20.09, 44.56, 269.62, 1.00),
    SiteImageSpec("A4", -17.70, 72.36, 270.19, 1.05),
    SiteImageSpec("A5", 17.96, 74.50, 269.89, 1.05),
    SiteImageSpec("A6", 12.37, 47.53, 270.92, 1.05),
    SiteImageSpec("A7", 3.00, 46.99, 270.70, 1.04),
)


@dataclass
class SimulatedSite:
    """A simulated multi-image site (SI units: metres, radians, seconds, pixels).

    Attributes
    ----------
    names : list of str
    true_cameras, nav_cameras : dict name -> LineScanCamera
    specs : dict name -> SiteImageSpec
    point_id : ndarray of str
    point_type : ndarray of str
        ``"tie"``, ``"control"``, ``"check"``.
    true_xyz : ndarray (n_pt, 3)
        True points, body-fixed metres.
    control_xyz : ndarray (n_pt, 3)
        Reference coordinates given to the adjustment: truth + ``control_sigma`` noise for control
        points, the truth for check points (for evaluation only), NaN for tie points.
    measure_point, measure_image : ndarray (n_meas,) int
    line_sample : ndarray (n_meas, 2)
        Measured image coordinates (truth + noise), pixels.
    measure_sigma : ndarray (n_meas,)
        The noise sigma of each measurement (per coordinate), pixels.
    true_line_sample : ndarray (n_meas, 2)
    image_sigma : dict name -> float
        Measurement sigma of each image, pixels.
    true_params : ndarray (n_img, 12)
        Degree-1 line-scan corrections taking each navigation camera to the truth.
    nav_sigma : dict
        ``position`` (m), ``attitude`` (rad), ``attitude_drift`` (rad/s) the errors were drawn with.
    control_sigma : float
        Metres per axis.
    site : tuple (lon, lat)
        Degrees.
    """

    names: list[str]
    true_cameras: dict[str, LineScanCamera]
    nav_cameras: dict[str, LineScanCamera]
    specs: dict[str, SiteImageSpec]
    point_id: NDArray
    point_type: NDArray
    true_xyz: Array
    control_xyz: Array
    measure_point: NDArray[np.int64]
    measure_image: NDArray[np.int64]
    line_sample: Array
    measure_sigma: Array
    true_line_sample: Array
    image_sigma: dict[str, float]
    true_params: Array
    nav_sigma: dict[str, float]
    control_sigma: float
    site: tuple[float, float]
    attrs: dict = field(default_factory=dict)


def _with_sun(cam: LineScanCamera, sun_xyz: Array) -> LineScanCamera:
    eo = dataclasses.replace(cam.eo, sun_times=np.array([cam.eo.times[0]]), sun_positions=sun_xyz[None, :])
    return LineScanCamera(cam.interior, eo, cam.shape, line_times=cam.line_times)


def _perturbed(cam: LineScanCamera, dpos: Array, datt: Array, ddrift: Array) -> LineScanCamera:
    """The camera with its position moved by ``dpos`` and its attitude turned by ``datt + t ddrift`` (sensor frame)."""
    eo = cam.eo
    M = quat_to_matrix(eo.quaternions)
    Ea = rotvec_to_matrix(datt[None, :] + eo.times[:, None] * ddrift[None, :])
    eo2 = ExteriorOrientation(epoch=eo.epoch, times=eo.times, positions=eo.positions + dpos, velocities=eo.velocities,
                              quaternions=matrix_to_quat(M @ Ea), sun_times=eo.sun_times,
                              sun_positions=eo.sun_positions, body_frame=eo.body_frame,
                              attrs={**eo.attrs, "perturbed": 1})
    return LineScanCamera(cam.interior, eo2, cam.shape, line_times=cam.line_times)


def _terrain(east: Array, north: Array, relief: float) -> Array:
    # smooth hills of a few hundred metres wavelength over the ~4 km common footprint
    return relief * (0.6 * np.sin(east / 410.0 + 0.3) * np.cos(north / 530.0) + 0.4 * np.sin((east + north) / 900.0))


def lroc_site(images: Sequence[SiteImageSpec] = APOLLO11_LIKE, *, n_tie: int = 100, n_control: int = 7,
              n_check: int = 15, sigma_px: float | Callable[[float], float] = 0.3, n_lines: int = 6000,
              n_samples: int = 5064, site: tuple[float, float] = (23.47, 0.67), relief: float = 60.0,
              pos_sigma: float = 20.0, att_sigma: float = 50e-6, att_drift_sigma: float = 2e-6,
              control_sigma: float = 0.5, k1: float | None = 1.81e-5, seed: int = 0) -> SimulatedSite:
    """A simulated NAC multi-image site (module docstring).

    Parameters
    ----------
    images : sequence of SiteImageSpec
        At least two images (default: the study's seven Apollo-11 images).
    n_tie, n_control, n_check : int
        Points of each kind, all seen by every image.
    sigma_px : float or callable
        Measurement noise per image coordinate, pixels: a constant, or a function of the image's
        emission angle at the site (degrees), e.g.
        ``lunarmap.evaluate.NAC_MATCHING_ERROR.per_image_emission``.
    n_lines, n_samples : int
        Image size, pixels (NAC: 5064 samples; 6000 lines of about 1 m cover the common overlap).
    site : (lon, lat)
        Degrees (default: near the Apollo 11 landing site).
    relief : float
        Terrain amplitude, metres.
    pos_sigma, att_sigma, att_drift_sigma : float
        Navigation errors per image: position (m per axis), attitude bias (rad), drift (rad/s).
    control_sigma : float
        Noise of the control coordinates, metres per axis.
    k1 : float or None
        ``lrolrocnac`` distortion of the cameras.
    seed : int

    Raises
    ------
    InvalidInputError
        Fewer than two images, repeated names, too few points or a bad parameter.
    """
    specs = list(images)
    if len(specs) < 2:
        raise InvalidInputError(f"a site needs at least two images, got {len(specs)}")
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise InvalidInputError(f"image names repeat: {names}")
    if min(n_tie, n_check) < 0 or n_control < 0 or n_tie + n_control + n_check < 1:
        raise InvalidInputError("the numbers of tie, control and check points must be >= 0 (and not all 0)")
    for s in specs:
        if not (abs(s.slew_deg) < 60 and 0 <= s.incidence_deg < 90 and s.pixel_m > 0):
            raise InvalidInputError(f"{s.name}: slew must be within +-60, incidence in [0, 90) degrees, pixel > 0")
    rng = np.random.default_rng(seed)
    lon0, lat0 = site
    E = enu_basis(lon0, lat0)
    centre = lonlat_height_to_xyz(lon0, lat0, 0.0)
    true_cams, nav_cams, tp = {}, {}, []
    for s in specs:
        altitude = s.pixel_m * NAC_FOCAL_PX
        r = MOON_RADIUS + altitude
        line_time = s.pixel_m / (np.sqrt(GM_MOON / r ** 3) * MOON_RADIUS)
        look = np.radians(abs(s.slew_deg))
        emission = np.degrees(np.arcsin(np.clip(r / MOON_RADIUS * np.sin(look), -1, 1)))
        # pointed_camera: a positive emission rolls the camera to the left of the northbound track
        io = nac_like_interior(n_lines=n_lines, n_samples=n_samples, k1=k1)
        cam = pointed_camera("linescan", lon0, lat0, -np.sign(s.slew_deg) * emission, altitude=altitude,
                             interior=io, line_time=line_time)
        i, a = np.radians(s.incidence_deg), np.radians(s.sun_azimuth_deg)
        to_sun = np.cos(i) * E[2] + np.sin(i) * (np.sin(a) * E[0] + np.cos(a) * E[1])
        assert isinstance(cam, LineScanCamera)      # kind "linescan"
        cam = _with_sun(cam, centre + 1.496e11 * to_sun)
        dpos, datt, ddrift = (rng.normal(0, sd, 3) for sd in (pos_sigma, att_sigma, att_drift_sigma))
        true_cams[s.name] = cam
        nav = _perturbed(cam, dpos, datt, ddrift)
        nav_cams[s.name] = nav
        corr = nav.corrections(1)
        p = np.zeros(12)
        p[0:3] = datt + corr.t_mid * ddrift
        p[3:6] = -dpos
        p[6:9] = corr.t_half * ddrift
        tp.append(p)

    # points on the terrain inside every image (20 px margin), drawn over the central area
    n_pt = n_tie + n_control + n_check
    half = 0.45 * min(n_lines * min(s.pixel_m for s in specs), n_samples * min(s.pixel_m for s in specs))
    kept = np.zeros((0, 3))
    for _ in range(50):
        en = rng.uniform(-half, half, (4 * n_pt, 2))
        up = _terrain(en[:, 0], en[:, 1], relief)
        lat = lat0 + np.degrees(en[:, 1] / MOON_RADIUS)
        lon = lon0 + np.degrees(en[:, 0] / (MOON_RADIUS * np.cos(np.radians(lat0))))
        X = lonlat_height_to_xyz(lon, lat, up)
        ok = np.ones(X.shape[0], bool)
        for cam in true_cams.values():
            ln, sm = cam.ground_to_image(X)
            ok &= np.isfinite(ln) & (ln > 20) & (ln < n_lines - 20) & (sm > 20) & (sm < n_samples - 20)
        kept = np.concatenate([kept, X[ok]])
        if kept.shape[0] >= n_pt:
            break
    if kept.shape[0] < n_pt:
        raise InvalidInputError(f"the common overlap of {names} holds only {kept.shape[0]} of {n_pt} points; "
                                "use fewer points or larger images")
    X = kept[:n_pt]
    # control: spread farthest-first from the corners; check: random among the rest
    kinds = np.array(["tie"] * n_pt, dtype=object)
    d = (X - X.mean(axis=0)) @ E[:2].T
    chosen: list[int] = []
    if n_control:
        corners = [int(np.argmin(d[:, 0] + d[:, 1])), int(np.argmax(d[:, 0] + d[:, 1])),
                   int(np.argmin(d[:, 0] - d[:, 1])), int(np.argmax(d[:, 0] - d[:, 1]))]
        chosen = list(dict.fromkeys(corners))[:n_control]
        dist = np.min(np.linalg.norm(d[:, None, :] - d[chosen][None, :, :], axis=2), axis=1)
        while len(chosen) < n_control:
            k = int(np.argmax(dist))
            chosen.append(k)
            dist = np.minimum(dist, np.linalg.norm(d - d[k], axis=1))
    kinds[chosen] = "control"
    rest = np.flatnonzero(kinds == "tie")
    kinds[rng.choice(rest, size=n_check, replace=False)] = "check"
    ref = np.full_like(X, np.nan)
    ctl, chk = kinds == "control", kinds == "check"
    ref[ctl] = X[ctl] + rng.normal(0.0, control_sigma, (int(ctl.sum()), 3))
    ref[chk] = X[chk]
    pid = np.array([f"{k}{i:03d}" for i, k in enumerate(kinds)])

    # measurements: every image sees every point; noise by the image's emission angle
    mp, mi, tl, sig, img_sigma = [], [], [], [], {}
    for k, (name, cam) in enumerate(true_cams.items()):
        ln, sm = cam.ground_to_image(X)
        e = float(np.degrees(np.arccos(np.clip(
            np.dot((cam.sensor_position(n_lines / 2, n_samples / 2) - centre) /
                   np.linalg.norm(cam.sensor_position(n_lines / 2, n_samples / 2) - centre), E[2]), -1, 1))))
        s_px = float(sigma_px(e)) if callable(sigma_px) else float(sigma_px)
        if not (np.isfinite(s_px) and s_px > 0):
            raise InvalidInputError(f"{name}: measurement sigma must be finite and > 0, got {s_px}")
        img_sigma[name] = s_px
        mp.append(np.arange(n_pt))
        mi.append(np.full(n_pt, k))
        tl.append(np.column_stack([ln, sm]))
        sig.append(np.full(n_pt, s_px))
    true_ls = np.concatenate(tl)
    msig = np.concatenate(sig)
    meas = true_ls + rng.normal(0.0, 1.0, true_ls.shape) * msig[:, None]
    return SimulatedSite(names, true_cams, nav_cams, {s.name: s for s in specs}, pid, kinds.astype(str), X, ref,
                         np.concatenate(mp).astype(np.int64), np.concatenate(mi).astype(np.int64), meas, msig,
                         true_ls, img_sigma, np.array(tp),
                         {"position": float(pos_sigma), "attitude": float(att_sigma),
                          "attitude_drift": float(att_drift_sigma)}, float(control_sigma), (float(lon0), float(lat0)),
                         attrs={"seed": int(seed), "relief_m": float(relief)})

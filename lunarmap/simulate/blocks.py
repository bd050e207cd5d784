"""Simulated adjustment blocks with known truth: cameras, navigation errors, points and measurements.

Everything here is plain data (cameras, arrays): the tests, benchmarks and demos build their
adjustment problems from it with the public :mod:`lunarmap.adjust` API, like any user.

* :func:`frame_block` -- the DLR paper's simulation set-up (``seeds/004``): a Clementine-UVVIS-like
  framing camera (384 x 288 pixels of 23 um, f = 90 mm, ``radial`` OD_K distortion) on several
  parallel north-bound orbits at ``altitude``, nadir looking, 60 % forward and 30 % side overlap,
  navigation with per-orbit offsets and drifts plus white noise;
* :func:`linescan_site` -- the LROC multi-image set-up (``seeds/001``): NAC-like pushbroom cameras
  (``lrolrocnac`` distortion) on polar orbits rolled to look at one site, navigation with a position
  error, an attitude bias and an attitude drift per image.

Navigation errors are expressed in the sensors' correction parameters
(:mod:`lunarmap.camera.corrections`): the navigation camera ``nav`` and the true camera satisfy
``true = nav.corrections().apply(true_params)``, so ``true_params`` is what an adjustment
starting from the navigation must find. Image measurements are projections of the true points by
the TRUE cameras (the rigorous models, not the adjustment's equations) plus Gaussian noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera import FrameCamera, InteriorOrientation, LineScanCamera, Shape
from ..camera.geodesy import enu_basis, lonlat_height_to_xyz, xyz_to_lonlat_height
from ..camera.shape import MOON_RADIUS
from ..errors import InvalidInputError, SimulationWarning, warn
from ..orientation.exterior import ExteriorOrientation
from ..orientation.rotation import matrix_to_quat, quat_to_matrix, rotvec_to_matrix
from .orbits import NAC_LINE_TIME, nac_like_interior, polar_orbit_eo

__all__ = ["Measurements", "SimulatedBlock", "frame_block", "frame_block_height", "linescan_site", "local_enu", "observe"]

Array = NDArray[np.float64]


@dataclass
class Measurements:
    """Image measurements: image index, point index, ``(line, sample)`` pixels and their sigma (pixels)."""

    cam_idx: NDArray[np.int64]
    pt_idx: NDArray[np.int64]
    xy: Array
    sigma: float


@dataclass
class SimulatedBlock:
    """A simulated block (SI units: metres, radians, seconds, pixels).

    Attributes
    ----------
    true_cameras, nav_cameras : list of camera
        The truth, and the navigation cameras an adjustment starts from.
    true_params : ndarray (n_img, p)
        Correction parameters taking each navigation camera to the true one
        (``nav.corrections(degree).apply(true_params[i])``).
    true_points : ndarray (n_pt, 3)
        Body-fixed metres.
    measurements : Measurements
        Noisy projections of the true points by the true cameras.
    orbit : ndarray (n_img,) int
        Orbit of every image.
    times : ndarray (n_img,)
        Image (centre) time, seconds relative to the orbit's mean image time.
    control, check : int arrays
        Indices of control points and check points.
    control_xyz : ndarray (k, 3)
        Observed control coordinates (truth + noise of ``control_sigma``).
    control_sigma : float
        Metres per axis.
    true_offsets, true_drifts : ndarray (n_orbits, 6)
        Per-orbit navigation offsets (rad, m) and drifts (rad/s, m/s) in ``[w, c]`` order.
    nav_sigma : ndarray (6,) or (n_orbits, 6)
        White-noise sigma of the navigation per parameter ``[w (rad), c (m)]`` (per orbit when they differ).
    offset_sigma, drift_sigma : ndarray (6,)
        Sigmas the per-orbit offsets (rad, m) and drifts (rad/s, m/s) were drawn with (for the line-scan
        site: the per-image attitude drift, rad/s, in ``drift_sigma[:3]``).
    degree : int
        Correction degree the truth is expressed in.
    camera : ndarray (n_img,) int
        Camera of every image (``frame_block(cameras=...)``; 0 otherwise).
    true_jitter : list of (times (m,), angles (m, 3))
        Per image, the attitude jitter in the TRUE cameras' records (``linescan_site(jitter=...)``):
        seconds after the EO epoch and the sensor-frame rotation vectors (radians) the navigation
        misses (``true = nav`` with the correction ``w(t) = (polynomial) + angles(t)``); empty arrays for
        images without jitter. ``true_params`` hold the polynomial part only.
    """

    true_cameras: list
    nav_cameras: list
    true_params: Array
    true_points: Array
    measurements: Measurements
    orbit: NDArray[np.int64]
    times: Array
    control: NDArray[np.int64]
    check: NDArray[np.int64]
    control_xyz: Array
    control_sigma: float
    true_offsets: Array = field(default_factory=lambda: np.zeros((0, 6)))
    true_drifts: Array = field(default_factory=lambda: np.zeros((0, 6)))
    nav_sigma: Array = field(default_factory=lambda: np.zeros(6))
    offset_sigma: Array = field(default_factory=lambda: np.zeros(6))
    drift_sigma: Array = field(default_factory=lambda: np.zeros(6))
    degree: int = 0
    camera: NDArray[np.int64] | None = None
    true_jitter: list = field(default_factory=list)


def local_enu(xyz: Array) -> Array:
    """Rows east, north, up (unit vectors) at body-fixed points ``(..., 3)``: ``(..., 3, 3)``."""
    lon, lat, _ = xyz_to_lonlat_height(xyz)
    return enu_basis(lon, lat)


def observe(cameras: list, X: Array, sigma_px: float, rng: np.random.Generator, n_points: int | None = None,
            min_rays: int = 2) -> tuple[Measurements, Array, NDArray[np.int64]]:
    """Noisy measurements of points by cameras (their rigorous ``ground_to_image``).

    Returns the measurements of the first ``n_points`` points seen by at least ``min_rays`` cameras,
    those points, and their indices in ``X``.
    """
    ci, pi, xy = [], [], []
    for i, cam in enumerate(cameras):
        li, sa = cam.ground_to_image(X, on_miss="nan")
        ok = np.isfinite(li) & np.isfinite(sa)
        ci.append(np.full(int(ok.sum()), i))
        pi.append(np.flatnonzero(ok))
        xy.append(np.column_stack([li[ok], sa[ok]]))
    c, p, v = np.concatenate(ci), np.concatenate(pi), np.concatenate(xy)
    keep = np.flatnonzero(np.bincount(p, minlength=X.shape[0]) >= min_rays)
    if n_points is not None:
        keep = keep[:n_points]
    remap = -np.ones(X.shape[0], np.int64)
    remap[keep] = np.arange(keep.size)
    sel = remap[p] >= 0
    meas = Measurements(c[sel].astype(np.int64), remap[p[sel]], v[sel] + rng.normal(0.0, sigma_px, (int(sel.sum()), 2)),
                        float(sigma_px))
    return meas, X[keep], keep


def _frame_eo(position: Array, rotation: Array, velocity: Array, epoch: float) -> ExteriorOrientation:
    return ExteriorOrientation(epoch=epoch, times=np.array([0.0]), positions=position[None], velocities=velocity[None],
                               quaternions=matrix_to_quat(rotation)[None], sun_times=np.array([0.0]),
                               sun_positions=np.array([[1.5e11, 0.0, 0.0]]),
                               attrs={"source": "lunarmap.simulate.blocks.frame_block"})


def clementine_interior(focal_mm: float = 90.0, pitch_um: float = 23.0, width: int = 384, height: int = 288,
                        odk: tuple[float, float, float] | None = (0.0, -2.42e-5, 0.0)) -> InteriorOrientation:
    """A Clementine-UVVIS-like framing interior: samples along focal-plane x, lines along y, ``radial`` OD_K."""
    pitch = pitch_um * 1e-3
    return InteriorOrientation(
        focal_length=focal_mm, focal2pixel_lines=(0.0, 0.0, 1.0 / pitch), focal2pixel_samples=(0.0, 1.0 / pitch, 0.0),
        detector_center_line=height / 2.0, detector_center_sample=width / 2.0, n_lines=height, n_samples=width,
        distortion_model="none" if odk is None else "radial",
        distortion_coefficients={} if odk is None else {"coefficients": list(odk)}, pixel_pitch=pitch,
        name="Clementine-like")


def frame_block(orbits: int = 4, per_orbit: int = 12, points: int = 1500, n_control: int = 4, n_check: int = 0,
                sigma_px: float | Sequence[float] = 0.3, altitude: float = 400e3,
                interior: InteriorOrientation | None = None,
                nav_sigma_pos: float | Sequence[float] = 10.0, nav_sigma_att: float | Sequence[float] = np.radians(0.001),
                offset_pos: float = 100.0, offset_att: float = np.radians(0.01),
                drift_pos: float = 0.5, drift_att: float = np.radians(0.0002), control_sigma: float = 5.0,
                relief: float = 2000.0, speed: float = 1600.0, seed: int = 0, cameras: int = 1,
                tilt_deg: Sequence[float] | None = None, forward_overlap: float = 0.6, side_overlap: float = 0.3,
                offsets: ArrayLike | None = None, drifts: ArrayLike | None = None,
                min_rays: int = 2, height: Callable[[Array, Array], Array] | None = None) -> SimulatedBlock:
    """The DLR paper's frame block (module docstring); lengths metres, angles radians, drifts per second.

    Parameters
    ----------
    orbits, per_orbit : int
        Parallel strips and images per strip (all cameras together).
    points : int
        Ground points kept (seen by >= ``min_rays`` images).
    n_control, n_check : int
        Control points (near the block's corners and centre, then spread farthest-first) and check points
        (random others).
    sigma_px : float or sequence of float
        Image measurement noise, pixels; one value per camera allowed (``Measurements.sigma`` is then
        per observation).
    interior : InteriorOrientation, optional
        Default :func:`clementine_interior` (with its ``radial`` distortion).
    nav_sigma_pos, nav_sigma_att : float or sequence of float
        White noise of the navigation per image (m, rad); one value per orbit allowed.
    offset_pos, offset_att, drift_pos, drift_att : float
        Sigmas of the per-orbit offsets (m, rad) and drifts (m/s, rad/s) the navigation errors are drawn with.
    control_sigma : float
        Control point noise, metres per axis.
    relief : float
        Terrain amplitude, metres.
    speed : float
        Ground speed, m/s (converts along-track spacing into image times).
    cameras : int
        Cameras per orbit; image ``k`` of an orbit is taken by camera ``k % cameras`` (the DLR
        paper's simulation: 2 cameras on 2 orbits). Each camera's footprints follow each other at
        the forward overlap, the cameras' interleaved by a fraction of the spacing.
    tilt_deg : sequence of float, optional
        Along-track look angle of every camera, degrees (positive: forward); the spacecraft is
        shifted back along the orbit so that each image looks at its footprint centre. Default nadir.
    forward_overlap, side_overlap : float
        Overlap of one camera's consecutive footprints, and of neighbouring strips (at nadir).
    offsets, drifts : array_like (orbits, 6), optional
        The per-orbit navigation offsets (rad, m) and drifts (rad/s, m/s) in ``[w, c]`` order;
        default: drawn with the sigmas above.
    min_rays : int
        Points seen by fewer images are not kept.
    height : callable, optional
        The true terrain ``height(lon, lat)``: metres above the Moon sphere at planetocentric degrees (e.g. a
        cratered DTM's interpolant); default :func:`frame_block_height` with ``relief``.
    """
    if orbits < 1 or per_orbit < 2:
        raise InvalidInputError(f"a frame block needs >= 1 orbit of >= 2 images, got {orbits} x {per_orbit}")
    if cameras < 1 or per_orbit % cameras:
        raise InvalidInputError(f"{per_orbit} images per orbit cannot be shared by {cameras} cameras")
    tilts = np.zeros(cameras) if tilt_deg is None else np.radians(np.asarray(tilt_deg, float))
    if tilts.shape != (cameras,):
        raise InvalidInputError(f"tilt_deg needs one angle per camera ({cameras}), got {tilt_deg!r}")
    if not (0.0 <= forward_overlap < 1.0 and 0.0 <= side_overlap < 1.0):
        raise InvalidInputError("overlaps must be in [0, 1)")
    rng = np.random.default_rng(seed)
    io = interior or clementine_interior()
    R = MOON_RADIUS
    f_px = io.focal_length / io.pixel_pitch
    gsd = altitude / f_px
    base = (1.0 - forward_overlap) * io.n_lines * gsd
    strip = (1.0 - side_overlap) * io.n_samples * gsd
    per_cam = per_orbit // cameras
    # footprint centres: camera c's k-th image at (k + c / cameras) spacings along the strip
    k_img = np.arange(per_orbit)
    cam_of = k_img % cameras
    along = (k_img // cameras + cam_of / cameras - (per_cam - 1 + (cameras - 1) / cameras) / 2) * base
    lats = along / R
    lons = (np.arange(orbits) - (orbits - 1) / 2) * strip / R
    LON, LAT = np.meshgrid(lons, lats, indexing="ij")
    LAT, LON = LAT.ravel(), LON.ravel()
    n = LAT.size
    orbit = np.repeat(np.arange(orbits), per_orbit)
    camera = np.tile(cam_of, orbits)
    tilt = tilts[camera]
    # the spacecraft is back along the orbit by altitude * tan(tilt) when it looks at the footprint centre
    LATC = LAT - altitude * np.tan(tilt) / R
    t = LATC * R / speed
    t = t - t.reshape(orbits, per_orbit).mean(axis=1)[orbit]
    E = enu_basis(np.degrees(LON), np.degrees(LATC))                     # rows east, north, up
    up, north, east = E[:, 2], E[:, 1], E[:, 0]
    C_true = (R + altitude + rng.normal(0, 500.0, n))[:, None] * up
    # sensor frame: x = east (samples), y = south (lines run north to south), z = down (boresight);
    # a forward tilt turns the boresight towards north about the sensor x axis
    ct, st = np.cos(tilt)[:, None], np.sin(tilt)[:, None]
    R_nadir = np.stack([east, -north * ct - up * st, -up * ct + north * st], axis=-1)   # columns: sensor axes
    R_true = R_nadir @ rotvec_to_matrix(rng.normal(0, np.radians(0.05), (n, 3)))
    vel = speed * (R + altitude) / R * north

    if offsets is None:
        off = np.column_stack([rng.normal(0, offset_att, (orbits, 3)), rng.normal(0, offset_pos, (orbits, 3))])
    else:
        off = _per_orbit("offsets", offsets, orbits)
    if drifts is None:
        dr = np.column_stack([rng.normal(0, drift_att, (orbits, 3)), rng.normal(0, drift_pos, (orbits, 3))])
    else:
        dr = _per_orbit("drifts", drifts, orbits)
    sig_att = np.broadcast_to(np.asarray(nav_sigma_att, float), (orbits,))
    sig_pos = np.broadcast_to(np.asarray(nav_sigma_pos, float), (orbits,))
    nav_sig_orbit = np.column_stack([sig_att, sig_att, sig_att, sig_pos, sig_pos, sig_pos])     # (orbits, 6)
    err = off[orbit] + t[:, None] * dr[orbit] + rng.normal(0, 1, (n, 6)) * nav_sig_orbit[orbit]
    # true = nav corrected by err: R_true = R_nav exp([w]x)^T, C_true = C_nav + c
    R_nav = R_true @ rotvec_to_matrix(err[:, 0:3])
    C_nav = C_true - err[:, 3:6]
    shape = Shape.moon()
    epoch = 3.0e8
    true_cams = [FrameCamera(io, _frame_eo(C_true[i], R_true[i], vel[i], epoch + t[i]), shape) for i in range(n)]
    nav_cams = [FrameCamera(io, _frame_eo(C_nav[i], R_nav[i], vel[i], epoch + t[i]), shape) for i in range(n)]

    margin = 0.5 * np.hypot(io.n_samples, io.n_lines) * gsd / R
    m = 6 * points
    plat = rng.uniform(lats.min() - margin, lats.max() + margin, m)
    plon = rng.uniform(lons.min() - margin, lons.max() + margin, m)
    h = (_frame_height(plon, plat, relief) if height is None
         else np.asarray(height(np.degrees(plon), np.degrees(plat)), float))
    X = lonlat_height_to_xyz(np.degrees(plon), np.degrees(plat), h)
    sig_cam = np.asarray(sigma_px, float)
    if sig_cam.ndim == 0:
        meas, X, _ = observe(true_cams, X, float(sig_cam), rng, n_points=points, min_rays=min_rays)
    else:
        if sig_cam.shape != (cameras,):
            raise InvalidInputError(f"sigma_px needs one value per camera ({cameras}), got {sigma_px!r}")
        meas, X, _ = observe(true_cams, X, 0.0, rng, n_points=points, min_rays=min_rays)
        per_obs = sig_cam[camera[meas.cam_idx]]
        meas.xy = meas.xy + rng.normal(0.0, 1.0, meas.xy.shape) * per_obs[:, None]
        meas.sigma = per_obs       # type: ignore[assignment]
    control, check, ctl_xyz = _control_and_check(X, meas, n_control, n_check, control_sigma, rng, with_centre=True)
    nav_sig = nav_sig_orbit[0].copy() if orbits == 1 or np.all(nav_sig_orbit == nav_sig_orbit[0]) else nav_sig_orbit
    return SimulatedBlock(true_cams, nav_cams, err.copy(), X, meas, orbit, t, control, check, ctl_xyz,
                          float(control_sigma), off, dr, nav_sig, np.array([offset_att] * 3 + [offset_pos] * 3),
                          np.array([drift_att] * 3 + [drift_pos] * 3), 0, camera)


def _frame_height(lon_rad: Array, lat_rad: Array, relief: float) -> Array:
    R = MOON_RADIUS
    return relief * (0.5 * np.sin(lat_rad * R / 37e3 + 1.0) * np.cos(lon_rad * R / 53e3)
                     + 0.2 * np.sin(lon_rad * R / 11e3))


def frame_block_height(lon: ArrayLike, lat: ArrayLike, relief: float = 2000.0) -> Array:
    """The true terrain of :func:`frame_block` (its ``relief``): heights above the Moon sphere, metres, at
    ``lon, lat`` degrees (planetocentric, east)."""
    return _frame_height(np.radians(np.asarray(lon, float)), np.radians(np.asarray(lat, float)), relief)


def _per_orbit(name: str, values: ArrayLike, orbits: int) -> Array:
    a = np.asarray(values, float)
    if a.shape != (orbits, 6):
        raise InvalidInputError(f"{name} must be ({orbits}, 6) [w (rad), c (m)] per orbit, got {a.shape}")
    return a.copy()


def _nac_camera(lon_orbit: float, lat: float, roll: float, altitude: float, n_lines: int, n_samples: int,
                k1: float | None, perturb: tuple[Array, Array, Array] | None = None,
                jitter: tuple[float, object] | None = None) -> LineScanCamera:
    step = 0.05 if jitter is None else float(jitter[0])
    eo = polar_orbit_eo(lat_center=lat, lon=lon_orbit, altitude=altitude, half_span=2.0 + n_lines * NAC_LINE_TIME,
                        step=step, roll_deg=roll)
    if jitter is not None:
        # truth = the smooth attitude with a sensor-frame jitter j(t) at every record: R = M exp([j]x)^T, so
        # that the correction from the (smooth) navigation is w(t) = bias + drift t + j(t)
        angles = jitter[1](eo.times)      # type: ignore[operator]
        R = quat_to_matrix(eo.quaternions) @ np.swapaxes(rotvec_to_matrix(angles), -1, -2)
        eo = ExteriorOrientation(epoch=eo.epoch, times=eo.times, positions=eo.positions, velocities=eo.velocities,
                                 quaternions=matrix_to_quat(R), sun_times=eo.sun_times, sun_positions=eo.sun_positions,
                                 attrs={**eo.attrs, "jitter": 1})
    if perturb is not None:
        # navigation = truth with a position error and a sensor-frame attitude error a(t) = bias + t drift
        dpos, datt, ddrift = perturb
        M = quat_to_matrix(eo.quaternions)
        Ea = rotvec_to_matrix(datt[None, :] + eo.times[:, None] * ddrift[None, :])
        eo = ExteriorOrientation(epoch=eo.epoch, times=eo.times, positions=eo.positions + dpos,
                                 velocities=eo.velocities, quaternions=matrix_to_quat(M @ Ea),
                                 sun_times=eo.sun_times, sun_positions=eo.sun_positions,
                                 attrs={**eo.attrs, "perturbed": 1})
    return LineScanCamera(nac_like_interior(n_lines=n_lines, n_samples=n_samples, k1=k1), eo, Shape.moon(),
                          line_times=(-n_lines * NAC_LINE_TIME / 2.0, NAC_LINE_TIME))


def _terrain(lon: Array, lat: Array, site: tuple[float, float], relief: float) -> Array:
    # smooth hills of a few hundred metres wavelength (the footprint is ~1 km)
    x = np.radians(lon - site[0]) * MOON_RADIUS * np.cos(np.radians(site[1]))
    y = np.radians(lat - site[1]) * MOON_RADIUS
    return relief * (0.6 * np.sin(x / 210.0 + 0.3) * np.cos(y / 330.0) + 0.4 * np.sin((x + y) / 500.0))


def linescan_site(rolls: tuple[float, ...] = (-15.0, 0.0, 15.0), degree: int = 1, n_points: int = 40,
                  n_control: int = 4, n_check: int = 10, sigma_px: float = 0.3, n_lines: int = 3000,
                  n_samples: int = 1500, altitude: float = 50e3, site: tuple[float, float] = (30.0, 20.0),
                  pos_sigma: float = 20.0, att_sigma: float = 50e-6, att_drift_sigma: float = 20e-6,
                  control_sigma: float = 0.3, relief: float = 50.0, k1: float | None = 1.81e-5,
                  seed: int = 0, jitter: Sequence[tuple[float, float]] = (), jitter_noise: float = 0.0,
                  jitter_images: Sequence[int] | None = None, jitter_step: float = 0.002,
                  point_extent: float = 0.35) -> SimulatedBlock:
    """NAC-like pushbroom images of one site from several rolled orbits (module docstring).

    Parameters
    ----------
    rolls : sequence of float
        Roll (look) angles across track, degrees; one image each.
    degree : int
        Degree (>= 1) of the correction polynomials the truth is expressed in.
    pos_sigma, att_sigma, att_drift_sigma : float
        Navigation errors per image: position (m per axis), attitude bias (rad), attitude drift (rad/s).
    k1 : float or None
        ``lrolrocnac`` distortion coefficient (mm^-2) of the cameras; ``None`` for none.
    jitter : sequence of (amplitude (rad), frequency (Hz))
        Attitude jitter of the TRUE cameras (LRO NAC CK-like: 1-3 urad at 1-10 Hz): per image and axis,
        the sum of these sinusoids with random phases, plus white noise of ``jitter_noise`` radians per
        attitude record; records every ``jitter_step`` seconds. The navigation cameras have none (their
        attitude is the smooth one with its bias and drift). See ``SimulatedBlock.true_jitter``.
    jitter_images : sequence of int, optional
        The images with jitter (default all, if ``jitter`` or ``jitter_noise`` is given).
    point_extent : float
        Half-size of the area the candidate points are drawn in, as a fraction of the ground size of
        the image's smaller dimension (times ``n_lines / min(n_lines, n_samples)`` along track): 0.35
        (the default) covers about the central third of the lines, 1.0 nearly all of them (a jitter
        spline needs points on all its knots).
    """
    if degree < 1:
        raise InvalidInputError("the simulated attitude drift needs a correction degree >= 1")
    waves = [(float(a), float(f)) for a, f in jitter]
    if any(not (np.isfinite(a) and np.isfinite(f) and a >= 0 and f > 0) for a, f in waves) or \
            not (np.isfinite(jitter_noise) and jitter_noise >= 0) or not (np.isfinite(jitter_step) and jitter_step > 0):
        raise InvalidInputError("jitter needs (amplitude >= 0 rad, frequency > 0 Hz) pairs, jitter_noise >= 0 rad "
                                "and jitter_step > 0 s")
    jittered = set(range(len(rolls)) if jitter_images is None else (int(i) for i in jitter_images)) \
        if (waves or jitter_noise > 0) else set()
    rng = np.random.default_rng(seed)
    jit_rng = np.random.default_rng([seed, 30])     # its own stream: the rest of the block is the jitter-free one
    true_jitter = []
    lon0, lat0 = site
    true_cams, nav_cams, truth = [], [], []
    for i_img, roll in enumerate(rolls):
        lon_o = lon0
        for _ in range(3):   # shift the orbit until the centre pixel looks at the site
            g = _nac_camera(lon_o, lat0, roll, altitude, n_lines, n_samples, k1).image_to_ground(
                n_lines / 2, n_samples / 2, 0.0)
            lon_o -= float(xyz_to_lonlat_height(g)[0] - lon0)
        dpos, datt, ddrift = (rng.normal(0, s, 3) for s in (pos_sigma, att_sigma, att_drift_sigma))
        spec = None
        if i_img in jittered:
            phases = jit_rng.uniform(0.0, 2.0 * np.pi, (len(waves), 3))
            noise_seed = int(jit_rng.integers(2**31))

            def angles(t: Array, phases: Array = phases, noise_seed: int = noise_seed) -> Array:
                a = np.zeros((t.size, 3))
                for (amp, freq), ph in zip(waves, phases):
                    a += amp * np.sin(2.0 * np.pi * freq * t[:, None] + ph[None, :])
                return a + np.random.default_rng(noise_seed).normal(0.0, jitter_noise, a.shape)

            spec = (jitter_step, angles)
        cam_true = _nac_camera(lon_o, lat0, roll, altitude, n_lines, n_samples, k1, jitter=spec)
        true_cams.append(cam_true)
        if spec is not None:
            true_jitter.append((cam_true.eo.times.copy(), spec[1](cam_true.eo.times)))
        else:
            true_jitter.append((np.zeros(0), np.zeros((0, 3))))
        nav_cams.append(_nac_camera(lon_o, lat0, roll, altitude, n_lines, n_samples, k1, (dpos, datt, ddrift)))
        truth.append((dpos, datt, ddrift))
    n_par = 6 * (degree + 1)
    true_params = np.zeros((len(rolls), n_par))
    for i, (dpos, datt, ddrift) in enumerate(truth):
        corr = nav_cams[i].corrections(degree)
        true_params[i, 0:3] = datt + corr.t_mid * ddrift
        true_params[i, 3:6] = -dpos
        true_params[i, 6:9] = corr.t_half * ddrift

    if not (np.isfinite(point_extent) and 0 < point_extent <= 1.5):
        raise InvalidInputError(f"point_extent must be in (0, 1.5], got {point_extent!r}")
    half = point_extent * min(n_lines, n_samples) * 0.5 * altitude * 0.007 / 699.62 / MOON_RADIUS * 180 / np.pi
    m = 4 * n_points
    lon = lon0 + rng.uniform(-half, half, m) / np.cos(np.radians(lat0))
    lat = lat0 + rng.uniform(-half, half, m) * n_lines / min(n_lines, n_samples)
    X = lonlat_height_to_xyz(lon, lat, _terrain(lon, lat, site, relief))
    meas, X, _ = observe(true_cams, X, sigma_px, rng, n_points=n_points)
    if X.shape[0] < n_points:
        warn(f"only {X.shape[0]} of {n_points} points are seen by 2 or more images", SimulationWarning)
    control, check, ctl_xyz = _control_and_check(X, meas, n_control, n_check, control_sigma, rng, with_centre=False)
    times = np.array([c.center_time for c in nav_cams])
    return SimulatedBlock(true_cams, nav_cams, true_params, X, meas, np.zeros(len(rolls), np.int64),
                          times - times.mean(), control, check, ctl_xyz, float(control_sigma),
                          nav_sigma=np.array([att_sigma] * 3 + [pos_sigma] * 3),
                          drift_sigma=np.array([att_drift_sigma] * 3 + [0.0] * 3), degree=degree,
                          true_jitter=true_jitter)


def _control_and_check(X: Array, meas: Measurements, n_control: int, n_check: int, control_sigma: float,
                       rng: np.random.Generator, with_centre: bool) -> tuple[NDArray[np.int64], NDArray[np.int64], Array]:
    """Control points nearest the cloud's corners (and centre) among well-observed points; random check points."""
    rays = np.bincount(meas.pt_idx, minlength=X.shape[0])
    cand = np.flatnonzero(rays >= min(3, int(rays.max())))
    enu = local_enu(X[cand].mean(axis=0))
    d = X[cand] - X[cand].mean(axis=0)
    e, nn = d @ enu[0], d @ enu[1]
    picks = [np.argmin(e + nn), np.argmax(e + nn), np.argmin(e - nn), np.argmax(e - nn)]
    if with_centre:
        picks.append(np.argmin(np.hypot(e, nn)))
    control = np.unique(cand[np.array(picks[:max(n_control, 0)], np.int64)]) if n_control > 0 else np.zeros(0, np.int64)
    if n_control > control.size:
        # more control: the well-observed candidates farthest from those chosen so far, one at a time
        chosen = list(control)
        dist = np.min(np.linalg.norm(X[cand][:, None, :] - X[np.array(chosen)][None, :, :], axis=2), axis=1)
        while len(chosen) < min(n_control, cand.size):
            k = int(np.argmax(dist))
            chosen.append(int(cand[k]))
            dist = np.minimum(dist, np.linalg.norm(X[cand] - X[cand[k]], axis=1))
        control = np.unique(np.array(chosen, np.int64))
    rest = np.setdiff1d(np.arange(X.shape[0]), control)
    check = np.sort(rng.choice(rest, size=min(n_check, rest.size), replace=False)) if n_check > 0 \
        else np.zeros(0, np.int64)
    ctl_xyz = X[control] + rng.normal(0.0, control_sigma, (control.size, 3))
    return control.astype(np.int64), check.astype(np.int64), ctl_xyz

"""The DLR paper's simulation (``seeds/004``, section 5, Tables 1-7), built on :func:`~.blocks.frame_block`.

Table 1: 32 images of a Clementine-UVVIS-like camera (384 x 288 pixels, f = 90 mm, 43.478 px/mm,
150 m pixels) from 2 orbits with 2 cameras, 10 control points, 40 conjugate points measured in 344
image points. Here the two cameras of an orbit look 10 degrees aft and fore (as Clementine's camera
was tilted within the orbit plane), each with 75 % forward overlap; the orbits overlap by 60 %. The
40 points (10 of them control points) are chosen among points seen by at least 3 images so that
they are measured exactly 344 times.

The experiments of the paper on it:

* gross errors (Tables 2-3): 10 image errors of 500-3000 px, 10 of 10-40 px (random directions,
  at most one per point), one navigation position error of 2 km, one attitude error of 0.2 degrees
  (one axis of one image each) and one control point error of 2 km (one axis): :func:`inject_blunders`;
* variance components (Tables 4-5): example I (image sigma 0.02 / 0.005 mm for the two cameras,
  positions 100 / 500 m and attitudes 0.01 / 0.05 degrees for the two orbits, control 200 m) and
  example II (0.1 mm, 2000 m, 0.2 degrees, 1000 m): :data:`VARIANCE_EXAMPLES`;
* offsets and drifts (Tables 6-7): example 1, offsets ``c1(x0) = 4000 m``, ``c2(y0) = 2000 m``,
  ``c1(kappa) = 0.5 deg``; example 2, offsets 2000 m, 1000 m, 1.0 deg with drifts 2 m/km, 5 m/km,
  0.01 deg/km: :data:`OFFSET_EXAMPLES`.

The paper's photogrammetric axes at the block (latitude 0, longitude 0): ``x0`` east (the body-fixed
``c_y``), ``y0`` north (``c_z``), ``z0`` up (``c_x``); ``kappa`` the rotation about the boresight
(``w_z``). Drifts are per kilometre of along-orbit distance ``s`` (:attr:`DlrSimulation.along_km`).
Navigation observations are the corrections of the navigation cameras, observed as zero (plus the
injected blunders, :attr:`DlrSimulation.nav_observed`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidInputError
from .blocks import Measurements, SimulatedBlock, clementine_interior, frame_block

__all__ = ["DlrSimulation", "Blunders", "dlr_block", "inject_blunders", "VARIANCE_EXAMPLES", "OFFSET_EXAMPLES",
           "PAPER_AXES"]

#: pixels per millimetre of the Clementine UVVIS camera (Table 8)
PX_PER_MM = 43.478
#: the paper's navigation axes -> index of the correction parameter ``[w_x, w_y, w_z, c_x, c_y, c_z]``
PAPER_AXES = {"phi": 0, "omega": 1, "kappa": 2, "z0": 3, "x0": 4, "y0": 5}

#: Tables 4-5: true sigmas (image mm per camera, position m and attitude degrees per orbit, control m)
VARIANCE_EXAMPLES: dict[str, dict[str, Any]] = {
    "I": dict(image_mm=(0.02, 0.005), position_m=(100.0, 500.0), attitude_deg=(0.01, 0.05), control_m=200.0),
    "II": dict(image_mm=(0.1, 0.1), position_m=(2000.0, 2000.0), attitude_deg=(0.2, 0.2), control_m=1000.0),
    # the gross-error experiments (Tables 2-3; the paper does not list their sigmas): example I's
    # image and control sigmas, the first orbit's navigation sigmas on both orbits
    "blunders": dict(image_mm=(0.02, 0.005), position_m=(100.0, 100.0), attitude_deg=(0.01, 0.01), control_m=200.0),
    # the offset/drift experiments (Tables 6-7; sigmas not given): as "blunders", with control points good
    # enough (20 m) to fix each orbit's absolute orientation -- with 200 m control a 0.5 degree kappa offset
    # of one orbit cannot be told from -0.5 degrees of the other
    "offsets": dict(image_mm=(0.02, 0.005), position_m=(100.0, 100.0), attitude_deg=(0.01, 0.01), control_m=20.0),
}
#: Tables 6-7: (orbit, paper axis, offset in m or deg, drift in m/km or deg/km)
OFFSET_EXAMPLES = {
    1: [(0, "x0", 4000.0, 0.0), (1, "y0", 2000.0, 0.0), (0, "kappa", 0.5, 0.0)],
    2: [(0, "x0", 2000.0, 2.0), (1, "y0", 1000.0, 5.0), (0, "kappa", 1.0, 0.01)],
}
SPEED = 1600.0   # m/s ground speed of frame_block: converts drifts per km into drifts per second


@dataclass
class Blunders:
    """Gross errors injected into a simulation (indices into its observations).

    Attributes
    ----------
    image_obs : (k,) int
        Image observations with a gross error; ``image_px (k, 2)`` the error added (line, sample).
    image_group : (k,) int
        1 for the large errors (500-3000 px), 2 for the small ones (10-40 px) -- the paper's groups.
    position, attitude : (image, parameter) or None
        Navigation observation with a gross error; ``position_value`` metres, ``attitude_value`` radians.
    control : (control point index in ``block.control``, axis) or None
        Control coordinate with a gross error of ``control_value`` metres.
    """

    image_obs: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    image_px: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    image_group: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    position: tuple[int, int] | None = None
    position_value: float = 0.0
    attitude: tuple[int, int] | None = None
    attitude_value: float = 0.0
    control: tuple[int, int] | None = None
    control_value: float = 0.0

    @property
    def count(self) -> int:
        return int(self.image_obs.size) + sum(x is not None for x in (self.position, self.attitude, self.control))


@dataclass
class DlrSimulation:
    """The paper's simulated block (module docstring).

    Attributes
    ----------
    block : SimulatedBlock
        Cameras, truth and the measurements (with the blunders, if injected). ``block.camera`` gives
        each image's camera, ``block.orbit`` its orbit.
    nav_observed : (n_img, 6)
        Observed navigation corrections ``[w (rad), c (m)]`` (zero + blunders).
    nav_sigma : (n_img, 6)
        Their a-priori sigmas (the simulated ones).
    image_sigma : (n_obs,)
        Simulated image sigma of every observation, pixels.
    control_sigma : float
        Metres per axis.
    along_km : (n_img,)
        Along-orbit distance of every image from its orbit's mean, km (the drift coordinate).
    clean_xy : (n_obs, 2)
        The image measurements before the blunders.
    blunders : Blunders
    """

    block: SimulatedBlock
    nav_observed: NDArray[np.float64]
    nav_sigma: NDArray[np.float64]
    image_sigma: NDArray[np.float64]
    control_sigma: float
    along_km: NDArray[np.float64]
    clean_xy: NDArray[np.float64]
    blunders: Blunders = field(default_factory=Blunders)


def _keep_points(sb: SimulatedBlock, keep: NDArray[np.int64]) -> None:
    """Restrict a simulated block to the points ``keep`` (sorted), in place."""
    remap = -np.ones(sb.true_points.shape[0], np.int64)
    remap[keep] = np.arange(keep.size)
    m = sb.measurements
    sel = remap[m.pt_idx] >= 0
    sig = np.asarray(m.sigma)
    sb.measurements = Measurements(m.cam_idx[sel], remap[m.pt_idx[sel]], m.xy[sel],
                                   sig[sel] if sig.ndim else float(sig))    # type: ignore[arg-type]
    ctl_keep = remap[sb.control] >= 0
    sb.control_xyz = sb.control_xyz[ctl_keep]
    sb.control = remap[sb.control[ctl_keep]]
    sb.check = remap[sb.check[remap[sb.check] >= 0]]
    sb.true_points = sb.true_points[keep]


def dlr_block(seed: int = 0, example: str = "I", offsets: int | None = None, n_points: int = 40,
              n_image_points: int = 344, n_control: int = 10, tilt_deg: float = 10.0) -> DlrSimulation:
    """The paper's simulated block without gross errors (see :func:`inject_blunders`).

    Parameters
    ----------
    seed : int
    example : {"I", "II", "blunders"}
        The simulated sigmas of Tables 4-5 (:data:`VARIANCE_EXAMPLES`), or those of the gross-error runs.
    offsets : {None, 1, 2}
        Navigation offsets/drifts of the paper's example 1 or 2 (:data:`OFFSET_EXAMPLES`); none by default.
    n_points, n_image_points, n_control : int
        Points (control points included), their measurements, control points.
    tilt_deg : float
        The two cameras look this far aft and fore.
    """
    if example not in VARIANCE_EXAMPLES:
        raise InvalidInputError(f"example must be one of {sorted(VARIANCE_EXAMPLES)}, got {example!r}")
    if offsets is not None and offsets not in OFFSET_EXAMPLES:
        raise InvalidInputError(f"offsets must be None or one of {sorted(OFFSET_EXAMPLES)}, got {offsets!r}")
    ex = VARIANCE_EXAMPLES[example]
    off = np.zeros((2, 6))
    dr = np.zeros((2, 6))
    for orbit, axis, c, d in (OFFSET_EXAMPLES[offsets] if offsets is not None else []):
        k = PAPER_AXES[axis]
        unit = np.radians(1.0) if k < 3 else 1.0
        off[orbit, k] = c * unit
        dr[orbit, k] = d * unit * SPEED / 1000.0                        # per km -> per second
    sig_px = tuple(mm * PX_PER_MM for mm in ex["image_mm"])
    sb = frame_block(orbits=2, per_orbit=16, cameras=2, tilt_deg=(-tilt_deg, tilt_deg), forward_overlap=0.75,
                     side_overlap=0.6, points=4 * n_points, n_control=n_control, n_check=0, sigma_px=sig_px,
                     altitude=150.0 * 90.0 / 0.023, interior=clementine_interior(),
                     nav_sigma_pos=ex["position_m"], nav_sigma_att=np.radians(ex["attitude_deg"]),
                     offsets=off, drifts=dr, control_sigma=ex["control_m"], min_rays=3, seed=seed)
    # the control points and free points whose measurements add up to n_image_points
    rng = np.random.default_rng(seed + 7919)
    rays = np.bincount(sb.measurements.pt_idx, minlength=sb.true_points.shape[0])
    others = np.setdiff1d(np.arange(rays.size), sb.control)
    need = n_image_points - int(rays[sb.control].sum())
    k = n_points - sb.control.size
    pick = rng.choice(others, k, replace=False)
    for _ in range(20000):
        diff = need - int(rays[pick].sum())
        if diff == 0:
            break
        i = rng.integers(k)
        cand = np.setdiff1d(others, pick)
        good = cand[np.abs(rays[cand] - rays[pick[i]] - diff) < abs(diff)]
        if good.size:
            pick[i] = rng.choice(good)
    if int(rays[pick].sum()) != need:
        raise InvalidInputError(f"no {n_points} points with {n_image_points} measurements in this block (seed {seed})")
    _keep_points(sb, np.sort(np.concatenate([sb.control, pick])))
    n = len(sb.nav_cameras)
    nav_sigma = np.column_stack([np.repeat(np.radians(ex["attitude_deg"]), 16)[:, None].repeat(3, 1),
                                 np.repeat(ex["position_m"], 16)[:, None].repeat(3, 1)])
    assert nav_sigma.shape == (n, 6)
    return DlrSimulation(sb, np.zeros((n, 6)), nav_sigma, np.asarray(sb.measurements.sigma, float),
                         float(ex["control_m"]), sb.times * SPEED / 1000.0, sb.measurements.xy.copy())


def inject_blunders(sim: DlrSimulation, seed: int = 0, large: int = 10, small: int = 10,
                    large_px: tuple[float, float] = (500.0, 3000.0), small_px: tuple[float, float] = (10.0, 40.0),
                    position_m: float | None = 2000.0, attitude_deg: float | None = 0.2,
                    control_m: float | None = 2000.0, position_axes: tuple[str, ...] = ("x0", "y0"),
                    attitude_axes: tuple[str, ...] = ("phi", "omega")) -> DlrSimulation:
    """A copy of ``sim`` with the paper's gross errors (Tables 2-3) at random places.

    Image errors go to distinct points, in random directions with magnitudes uniform in the
    ranges; the navigation errors go to one random image, on one of ``position_axes`` /
    ``attitude_axes`` (:data:`PAPER_AXES`), the control error to one random axis of one random
    control point, each with a random sign.

    The default axes are the ones the images can see: for this 5.6 degree camera 587 km up, the
    height ``z0`` and the rotation ``kappa`` about the boresight move the image points by less than
    a pixel for 2 km and 0.2 degrees (scale 0.34 %, rotation 0.0035 rad), their navigation
    observations have redundancy numbers of ~0.02, and their minimal detectable errors
    (``4.1 sigma / sqrt(r)``) are ~2.6 km and ~0.5 degrees: no test can find errors of the
    paper's size there.
    """
    rng = np.random.default_rng(seed)
    sb = sim.block
    m = sb.measurements
    n_pt = sb.true_points.shape[0]
    if large + small > n_pt:
        raise InvalidInputError(f"{large + small} image blunders need as many points, the block has {n_pt}")
    pts = rng.choice(n_pt, large + small, replace=False)
    obs = np.array([rng.choice(np.flatnonzero(m.pt_idx == j)) for j in pts], np.int64)
    mag = np.concatenate([rng.uniform(*large_px, large), rng.uniform(*small_px, small)])
    ang = rng.uniform(0.0, 2.0 * np.pi, large + small)
    vec = mag[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    xy = sim.clean_xy.copy()
    xy[obs] += vec
    bl = Blunders(obs, vec, np.r_[np.ones(large, np.int64), np.full(small, 2, np.int64)])
    nav_obs = np.zeros_like(sim.nav_observed)
    n_img = nav_obs.shape[0]
    if position_m:
        j, k = int(rng.integers(n_img)), PAPER_AXES[position_axes[int(rng.integers(len(position_axes)))]]
        nav_obs[j, k] = rng.choice([-1.0, 1.0]) * position_m
        bl.position, bl.position_value = (j, k), float(nav_obs[j, k])
    if attitude_deg:
        # another image than the position error's: on one image the two would be the same error to the
        # images (a cross-track shift is a roll), and nothing could tell which observation is wrong
        others = [i for i in range(n_img) if bl.position is None or i != bl.position[0]]
        j, k = int(rng.choice(others)), PAPER_AXES[attitude_axes[int(rng.integers(len(attitude_axes)))]]
        nav_obs[j, k] = rng.choice([-1.0, 1.0]) * np.radians(attitude_deg)
        bl.attitude, bl.attitude_value = (j, k), float(nav_obs[j, k])
    ctl = sb.control_xyz.copy()
    if control_m and sb.control.size:
        c, a = int(rng.integers(sb.control.size)), int(rng.integers(3))
        v = rng.choice([-1.0, 1.0]) * control_m
        ctl[c, a] += v
        bl.control, bl.control_value = (c, a), float(v)
    new = SimulatedBlock(**{**sb.__dict__, "measurements": Measurements(m.cam_idx, m.pt_idx, xy, m.sigma),
                            "control_xyz": ctl})
    return DlrSimulation(new, nav_obs, sim.nav_sigma, sim.image_sigma, sim.control_sigma, sim.along_km,
                         sim.clean_xy, bl)

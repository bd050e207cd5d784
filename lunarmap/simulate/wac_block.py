"""A WAC-like push-frame block as a user receives one: SPICE kernels, ISIS-like labels, rendered images.

:func:`write_wac_block` writes, into one folder, four LRO WAC UV-like push-frame images (the interior of
:func:`lunarmap.simulate.orbits.wac_like_interior`: 4.67 mm focal length, 16-line framelets summed 4x,
128 samples, the UV's radial distortion) of the LUNARMAP-SIM spacecraft, two per orbit on two adjacent
polar orbits 50 km up (about 13 km apart at 10 deg N, one orbit period apart in time), the two images
of an orbit a few framelets apart; framelets every second leave small gaps, as the WAC's even/odd
framelet images do. Tie points are therefore matched across the orbits only (the images of one orbit
see the same rays). What is written:

* ``mission/``: LSK, SCLK, PCK, planets SPK (the synthetic mission's), a frames kernel and an IK of the
  camera ``SIM_WAC`` (CK frame, :class:`lunarmap.orientation.drivers.GenericDriver` keywords
  ``LUNARMAP_CAMERA_TYPE = 'PUSHFRAME'``, ``FRAMELET_HEIGHT``, ``SUMMING``, ``LINE_OFFSET``,
  ``SAMPLE_OFFSET``), TRUTH and NAVIGATION SPK and CK (navigation: per-orbit position (1 km) and
  attitude (5 mrad) offsets and their rates, 50 m and 0.5 mrad over half an image), their
  meta-kernels, and one ISIS-like label per image (``ExposureDuration``, ``InterframeDelay``,
  ``DataFlipped``, as ``lrowac2isis`` writes them);
* the images (netCDF), rendered through the cameras of the TRUTH kernels (their ISDs, as a run
  reads them) of a synthetic DTM and albedo at 400 m (``mission/dtm.nc``);
* ``points.nc``: control (0.5 m coordinates) and check points measured in the true cameras
  (0.2 px), seen from both orbits;
* ``run.toml``: the run over the NAVIGATION kernels (``lunarmap run``): push-frame corrections of
  degree 1 with navigation observations of the errors' sigmas, per-orbit navigation groups.

The orbits are body-fixed circles (:func:`lunarmap.simulate.orbits.polar_orbit_eo`; written to the SPK
in ``IAU_MOON``), the orbit plane 30 degrees east of the subsolar meridian of the synthetic Sun.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

__all__ = ["write_wac_block", "measure_points", "WAC_NAME", "WAC_ID"]

WAC_NAME = "SIM_WAC"
WAC_ID = -990700
_LAT0 = 10.0
_ORBIT_SPACING_DEG = 0.45
_ORBIT_PERIOD = 7080.0          # s between the passes (about one 50 km orbit)
_EXPOSURE = 0.04                # s
_STEP = 0.5                     # s between SPK / CK records
_KERNELS = ("lunarmap_sim.tls", "lunarmap_sim.tsc", "lunarmap_sim.tpc", "lunarmap_wac.tf", "lunarmap_wac.ti",
            "lunarmap_sim_planets.bsp")

_CONFIG = """# lunarmap run configuration of a WAC-like push-frame block (lunarmap.simulate.write_wac_block)
[run]
output = "{output}"
name = "synthetic WAC block: 4 LRO-WAC-UV-like push-frame images, 2 orbits (seed {seed})"

[kernels]
metakernel = "mission/navigation.tm"

{images}
[dtm]
path = "mission/dtm.nc"

[points]
path = "points.nc"

[rpc]
enabled = true
height_range = [-3000.0, 3000.0]

[tiepoints]
cell = 16
search = 24.0
min_overlap = 0.05

[adjust]
degree = 1
estimate_tie_variance = true
ftol = 1e-10

[adjust.navigation]
position_sigma = 1000.0
attitude_sigma = 5e-3
position_rate_sigma = {position_rate}
attitude_rate_sigma = {attitude_rate}

[report]
html = true
"""


def _label(name: str, lines: int, start_utc: str, sclk: str, exposure_ms: float, delay_ms: float) -> str:
    inst = [("SpacecraftName", '"LUNARMAP-SIM"'), ("InstrumentId", WAC_NAME), ("TargetName", "MOON"),
            ("StartTime", start_utc), ("SpacecraftClockStartCount", sclk),
            ("ExposureDuration", f"{exposure_ms:.6f} <ms>"), ("InterframeDelay", f"{delay_ms:.6f} <ms>"),
            ("DataFlipped", "Yes"), ("NumLinesOverlap", "0")]
    w = max(len(k) for k, _ in inst)
    return "\n".join(["Object = IsisCube", "  Object = Core", "    Group = Dimensions", "      Samples = 128",
                      f"      Lines   = {lines}", "      Bands   = 1", "    End_Group", "  End_Object", "",
                      "  Group = Instrument", *[f"    {k.ljust(w)} = {v}" for k, v in inst], "  End_Group", "",
                      "  Group = Kernels", f"    NaifFrameCode = {WAC_ID}", "  End_Group", "End_Object",
                      "End"]) + "\n"


def _frames_kernel() -> tuple[str, Any]:
    from ..spice.writer import Append
    from ..synthetic import ids

    b = WAC_ID
    names = {"NAIF_BODY_NAME": Append([ids.SPACECRAFT_NAME, WAC_NAME]),
             "NAIF_BODY_CODE": Append([ids.SPACECRAFT_ID, WAC_ID])}
    frame = {f"FRAME_{WAC_NAME}": b, f"FRAME_{b}_NAME": WAC_NAME, f"FRAME_{b}_CLASS": 3, f"FRAME_{b}_CLASS_ID": b,
             f"FRAME_{b}_CENTER": ids.SPACECRAFT_ID, f"CK_{b}_SCLK": ids.SCLK_ID, f"CK_{b}_SPK": ids.SPACECRAFT_ID}
    return ("Frames of the LUNARMAP-SIM WAC-like block (lunarmap.simulate.write_wac_block): SIM_WAC is a CK\n"
            "frame (boresight +z nadir, +x along the ground-track velocity).",
            [("Names and ids.", names), ("SIM_WAC (CK frame).", frame)])


def _instrument_kernel() -> tuple[str, Any]:
    from ..synthetic import ids
    from .orbits import wac_like_interior

    io = wac_like_interior()
    p = f"INS{WAC_ID}_"
    k = io.distortion_coefficients["coefficients"]
    geometry = {p + "FOCAL_LENGTH": io.focal_length, p + "PIXEL_PITCH": io.pixel_pitch,
                p + "ITRANSL": list(io.focal2pixel_lines), p + "ITRANSS": list(io.focal2pixel_samples),
                p + "BORESIGHT_LINE": io.detector_center_line + 0.5,
                p + "BORESIGHT_SAMPLE": io.detector_center_sample + 0.5, p + "OD_K": [float(v) for v in k]}
    push = {p + "FRAMELET_HEIGHT": 16, p + "SUMMING": int(io.line_summing),
            p + "LINE_OFFSET": float(io.starting_detector_line), p + "SAMPLE_OFFSET": float(io.starting_detector_sample)}
    lunarmap = {p + ids.KW_CAMERA_TYPE: "PUSHFRAME", p + ids.KW_DISTORTION_MODEL: "radial",
                p + ids.KW_LIGHTTIME_CORRECTION: "NONE", p + "CK_FRAME_ID": WAC_ID, p + "CK_REFERENCE_ID": 10020,
                p + "PLATFORM_ID": ids.SPACECRAFT_ID}
    return (f"Instrument kernel of {WAC_NAME} (NAIF id {WAC_ID}): an LRO WAC UV filter-1-like push-frame camera\n"
            "(IK INS-85641 values, COLOR readout window). FOCAL_LENGTH mm; ITRANSL/ITRANSS pixels per mm;\n"
            "BORESIGHT_LINE/SAMPLE ISIS pixels; OD_K the 'radial' model's coefficients (lunarmap's sign);\n"
            "FRAMELET_HEIGHT detector lines per framelet, SUMMING line and sample summing, LINE_OFFSET and\n"
            "SAMPLE_OFFSET the readout window's first detector line and sample.",
            [("Optics and detector.", geometry), ("Framelets.", push), ("lunarmap keywords.", lunarmap)])


def _metakernel(files: list[str], what: str) -> str:
    lines = ["KPL/MK", "", f"Meta-kernel of the LUNARMAP-SIM WAC-like block: {what}.", "", "\\begindata", "",
             "   PATH_VALUES     = ( '.' )", "   PATH_SYMBOLS    = ( 'KERNELS' )", ""]
    for i, f in enumerate(files):
        head = "   KERNELS_TO_LOAD = ( " if i == 0 else " " * 22
        lines.append(f"{head}'$KERNELS/{f}'{' )' if i == len(files) - 1 else ''}")
    return "\n".join([*lines, "", "\\begintext", ""]) + "\n"


def _skew_exp(v: np.ndarray) -> np.ndarray:
    """Rotation matrices exp([v]x) of small rotation vectors, shape (n, 3, 3)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(v).as_matrix()


def measure_points(cameras: Mapping[str, Any], X: np.ndarray, kind: str, sigma_px: float, rng: np.random.Generator,
                   control_sigma_m: float = 0.5) -> Any:
    """Ground points measured in the images that see them: a :class:`~lunarmap.adjust.ControlNetwork`.

    Parameters
    ----------
    cameras : mapping of str to camera
        The (true) cameras, by image name; their order is the network's image order.
    X : (n, 3) ndarray
        Body-fixed points, m.
    kind : {"control", "check", "tie"}
        Point type; control points get coordinates perturbed by ``control_sigma_m`` and that covariance.
    sigma_px : float
        Noise of each image coordinate, pixels.
    rng : numpy.random.Generator
    control_sigma_m : float
        σ of each control point coordinate, m.
    """
    from ..adjust import ControlNetwork

    names = list(cameras)
    pid, img, ls = [], [], []
    for i, x in enumerate(np.asarray(X, dtype=float)):
        for j, name in enumerate(names):
            li, sa = cameras[name].ground_to_image(x)
            if np.isfinite(li):
                pid.append(i)
                img.append(j)
                ls.append([li + rng.normal(0, sigma_px), sa + rng.normal(0, sigma_px)])
    keep = np.unique(pid)
    xyz = np.asarray(X, dtype=float)[keep]
    cov = None
    if kind == "control":
        xyz = xyz + rng.normal(0, control_sigma_m, xyz.shape)
        cov = np.tile(np.eye(3) * control_sigma_m ** 2, (keep.size, 1, 1))
    return ControlNetwork(point_id=np.array([f"{kind[:2]}{i}" for i in keep]), point_type=np.array([kind] * keep.size),
                          xyz=xyz, measure_point=np.searchsorted(keep, pid), measure_image=np.array(img),
                          line_sample=np.array(ls), measure_sigma=np.full((len(pid), 2), sigma_px),
                          image_id=np.array(names), xyz_cov=cov)


def write_wac_block(folder: str | os.PathLike[str], seed: int = 0, framelets: int = 60, delay: float = 1.0,
                    n_control: int = 8, n_check: int = 32, output: str = "run") -> Path:
    """Write the WAC-like block (see the module docstring) into ``folder``; returns ``run.toml``.

    Parameters
    ----------
    folder : path-like
        Created if needed; its files are replaced.
    seed : int
        Seed of the navigation errors, scene, image noise and points.
    framelets, delay : int, float
        Framelets per image (4 image lines each) and seconds between them.
    n_control, n_check : int
        Control and check points (fewer when not enough are seen from both orbits).
    output : str
        Run folder, relative to ``folder``.
    """
    import spiceypy

    from ..adjust import merge_networks, write_network
    from ..camera.factory import camera_from_isd
    from ..orientation.drivers import image_support
    from ..orientation.rotation import align_quaternion_signs, matrix_to_quat
    from ..spice.writer import CkSegment, SpkSegment, loaded_temporarily, write_ck, write_spk, write_text_kernel
    from ..synthetic import ids, textkernels
    from ..synthetic.bodies import moon_state_ssb, sun_state_ssb
    from ..synthetic.mission import tdb_to_et
    from .orbits import nadir_rotation, orbit_state
    from .render import render_image
    from .terrain import synthetic_scene

    root = Path(folder)
    d = root / "mission"
    d.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    lsk, sclk, pck, fk, ik, planets = (d / f for f in _KERNELS)
    c, sec = textkernels.lsk()
    write_text_kernel(lsk, "LSK", sec, c)
    zero_et = tdb_to_et(textkernels.SCLK_ZERO_TDB)
    c, sec = textkernels.sclk(zero_et)
    write_text_kernel(sclk, "SCLK", sec, c)
    c, sec = textkernels.pck()
    write_text_kernel(pck, "PCK", sec, c)
    c, sec = _frames_kernel()
    write_text_kernel(fk, "FK", sec, c)
    c, sec = _instrument_kernel()
    write_text_kernel(ik, "IK", sec, c)
    epoch0 = zero_et + 80 * 86400.0 + 0.25      # tick-aligned (1/65536 s)
    epochs = [epoch0 + o * _ORBIT_PERIOD for o in (0, 1)]
    tp = epoch0 - 86400.0 + 3600.0 * np.arange(51)
    sun, moon = sun_state_ssb(tp), moon_state_ssb(tp)
    write_spk(planets, [SpkSegment(ids.SUN_ID, ids.SSB_ID, "J2000", tp, sun[:, :3], sun[:, 3:], "SIM SUN", 7),
                        SpkSegment(ids.MOON_ID, ids.SSB_ID, "J2000", tp, moon[:, :3], moon[:, 3:], "SIM MOON", 7)],
              internal_name="LUNARMAP-SIM PLANETS", comments=["Sun and Moon SPK of the WAC-like block (fictional)."])
    with loaded_temporarily([lsk, pck, planets]):
        s, _ = spiceypy.spkpos("SUN", epoch0, "IAU_MOON", "LT+S", "MOON")
    lon0 = float(np.degrees(np.arctan2(s[1], s[0]))) + 30.0

    # per orbit: a body-fixed polar circle through (_LAT0, lon_o) at its epoch; navigation errors per orbit
    half_image = 0.5 * (framelets - 1) * delay
    span = 0.95 * framelets * delay + framelets * delay
    t = np.arange(-span, span + 1e-9, _STEP)
    truth_spk: list[Any] = []
    nav_spk: list[Any] = []
    truth_ck: list[Any] = []
    nav_ck: list[Any] = []
    for o, e in enumerate(epochs):
        lon = lon0 + _ORBIT_SPACING_DEG * o
        pos, vel = orbit_state(t, _LAT0, lon)
        m = nadir_rotation(pos, vel)                           # sensor -> body
        w = np.sqrt(4.9028e12 / np.linalg.norm(pos[0]) ** 3)
        lam = np.radians(lon)
        av = np.tile(w * np.array([np.sin(lam), -np.cos(lam), 0.0]), (t.size, 1))
        dp, dpr = rng.normal(0, 1000.0, 3), rng.normal(0, 50.0, 3) / half_image
        da, dar = rng.normal(0, 5e-3, 3), rng.normal(0, 5e-4, 3) / half_image
        pos_n, vel_n = pos + dp + np.outer(t, dpr), vel + dpr
        m_n = _skew_exp(da + np.outer(t, dar)) @ m
        et = e + t
        seg = f"ORBIT {o}"
        truth_spk.append(SpkSegment(ids.SPACECRAFT_ID, ids.MOON_ID, "IAU_MOON", et, pos / 1e3, vel / 1e3, seg, 7))
        nav_spk.append(SpkSegment(ids.SPACECRAFT_ID, ids.MOON_ID, "IAU_MOON", et, pos_n / 1e3, vel_n / 1e3, seg, 7))
        for out, mm, a in ((truth_ck, m, av), (nav_ck, m_n, av + dar)):
            # C-matrices rotate IAU_MOON vectors into the sensor frame: the transposes of sensor -> body
            q = align_quaternion_signs(matrix_to_quat(np.transpose(mm, (0, 2, 1))))
            out.append(CkSegment(WAC_ID, "IAU_MOON", et, q, a, f"SIM WAC {seg}"))
    for kind, spk, ck in (("truth", truth_spk, truth_ck), ("navigation", nav_spk, nav_ck)):
        write_spk(d / f"wac_{kind}.bsp", spk, internal_name=f"LUNARMAP-SIM WAC {kind.upper()}",
                  comments=[f"{kind} trajectory of the WAC-like block (fictional)."])
        write_ck(d / f"wac_{kind}.bc", ck, time_kernels=[lsk, sclk], sclk_id=ids.SCLK_ID,
                 internal_name=f"LUNARMAP-SIM WAC {kind.upper()}",
                 comments=[f"{kind} attitude of the WAC-like block (fictional)."])
        (d / f"{kind}.tm").write_text(_metakernel([*_KERNELS, f"wac_{kind}.bsp", f"wac_{kind}.bc"],
                                                  kind.upper()), encoding="ascii")

    # labels: two images per orbit, centred (k - 0.5) 0.95 framelets * delay from the orbit's epoch
    names, tick = [], 1.0 / textkernels.SCLK_MODULI[1]
    with loaded_temporarily([lsk, sclk]):
        for o, e in enumerate(epochs):
            for k in (0, 1):
                name = f"orbit{o}_img{k}"
                start = e + (k - 0.5) * 0.95 * framelets * delay - half_image - 0.5 * _EXPOSURE
                start = zero_et + round((start - zero_et) / tick) * tick
                ticks = int(round((start - zero_et) / tick))
                sc = f"1/{ticks // textkernels.SCLK_MODULI[1]:010d}:{ticks % textkernels.SCLK_MODULI[1]:05d}"
                utc = spiceypy.et2utc(start, "ISOC", 3)
                (d / f"{name}.lbl").write_text(_label(name, 4 * framelets, utc, sc, 1e3 * _EXPOSURE, 1e3 * delay))
                names.append(name)
    truth = {n: camera_from_isd(image_support(d / f"{n}.lbl", d / "truth.tm")) for n in names}

    dtm, albedo = synthetic_scene(lon0 + 0.5 * _ORBIT_SPACING_DEG, _LAT0, extent=220e3, gsd=400.0, seed=seed)
    dtm.to_netcdf(d / "dtm.nc")
    for i, n in enumerate(names):
        img = render_image(truth[n], dtm, albedo, supersample=2, noise_sigma=1.0, seed=seed + i, sun="eo", name=n)
        img.to_netcdf(d / f"{n}.nc")

    # control and check points: truth ground points seen from both orbits, measured in the true cameras
    lines = 4 * framelets
    g = np.concatenate([truth[n].image_to_ground(rng.uniform(2, lines - 2, 80), rng.uniform(10, 118, 80),
                                                 dtm=dtm, on_miss="nan") for n in ("orbit0_img0", "orbit1_img1")])
    g = g[np.isfinite(g).all(axis=1)]
    seen = np.array([[np.isfinite(c.ground_to_image(x)[0]) for c in truth.values()] for x in g])
    g = g[seen[:, :2].any(axis=1) & seen[:, 2:].any(axis=1)]
    g = g[rng.permutation(g.shape[0])]

    net = merge_networks(measure_points(truth, g[:n_control], "control", 0.2, rng),
                         measure_points(truth, g[n_control:n_control + n_check], "check", 0.2, rng))
    write_network(net, root / "points.nc")
    images = "\n".join(f'[[images]]\nname = "{n}"\nlabel = "mission/{n}.lbl"\npixels = "mission/{n}.nc"\n'
                       f'group = "orbit{n[5]}"\n' for n in names)
    path = root / "run.toml"
    path.write_text(_CONFIG.format(output=output, seed=seed, images=images, position_rate=50.0 / half_image,
                                   attitude_rate=5e-4 / half_image))
    return path

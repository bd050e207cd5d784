"""Reading ISD JSON files back into cameras, without SPICE (lunarmap's own ISDs and USGS ALE's).

Oracles: the cameras built from the in-memory ISDs that the drivers sampled
from SPICE, SPICE itself (``sxform``, ``xf2rav``, ``rav2xf``, ``pxform``), and
ALE's published LRO NAC ISD. The reader never sees the kernels.
"""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lunarmap.camera import camera_from_isd, camera_from_isd_file
from lunarmap.errors import IsdFormatError, LunarmapError
from lunarmap.orientation.isd import ImageSupport
from lunarmap.orientation.rotation import quat_to_matrix
from lunarmap.orientation.rotation_hermite import RotationHermite, state_transform
from lunarmap.synthetic import IMAGE_NAMES

MOON_RADIUS_M = 1737.4e3


def angle_between(m1: np.ndarray, m2: np.ndarray) -> np.ndarray:
    """Rotation angles (rad) of ``m1 m2^T`` for stacks of matrices."""
    r = m1 @ np.swapaxes(m2, -1, -2)
    c = (np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0
    # acos loses precision near 0: use the skew part instead
    s = np.linalg.norm(np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                                 r[..., 1, 0] - r[..., 0, 1]], axis=-1), axis=-1) / 2.0
    return np.arctan2(s, c)


def quat_angle(q1, q2) -> np.ndarray:
    q1, q2 = np.asarray(q1, float), np.asarray(q2, float)
    d = np.minimum(np.linalg.norm(q1 - q2, axis=-1), np.linalg.norm(q1 + q2, axis=-1))
    return 4.0 * np.arcsin(np.clip(d / 2.0, 0.0, 1.0))


def image_grid(n_lines: int, n_samples: int, n: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """An n x n grid of pixel centres from the first to the last pixel (CSM convention)."""
    lines, samples = np.meshgrid(np.linspace(0.5, n_lines - 0.5, n), np.linspace(0.5, n_samples - 0.5, n),
                                 indexing="ij")
    return lines.ravel(), samples.ravel()


def compare_cameras(ref, other, n_lines: int, n_samples: int) -> tuple[float, float, float]:
    """Max ground difference (m), max pixel difference and ground sample distance (m/px) over a grid.

    Ground points come from the reference camera; points that the reference
    cannot project back (NaN) must be NaN for the other camera too.
    """
    line, sample = image_grid(n_lines, n_samples)
    g_ref = ref.image_to_ground(line, sample)
    g_other = other.image_to_ground(line, sample)
    l_ref, s_ref = ref.ground_to_image(g_ref)
    l_oth, s_oth = other.ground_to_image(g_ref)
    ok = np.isfinite(l_ref)
    assert np.array_equal(ok, np.isfinite(l_oth))
    assert ok.sum() >= 0.8 * ok.size
    px = max(np.abs(l_oth - l_ref)[ok].max(), np.abs(s_oth - s_ref)[ok].max())
    g1 = ref.image_to_ground(line + 1.0, sample)
    g2 = ref.image_to_ground(line, sample + 1.0)
    gsd = min(np.linalg.norm(g1 - g_ref, axis=-1).min(), np.linalg.norm(g2 - g_ref, axis=-1).min())
    return float(np.abs(g_other - g_ref).max()), float(px), float(gsd)


# -- synthetic mission: every image written, read back ------------------------------------------

@pytest.fixture(scope="module")
def sim_isds(sim_mission, tmp_path_factory):
    from lunarmap.orientation.drivers import image_support

    folder = tmp_path_factory.mktemp("isd_json")
    out = {}
    for name in IMAGE_NAMES:
        isd = image_support(sim_mission.parent / f"{name}.lbl", sim_mission)
        path = folder / f"{name}.json"
        isd.write_json(path)
        out[name] = (isd, path)
    return out


@pytest.mark.parametrize("name", IMAGE_NAMES)
def test_sim_round_trip_gives_the_same_camera(sim_isds, name):
    isd, path = sim_isds[name]
    back = ImageSupport.read_json(path)
    assert back.model == isd.model
    # the document itself survives unchanged (the reader adds only its file name to the provenance)
    d0, d1 = isd.to_ale_dict(), back.to_ale_dict()
    assert d1["lunarmap"].pop("isd_file") == str(path)
    assert d0 == d1
    ground_m, px, gsd = compare_cameras(camera_from_isd(isd), camera_from_isd_file(path),
                                        isd.image_lines, isd.image_samples)
    # The file lists the body rotation at the first and last epoch only; the driver samples it there
    # too and interpolates it to the other epochs the same way (test_sim_body_rotation_vs_spice: the
    # smooth rotation differs from SPICE's per-epoch values by SPICE's rounding noise only), so the
    # re-read ISD is the same camera.
    noise = angle_between(back.body_state_rotations[:, :3, :3], isd.body_state_rotations[:, :3, :3]).max()
    assert noise < 1e-14
    sun_file, sun_memory = back.exterior_orientation().sun_positions, isd.exterior_orientation().sun_positions
    assert np.abs(sun_file - sun_memory).max() < 2e-12 * np.linalg.norm(sun_memory, axis=1).max()
    assert ground_m < 1e-6
    assert px <= 1e-6, (px, gsd)
    print(f"{name}: ground {ground_m:.2e} m, {px:.2e} px (body rotation differs by {noise:.1e} rad)")


def test_sim_frame_round_trip_within_1e_6_px(sim_isds):
    for name in ("sim_frame_a", "sim_frame_b"):
        isd, path = sim_isds[name]
        ground_m, px, _ = compare_cameras(camera_from_isd(isd), camera_from_isd_file(path),
                                          isd.image_lines, isd.image_samples)
        assert px <= 1e-6 and ground_m < 1e-6


def test_sim_body_rotation_vs_spice(sim_isds, sim_mission):
    """The body rotation of the ISD (sampled at 2 epochs 16 s apart, interpolated like a reader of the file
    does), against SPICE's sxform at all 5223 epochs.

    The difference is SPICE's rounding noise (about 1e-13 rad rms: the IAU prime meridian is evaluated in
    degrees near 4.6e4), not an interpolation error: it is mostly what a cubic in time cannot fit, and the
    smooth part is no larger than that noise (the two sampled epochs are themselves noisy SPICE values).
    """
    from lunarmap.spice import KernelSet, kernels
    from lunarmap.spice import queries as q

    isd, path = sim_isds["sim_nac_equator"]
    assert isd.times[-1] - isd.times[0] > 15.0
    with kernels(KernelSet.from_metakernel(sim_mission)):
        xf = q.state_rotations("J2000", isd.body_frame, isd.times)
    r = np.swapaxes(isd.body_state_rotations[:, :3, :3], 1, 2) @ xf[:, :3, :3]
    small = np.stack([r[:, 2, 1], r[:, 0, 2], r[:, 1, 0]], axis=1)  # small-angle rotation vector, rad
    t = isd.times - isd.times[0]
    smooth = np.stack([np.polyval(np.polyfit(t, small[:, k], 3), t) for k in range(3)], axis=1)
    noise = small - smooth
    assert np.abs(small).max() < 1.5e-12
    assert np.abs(smooth).max() <= 2.0 * np.abs(noise).max()
    assert noise.std() >= 0.5 * small.std()
    # the state transforms' rate part: d(R)/dt = -R [w]x with |w| = 2.7e-6 rad/s, here within 1e-17 /s
    dr = isd.body_state_rotations[:, 3:, :3] - xf[:, 3:, :3]
    assert np.abs(dr).max() < 1e-17
    back = ImageSupport.read_json(path)
    assert np.array_equal(back.body_state_rotations, isd.body_state_rotations)
    print(f"sim body rotation vs SPICE: max {np.abs(small).max():.1e} rad (noise rms {noise.std():.1e}, smooth "
          f"part {np.abs(smooth).max():.1e}), dR/dt {np.abs(dr).max():.1e} /s")


def test_sim_resampling_of_different_position_and_pointing_epochs(sim_isds):
    """Positions every 0.31 s and pointing every 31 ms at other epochs, against SPICE at all of them."""
    isd, path = sim_isds["sim_nac_equator"]
    doc = json.loads(path.read_text())
    n = isd.times.size
    pos_idx = np.r_[np.arange(0, n, 100), n - 1]
    att_idx = np.arange(5, n, 10)
    ip, pt = doc["instrument_position"], doc["instrument_pointing"]
    for key in ("ephemeris_times", "positions", "velocities"):
        ip[key] = [ip[key][i] for i in pos_idx]
    for key in ("ephemeris_times", "quaternions", "angular_velocities"):
        pt[key] = [pt[key][i] for i in att_idx]
    back = ImageSupport.from_ale_dict(doc, source="decimated")
    idx = np.union1d(pos_idx, att_idx)
    assert np.array_equal(back.times, isd.times[idx])
    dp = np.abs(back.positions - isd.positions[idx]).max() * 1e3  # km -> m
    dv = np.abs(back.velocities - isd.velocities[idx]).max() * 1e3
    da = quat_angle(back.pointing.quaternions, isd.pointing.quaternions[idx]).max()
    assert dp < 1e-6 and dv < 1e-6
    assert da < 1e-10
    # and the body-fixed sensor-to-body rotations the camera uses
    db = angle_between(back.sensor_to_body_matrices(), isd.sensor_to_body_matrices()[idx]).max()
    assert db < 1e-10
    print(f"resampling vs SPICE: position {dp:.1e} m, velocity {dv:.1e} m/s, pointing {da:.1e} rad, "
          f"sensor-to-body {db:.1e} rad")


@pytest.mark.shared
def test_pointing_epochs_within_a_microsecond_are_merged(lro_set):
    doc = json.loads((lro_set / "ale_isd.json").read_text())
    original = np.array(doc["instrument_pointing"]["quaternions"])
    doc["instrument_pointing"]["ephemeris_times"] = [t + 3e-7 for t in doc["instrument_pointing"]["ephemeris_times"]]
    back = ImageSupport.from_ale_dict(doc)
    assert np.array_equal(back.times, doc["instrument_position"]["ephemeris_times"])
    # the attitude 0.3 microsecond earlier: LRO turns at 8e-4 rad/s, i.e. 2.4e-10 rad
    moved = quat_angle(back.pointing.quaternions, original)
    assert 1e-10 < moved.max() < 3e-10


def test_single_position_and_pointing_at_different_epochs(sim_isds):
    """A framer whose pointing epoch is 10 ms off its position epoch: both propagated to both epochs."""
    isd, path = sim_isds["sim_frame_a"]
    doc = json.loads(path.read_text())
    t0 = doc["instrument_position"]["ephemeris_times"][0]
    w = np.array(doc["instrument_pointing"]["angular_velocities"][0])
    q0 = np.array(doc["instrument_pointing"]["quaternions"][0])
    # the pointing table moved 10 ms later, with the rotation propagated at constant rate (SPICE sign)
    q1 = RotationHermite([t0], [q0], [w])([t0 + 0.01])[0][0]
    doc["instrument_pointing"]["ephemeris_times"] = [t0 + 0.01]
    doc["instrument_pointing"]["quaternions"] = [q1.tolist()]
    back = ImageSupport.from_ale_dict(doc)
    assert np.array_equal(back.times, [t0, t0 + 0.01])
    assert quat_angle(back.pointing.quaternions[0], q0) < 1e-15
    assert np.array_equal(back.pointing.quaternions[1], q1)
    v = np.array(doc["instrument_position"]["velocities"][0])
    dt = back.times[1] - t0  # 0.01 s to the ET spacing (6e-8 s)
    assert np.abs(back.positions[1] - (np.array(doc["instrument_position"]["positions"][0]) + dt * v)).max() < 1e-12
    assert np.array_equal(back.positions[0], doc["instrument_position"]["positions"][0])


# -- rotation interpolation with angular velocities --------------------------------------------

def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _analytic_rotation(t: float) -> np.ndarray:
    """A rotation with time-varying axis and rate, from scipy's matrix exponential."""
    from scipy.linalg import expm

    base = quat_to_matrix(np.array([0.3, 0.5, -0.2, 0.7]))
    return base @ expm(_skew(np.array([0.3 * t + 0.05 * np.sin(t), -0.2 * t + 0.1 * t * t, 0.5 * np.cos(0.7 * t)])))


def _analytic_rate(t: float, h: float = 1e-5) -> np.ndarray:
    """``xf2rav``-convention angular velocity, ``dR/dt = -R [w]x``, by central differences."""
    w = -_analytic_rotation(t).T @ (_analytic_rotation(t + h) - _analytic_rotation(t - h)) / (2.0 * h)
    return np.array([w[2, 1], w[0, 2], w[1, 0]])


def test_rotation_hermite_is_fourth_order_and_exact_for_constant_rate():
    from lunarmap.orientation.rotation import matrix_to_quat
    from scipy.linalg import expm

    errors = []
    for n in (11, 21, 41):
        t = np.linspace(0.0, 2.0, n)
        interp = RotationHermite(t, [matrix_to_quat(_analytic_rotation(x)) for x in t],
                                 [_analytic_rate(x) for x in t], rates="derivative")
        tt = np.linspace(0.0, 2.0, 157)
        q, w = interp(tt)
        errors.append(angle_between(quat_to_matrix(q), np.array([_analytic_rotation(x) for x in tt])).max())
        assert np.abs(w - np.array([_analytic_rate(x) for x in tt])).max() < 2e-5
    assert errors[0] / errors[1] > 12.0 and errors[1] / errors[2] > 12.0  # ~16: fourth order
    assert errors[-1] < 5e-9
    # constant angular velocity: exact inside, and propagated exactly outside the samples
    w0 = np.array([1e-3, -2e-3, 5e-4])
    base = quat_to_matrix(np.array([0.1, 0.2, 0.3, 0.9]))
    t = np.array([0.0, 3.0, 10.0])
    interp = RotationHermite(t, [matrix_to_quat(base @ expm(-_skew(w0 * x))) for x in t], np.tile(w0, (3, 1)))
    tt = np.linspace(-5.0, 15.0, 41)
    q, w = interp(tt)
    truth = np.array([base @ expm(-_skew(w0 * x)) for x in tt])
    assert angle_between(quat_to_matrix(q), truth).max() < 1e-14
    assert np.abs(w - w0).max() < 1e-18


# -- SPICE sign conventions and the body rotation of the real LRO kernels ----------------------

@pytest.fixture(scope="module")
def lro_kernels(lro_set):
    from lunarmap.spice import KernelSet

    return KernelSet.from_metakernel(lro_set / "lro_nac_M103595705LE.tm")


@pytest.mark.shared
def test_angular_velocity_sign_matches_spice(lro_set, lro_kernels):
    """``state_transform`` is SPICE's rav2xf; constant-rate propagation has SPICE's sign."""
    import spiceypy

    from lunarmap.spice import kernels

    ale = json.loads((lro_set / "ale_isd.json").read_text())
    t = np.array(ale["instrument_position"]["ephemeris_times"])
    with kernels(lro_kernels):
        for frame in ("MOON_PA_DE421", "LRO_SC_BUS"):
            for et in t[::100]:
                xf = np.array(spiceypy.sxform("J2000", frame, et))
                rot, av = spiceypy.xf2rav(xf)
                assert np.abs(state_transform(rot, av) - xf).max() < 1e-18
                assert np.abs(state_transform(rot, av) - np.array(spiceypy.rav2xf(rot, av))).max() < 1e-18
        # the Moon's rotation 0.4 s on, from the first epoch's rotation and angular velocity
        rot, av = spiceypy.xf2rav(np.array(spiceypy.sxform("J2000", "MOON_PA_DE421", t[0])))
        truth = np.array(spiceypy.pxform("J2000", "MOON_PA_DE421", t[-1]))
    from lunarmap.orientation.rotation import matrix_to_quat

    q0 = matrix_to_quat(np.array(rot))
    ahead = quat_to_matrix(RotationHermite([t[0]], [q0], [av])([t[-1]])[0][0])
    wrong = quat_to_matrix(RotationHermite([t[0]], [q0], [-np.array(av)])([t[-1]])[0][0])
    # SPICE's own rounding noise of the lunar orientation is ~1e-13 rad
    assert angle_between(ahead, truth) < 1e-12
    assert angle_between(wrong, truth) > 1e-6  # the opposite sign is off by 2 |w| dt = 2.2e-6 rad


@pytest.mark.shared
def test_lro_body_rotation_from_ale_two_epochs_vs_spice(lro_set, lro_kernels):
    import spiceypy

    from lunarmap.spice import kernels

    isd = ImageSupport.read_json(lro_set / "ale_isd.json")
    assert len(json.loads((lro_set / "ale_isd.json").read_text())["body_rotation"]["ephemeris_times"]) == 2
    assert isd.body_frame == "MOON_ME" and isd.times.size == 401
    with kernels(lro_kernels):
        xf = np.array([spiceypy.sxform("J2000", "MOON_ME", et) for et in isd.times])
    ang = angle_between(isd.body_state_rotations[:, :3, :3], xf[:, :3, :3]).max()
    dr = np.abs(isd.body_state_rotations[:, 3:, :3] - xf[:, 3:, :3]).max()
    assert ang < 1e-12  # SPICE's own rounding noise is ~1e-13 rad
    assert dr < 1e-18
    print(f"LRO body rotation from 2 ALE epochs vs SPICE sxform: {ang:.1e} rad, dR/dt {dr:.1e} /s")


@pytest.mark.shared
def test_lro_ale_isd_camera_matches_kernel_camera(lro_set):
    from lunarmap.orientation.drivers import image_support

    isd = image_support(lro_set / "M103595705LE_isis3.lbl", lro_set / "lro_nac_M103595705LE.tm")
    ale_cam = camera_from_isd_file(lro_set / "ale_isd.json")
    assert ale_cam.interior.distortion_model == "lrolrocnac"
    ground_m, px, _ = compare_cameras(camera_from_isd(isd), ale_cam, isd.image_lines, isd.image_samples)
    assert px <= 1e-4
    assert ground_m < 1e-3
    print(f"LRO NAC, ALE's ISD vs kernels: {px:.2e} px, {ground_m:.2e} m")


@pytest.mark.shared
def test_lro_resampling_limited_by_ck_records(lro_set):
    """Real CK data: positions every 2nd epoch, pointing at the others, against ALE's full tables.

    LRO's CK (type 3) is piecewise geodesic, with angular-rate jumps of up to
    3e-5 rad/s at its records, 0.1 s apart. Spherical linear interpolation
    reproduces it between records to rounding; an interval of 2 ms that spans a
    record cannot know where the jump lies (nor can the camera's own
    interpolation between samples): about 1e-8 rad there.
    """
    doc = json.loads((lro_set / "ale_isd.json").read_text())
    full = copy.deepcopy(doc)
    n = len(doc["instrument_position"]["ephemeris_times"])
    pos_idx, att_idx = np.arange(0, n, 2), np.arange(1, n, 2)
    ip, pt = doc["instrument_position"], doc["instrument_pointing"]
    for key in ("ephemeris_times", "positions", "velocities"):
        ip[key] = [ip[key][i] for i in pos_idx]
    for key in ("ephemeris_times", "quaternions", "angular_velocities"):
        pt[key] = [pt[key][i] for i in att_idx]
    back = ImageSupport.from_ale_dict(doc)
    assert back.times.size == n
    dp = np.abs(back.positions - np.array(full["instrument_position"]["positions"])).max() * 1e3
    # pointing at the position epochs, where it was interpolated (or extrapolated, at the first one)
    da = quat_angle(back.pointing.quaternions, full["instrument_pointing"]["quaternions"])[pos_idx]
    assert dp < 1e-6  # m: ALE's positions are consistent with their velocities to 0.3 micrometre
    assert da.max() < 3e-8
    assert np.median(da) < 1e-14 and np.mean(da > 1e-9) < 0.05  # only intervals spanning a CK record
    print(f"LRO resampling: position {dp:.1e} m, pointing max {da.max():.1e} rad, median {np.median(da):.1e} rad, "
          f"{np.mean(da > 1e-9):.1%} of epochs above 1e-9 rad")


# -- Kaguya TC (kaguyalism) and Clementine UVVIS (radial), written by lunarmap, read back -----------

@pytest.mark.shared
@pytest.mark.parametrize("which", ["kaguya", "clementine"])
def test_shared_sets_written_and_read_back(which, kaguya_set, clementine_set, tmp_path):
    from lunarmap.orientation.drivers import image_support

    if which == "kaguya":
        label, mk, model = (kaguya_set / "TC1S2B0_01_06691S820E0465_pds3.lbl", kaguya_set / "kaguya_tc_TC1S2B0.tm",
                            "kaguyalism")
    else:
        label, mk, model = (clementine_set / "LUA3107H.161_isis3.lbl",
                            clementine_set / "clementine_uvvis_LUA3107H161.tm", "radial")
    isd = image_support(label, mk)
    path = tmp_path / "isd.json"
    isd.write_json(path)
    back = ImageSupport.read_json(path)
    assert back.optical_distortion == isd.optical_distortion and model in back.optical_distortion
    assert back.body_frame == isd.body_frame
    assert back.naif_keywords == isd.naif_keywords
    cam = camera_from_isd_file(path)
    assert cam.interior.distortion_model == model
    ground_m, px, _ = compare_cameras(camera_from_isd(isd), cam, isd.image_lines, isd.image_samples)
    assert px <= 1e-6 and ground_m < 1e-3
    print(f"{which}: {px:.2e} px, {ground_m:.2e} m")


# -- variable line rate ----------------------------------------------------------------------------

def test_multi_row_line_scan_rate_gives_the_right_line_times(sim_isds, tmp_path):
    isd, path = sim_isds["sim_nac_equator"]
    doc = json.loads(path.read_text())
    start, center = doc["starting_ephemeris_time"], doc["center_ephemeris_time"]
    dt = doc["line_scan_rate"][0][2]
    split, dt2 = 20000, 0.75 * dt  # lines from CSM line 20000 on are exposed faster
    doc["line_scan_rate"] = [[0.5, start - center, dt], [split + 0.5, start - center + split * dt, dt2]]
    edited = tmp_path / "two_rates.json"
    edited.write_text(json.dumps(doc))
    back = ImageSupport.read_json(edited)
    assert back.to_ale_dict()["line_scan_rate"] == doc["line_scan_rate"]
    cam = camera_from_isd_file(edited)
    epoch = cam.eo.epoch
    lines = np.array([0.0, 0.5, 1234.25, 19999.5, 20000.0, 20000.5, 40000.0, 52223.5])
    assert epoch == start
    expected = np.where(lines < split, lines * dt, split * dt + (lines - split) * dt2)  # s after the start
    assert np.abs(cam.image_time(lines) - expected).max() < 1e-12
    # the geometry follows: the sensor position of a line in the second segment, and back
    s = np.full(lines.size, 2500.0)
    assert np.abs(cam.sensor_position(lines, s) - cam.eo.position_at(expected)).max() < 1e-9
    ground = cam.image_to_ground(lines[1:], s[1:])
    line_back, _ = cam.ground_to_image(ground)
    assert np.abs(line_back - lines[1:]).max() < 1e-6
    # the single-rate camera puts line 40000 elsewhere (the test can tell)
    single = camera_from_isd(isd)
    assert abs(single.image_time(40000.0) - cam.image_time(40000.0)) > 1.0


# -- bad input -------------------------------------------------------------------------------------

def _edit(doc: dict, path: str, value) -> dict:
    """Set (or with value ``...`` delete) a dotted key path; ``[i]`` selects list items."""
    out = copy.deepcopy(doc)
    keys = path.split(".")
    node = out
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node[k]
    last = keys[-1]
    if value is ...:
        del node[last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return out


BAD_EDITS = [
    ("instrument_pointing", ..., "'instrument_pointing' is missing"),
    ("instrument_pointing.quaternions", ..., "'instrument_pointing.quaternions' is missing"),
    ("body_rotation.angular_velocities", ..., "'body_rotation.angular_velocities' is missing"),
    ("center_ephemeris_time", ..., "'center_ephemeris_time' is missing"),
    ("image_lines", "400", "'image_lines' must be an integer"),
    ("image_lines", True, "'image_lines' must be an integer"),
    ("image_lines", 0, "'image_lines' must be >= 1"),
    ("detector_line_summing", 1.5, "'detector_line_summing' must be an integer"),
    ("focal_length_model.focal_length", "699.62", "'focal_length_model.focal_length' must be a number"),
    ("instrument_position.positions", [[1.0, 2.0]], r"'instrument_position.positions' must have shape \(401, 3\)"),
    ("instrument_position.positions.3", [1.0, 2.0], "'instrument_position.positions' is a ragged list"),
    ("instrument_pointing.quaternions.0", [1.0, 0.0, 0.0], "'instrument_pointing.quaternions' is a ragged"),
    ("instrument_pointing.quaternions.7", [2.0, 0.0, 0.0, 0.0], "'instrument_pointing.quaternions' must hold unit"),
    ("instrument_position.velocities.5.1", "fast", "'instrument_position.velocities' must hold numbers only"),
    ("instrument_position.positions.0.2", 10 ** 400, "'instrument_position.positions' must hold finite numbers"),
    ("center_ephemeris_time", -(10 ** 400), "'center_ephemeris_time' must be a finite number"),
    ("instrument_position.ephemeris_times.3", 0.0, "'instrument_position.ephemeris_times' must be strictly"),
    ("instrument_position.reference_frame", 10020, "'instrument_position.reference_frame' is 10020"),
    ("body_rotation.constant_rotation", [1.0] * 9, "'body_rotation.constant_rotation' is not a rotation"),
    ("body_rotation.time_dependent_frames", [], "'body_rotation.time_dependent_frames' must be a non-empty"),
    ("name_model", "USGS_ASTRO_PROJECTED_SENSOR_MODEL", "'name_model' is 'USGS_ASTRO_PROJECTED_SENSOR_MODEL'"),
    # a NAC ISD relabelled SAR: a SAR ISD without range coefficients (issue 26)
    ("name_model", "USGS_ASTRO_SAR_SENSOR_MODEL", "'range_conversion_times' is missing"),
    ("optical_distortion", {"brown": {"x": [0.0], "y": [0.0]}},
     "'optical_distortion.brown' names a distortion model lunarmap does not know"),
    ("optical_distortion", {"lrolrocnac": {"coefficients": [1.0, 2.0]}},
     "'optical_distortion.lrolrocnac.coefficients' must hold 1 numbers, got 2"),
    ("optical_distortion", {"kaguyalism": {"x": [0.0]}}, "'optical_distortion.kaguyalism.y' is missing"),
    ("optical_distortion", {"transverse": {"x": [0.0] * 11, "y": [0.0]}},
     "'optical_distortion.transverse.x' must hold 1 to 10 numbers"),
    ("optical_distortion", {}, "'optical_distortion' must name exactly one model"),
    ("optical_distortion", [1.81e-05], "'optical_distortion' must be a JSON object"),
    ("line_scan_rate", [[0.5, -0.2, -0.001]], "'line_scan_rate' must have positive line periods"),
    ("line_scan_rate", [[0.5, -0.2]], r"'line_scan_rate' must have shape \(n, 3\)"),
    ("radii.semimajor", -1737.4, "'radii' must be positive"),
    ("focal2pixel_lines", [0.0, 0.0, 0.0], "'focal2pixel_lines' and focal2pixel_samples form a singular"),
    ("detector_center", 2547.5, "'detector_center' must be a JSON object"),
]


@pytest.mark.shared
@pytest.mark.parametrize("key, value, message", BAD_EDITS, ids=[f"{k}={v!r:.20}" for k, v, _ in BAD_EDITS])
def test_bad_isd_raises_isd_format_error_naming_file_and_key(lro_set, tmp_path, key, value, message):
    doc = json.loads((lro_set / "ale_isd.json").read_text())
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(_edit(doc, key, value)))
    before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in tmp_path.iterdir()}
    with pytest.raises(IsdFormatError, match=message) as info:
        camera_from_isd_file(path)
    assert str(path) in str(info.value)
    assert isinstance(info.value, (ValueError, LunarmapError))
    # a failed read writes nothing and changes nothing
    assert {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in tmp_path.iterdir()} == before


@pytest.mark.shared
def test_from_ale_dict_leaves_its_input_alone_and_names_no_file(lro_set):
    doc = json.loads((lro_set / "ale_isd.json").read_text())
    original = copy.deepcopy(doc)
    ImageSupport.from_ale_dict(doc)
    assert doc == original
    bad = _edit(doc, "image_samples", ...)
    with pytest.raises(IsdFormatError, match=r"ISD \(in memory\): key 'image_samples' is missing"):
        ImageSupport.from_ale_dict(bad)
    assert bad == _edit(original, "image_samples", ...)
    with pytest.raises(IsdFormatError, match="must be a JSON object, got list"):
        ImageSupport.from_ale_dict([doc])  # type: ignore[arg-type]


@pytest.mark.parametrize("text, message", [
    ('{"name_model": "USGS_ASTRO_FRAME_SENSOR_MODEL", ', "malformed JSON at line 1"),
    ("[1, 2, 3]", "the document must be a JSON object, got list"),
    ("", "malformed JSON"),
    ('{"name_model": NaN}', r"key 'name_model' holds a non-finite number \(nan\)"),
    ('{"naif_keywords": {"INS-85600_OD_K": Infinity}}', "key 'naif_keywords.INS-85600_OD_K' holds a non-finite"),
    ('{"instrument_position": {"positions": [[1, 2, -Infinity]]}}',
     r"key 'instrument_position.positions\[0\]\[2\]' holds a non-finite"),
])
def test_malformed_json(tmp_path, text, message):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(IsdFormatError, match=message) as info:
        ImageSupport.read_json(path)
    assert str(path) in str(info.value)
    assert [p.name for p in tmp_path.iterdir()] == ["bad.json"]


def test_non_utf8_and_missing_file(tmp_path):
    path = tmp_path / "latin1.json"
    path.write_bytes(b'{"name_sensor": "\xe9"}')
    with pytest.raises(IsdFormatError, match="not UTF-8"):
        ImageSupport.read_json(path)
    with pytest.raises(FileNotFoundError, match="nope.json"):
        camera_from_isd_file(tmp_path / "nope.json")


@pytest.mark.shared
def test_reading_needs_no_spice(lro_set):
    """With spiceypy made unimportable, the camera is still built from the file."""
    code = ("import sys; sys.modules['spiceypy'] = None\n"
            "from lunarmap.camera import camera_from_isd_file\n"
            f"cam = camera_from_isd_file({str(lro_set / 'ale_isd.json')!r})\n"
            "print(cam.image_to_ground(200.0, 2532.0).tolist())\n")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stderr
    assert len(json.loads(res.stdout)) == 3


@pytest.mark.shared
def test_pointing_without_angular_velocities(lro_set):
    """The pointing's angular velocities are optional: the quaternions alone make the camera."""
    doc = json.loads((lro_set / "ale_isd.json").read_text())
    with_rates = ImageSupport.from_ale_dict(doc)
    del doc["instrument_pointing"]["angular_velocities"]
    without = ImageSupport.from_ale_dict(doc)
    assert np.array_equal(without.pointing.quaternions, with_rates.pointing.quaternions)
    # derived from the samples' own motion: LRO turns at 8e-4 rad/s; the CK's rates differ by up to 3e-5
    assert np.abs(without.pointing.angular_velocities - with_rates.pointing.angular_velocities).max() < 5e-5
    line, sample = image_grid(without.image_lines, without.image_samples, 5)
    g1 = camera_from_isd(with_rates).image_to_ground(line, sample)
    g2 = camera_from_isd(without).image_to_ground(line, sample)
    assert np.abs(g1 - g2).max() < 1e-9
    body = _edit(json.loads((lro_set / "ale_isd.json").read_text()), "body_rotation.angular_velocities", ...)
    with pytest.raises(IsdFormatError, match="'body_rotation.angular_velocities' is missing"):
        ImageSupport.from_ale_dict(body)

"""Adjusted orientation written back: updated ISDs and SPICE kernels layered over the original set.

The oracle of every round trip is the perturbed exterior orientation itself (a known
correction applied to what the driver sampled): the new kernels are read back by the
*unchanged* driver through the new meta-kernel, and cameras built from that ISD are
compared with cameras built directly from the perturbed EO. Rotations of the
perturbation come from scipy (not lunarmap's helpers); spiceypy is asked directly where
SPICE's own reading of the files is the question.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest
import spiceypy
from scipy.spatial.transform import Rotation

from lunarmap.camera.factory import camera_from_isd, interior_from_isd, shape_from_isd
from lunarmap.camera.frame import FrameCamera
from lunarmap.camera.linescan import LineScanCamera, LineTimes
from lunarmap.errors import (InvalidInputError, LunarmapError, MissingClockError, OrientationConflictError,
                             OrientationCoverageError, TrajectoryFitError)
from lunarmap.orientation import ExteriorOrientation
from lunarmap.orientation import kernels as okernels
from lunarmap.orientation.drivers import image_support
from lunarmap.orientation.isd import ImageSupport
from lunarmap.orientation.kernels import write_orientation_kernels
from lunarmap.orientation.update import updated_image_support
from lunarmap.spice import SPICE_LOCK, KernelSet, clear, kernels
from lunarmap.spice.writer import CkSegment, write_ck, write_text_kernel
from lunarmap.synthetic import FRAME_CAMERA_ID, NAC_ID

ARCSEC = np.pi / 180.0 / 3600.0
SIM_IMAGES = ("sim_nac_equator", "sim_frame_a", "sim_frame_b")
MEASURED: dict[str, dict[str, float]] = {}  # printed by -s; the figures quoted in the report


# ----------------------------------------------------------------------------- helpers

def perturbed(eo: ExteriorOrientation, k: int = 1, t_ref: float | None = None) -> ExteriorOrientation:
    """``eo`` with a known correction: ~100 m offset + 0.5 m/s drift, ~50 urad rotation + 5 urad/s.

    The rotation is applied in the body-fixed frame (left), built by scipy from a rotation
    vector linear in time; ``k`` varies the correction between images. Time counts from
    ``eo.epoch``, or from the ephemeris time ``t_ref`` (one correction shared by several images).
    """
    t = eo.times if t_ref is None else eo.times + (eo.epoch - t_ref)
    offset = np.array([80.0, -60.0, 45.0]) * k
    drift = np.array([0.5, -0.3, 0.2]) * k
    rotvec = np.array([30e-6, -40e-6, 25e-6]) * k + np.outer(t, np.array([4e-6, 3e-6, -5e-6]) / k)
    rot = Rotation.from_rotvec(rotvec).as_matrix() @ eo.rotation_at(eo.times)
    quat = Rotation.from_matrix(rot).as_quat()[:, [3, 0, 1, 2]]
    return ExteriorOrientation(eo.epoch, eo.times, eo.positions + offset + np.outer(t, drift),
                               eo.velocities + drift, quat, eo.sun_times, eo.sun_positions, eo.body_frame,
                               dict(eo.attrs))


def direct_camera(isd: ImageSupport, eo: ExteriorOrientation) -> FrameCamera | LineScanCamera:
    """The camera built straight from an EO (no SPICE, no ISD positions or pointing)."""
    interior, shape = interior_from_isd(isd), shape_from_isd(isd)
    if isd.model == "frame":
        return FrameCamera(interior, eo, shape, time=isd.center_ephemeris_time - eo.epoch)
    return LineScanCamera(interior, eo, shape,
                          line_times=LineTimes.uniform(isd.starting_ephemeris_time - eo.epoch, isd.line_period))


def compare(reloaded: ImageSupport, isd: ImageSupport, eo: ExteriorOrientation) -> dict[str, float]:
    """Largest position (m), rotation (arcsec) and ground_to_image (px) differences."""
    got = reloaded.exterior_orientation(epoch=eo.epoch)
    assert np.array_equal(got.times, eo.times)
    dpos = float(np.max(np.linalg.norm(got.positions - eo.position_at(got.times), axis=1)))
    rel = np.swapaxes(got.rotation_at(got.times), 1, 2) @ eo.rotation_at(got.times)
    drot = float(np.max(Rotation.from_matrix(rel).magnitude())) / ARCSEC
    cam_k, cam_p = camera_from_isd(reloaded), direct_camera(isd, eo)
    # line scanners: 10.5 lines inside, since LineScanCamera.ground_to_image returns NaN for
    # Kaguya TC's first ~4.5 lines even with the original kernels (its search bracket)
    edge = 0.5 if isd.model == "frame" else 10.5
    lines = np.linspace(edge, isd.image_lines - edge, 9)
    samples = np.linspace(0.5, isd.image_samples - 0.5, 9)
    ll, ss = np.meshgrid(lines, samples, indexing="ij")
    worst_px = 0.0
    for h in (-2000.0, 0.0, 2000.0):
        ground = cam_p.image_to_ground(ll.ravel(), ss.ravel(), height=h)
        lk, sk = cam_k.ground_to_image(ground, within_image=False)
        lp, sp = cam_p.ground_to_image(ground, within_image=False)
        assert np.all(np.isfinite(lk)) and np.all(np.isfinite(lp))
        worst_px = max(worst_px, float(np.max(np.hypot(lk - lp, sk - sp))))
    return {"position_m": dpos, "rotation_arcsec": drot, "ground_to_image_px": worst_px}


def assert_reproduced(fig: dict[str, float]) -> None:
    assert fig["position_m"] <= 1e-3
    assert fig["rotation_arcsec"] <= 1e-3
    assert fig["ground_to_image_px"] <= 1e-4


def digests(kset: KernelSet) -> dict[str, str]:
    files = list(kset.paths) + ([kset.source] if kset.source else [])
    return {p: hashlib.sha256(Path(p).read_bytes()).hexdigest() for p in files}


def round_trip(labels: dict[str, Path], originals: dict[str, ImageSupport], base: KernelSet | Path,
               folder: Path, tag: str) -> dict[str, dict[str, float]]:
    """Perturb, write kernels, reload with the driver, compare; returns the figures per image."""
    kset = base if isinstance(base, KernelSet) else KernelSet.from_metakernel(base)
    before = digests(kset)
    pert = {n: perturbed(isd.exterior_orientation(), k + 1) for k, (n, isd) in enumerate(originals.items())}
    new = [updated_image_support(originals[n], pert[n]) for n in originals]
    mk = write_orientation_kernels(new, folder, base)
    assert sorted(p.name for p in folder.iterdir()) == ["adjusted.bc", "adjusted.bsp", "adjusted.tm"]
    assert digests(kset) == before  # the original kernel files are never modified
    figures = {}
    for n, isd in originals.items():
        reloaded = image_support(labels[n], mk)
        figures[n] = compare(reloaded, isd, pert[n])
        MEASURED[f"{tag}:{n}"] = figures[n]
        assert_reproduced(figures[n])
    return figures


# ----------------------------------------------------------------------------- fixtures

@pytest.fixture(scope="module")
def sim(sim_mission):
    folder = sim_mission.parent
    labels = {n: folder / f"{n}.lbl" for n in SIM_IMAGES}
    return labels, {n: image_support(labels[n], sim_mission) for n in SIM_IMAGES}


@pytest.fixture(scope="module")
def sim_lt(sim_mission, tmp_path_factory):
    """The synthetic mission with both cameras' positions LT+S corrected (an IK addendum loaded last)."""
    folder = tmp_path_factory.mktemp("lt_addendum")
    addendum = write_text_kernel(folder / "lt.ti", "IK", {f"INS{NAC_ID}_LIGHTTIME_CORRECTION": "LT+S",
                                                          f"INS{FRAME_CAMERA_ID}_LIGHTTIME_CORRECTION": "LT+S"})
    base = KernelSet.from_metakernel(sim_mission)
    kset = KernelSet(base.paths + (str(addendum),), "")
    labels = {n: sim_mission.parent / f"{n}.lbl" for n in ("sim_nac_85n", "sim_frame_a")}
    isds = {n: image_support(labels[n], kset) for n in labels}
    assert {i.provenance["position_correction"] for i in isds.values()} == {"LT+S"}
    return labels, isds, kset


# ----------------------------------------------------------------------------- updated_image_support

def test_updated_image_support_reproduces_the_eo_and_leaves_the_original(sim):
    _, isds = sim
    for k, (name, isd) in enumerate(isds.items()):
        keep = (isd.positions.copy(), isd.pointing.quaternions.copy(), isd.pointing.angular_velocities.copy())
        eo = perturbed(isd.exterior_orientation(), k + 1)
        new = updated_image_support(isd, eo)
        got = new.exterior_orientation(epoch=eo.epoch)
        dpos = np.max(np.linalg.norm(got.positions - eo.position_at(got.times), axis=1))
        dvel = np.max(np.linalg.norm(got.velocities - eo.velocity_at(got.times), axis=1))
        rel = np.swapaxes(got.rotation_at(got.times), 1, 2) @ eo.rotation_at(got.times)
        drot = np.max(Rotation.from_matrix(rel).magnitude())
        MEASURED[f"update:{name}"] = {"position_m": float(dpos), "velocity_m_s": float(dvel), "rotation_rad": float(drot)}
        assert dpos <= 1e-6 and dvel <= 1e-9 and drot <= 1e-12
        assert np.array_equal(isd.positions, keep[0]) and np.array_equal(isd.pointing.quaternions, keep[1])
        assert np.array_equal(isd.pointing.angular_velocities, keep[2])
        assert new.provenance["orientation"] == "adjusted" and "orientation" not in isd.provenance
        assert np.array_equal(new.times, isd.times) and np.array_equal(new.sun_positions, isd.sun_positions)


def _rates_by_differences(isd: ImageSupport) -> np.ndarray:
    """Angular velocities from central differences of the pointing nodes: [w]x = dQ^T Q."""
    q = Rotation.from_quat(isd.pointing.quaternions[:, [1, 2, 3, 0]]).as_matrix()
    dq = (q[2:] - q[:-2]) / (isd.times[2:] - isd.times[:-2])[:, None, None]
    s = np.swapaxes(dq, 1, 2) @ q[1:-1]
    return 0.5 * np.stack([s[:, 2, 1] - s[:, 1, 2], s[:, 0, 2] - s[:, 2, 0], s[:, 1, 0] - s[:, 0, 1]], axis=1)


def test_updated_angular_velocities(sim):
    _, isds = sim
    nac = isds["sim_nac_equator"]
    # the convention, against SPICE's own xf2rav rates in the original ISD
    assert np.max(np.abs(_rates_by_differences(nac) - nac.pointing.angular_velocities[1:-1])) < 2e-9
    new = updated_image_support(nac, perturbed(nac.exterior_orientation()))
    change = new.pointing.angular_velocities - nac.pointing.angular_velocities
    expected = _rates_by_differences(new) - _rates_by_differences(nac)
    err = float(np.max(np.abs(change[1:-1] - expected)))
    MEASURED["update:rate_change_error_rad_s"] = {"max": err, "change": float(np.max(np.abs(change)))}
    assert np.max(np.abs(change)) > 1e-6 and err < 1e-9
    # a frame image's correction is constant: the bus keeps its own rotation
    frame = isds["sim_frame_a"]
    same = updated_image_support(frame, perturbed(frame.exterior_orientation()))
    assert np.array_equal(same.pointing.angular_velocities, frame.pointing.angular_velocities)


def test_updated_image_support_refuses_an_eo_that_misses_the_epochs(sim):
    _, isds = sim
    nac = isds["sim_nac_equator"]
    eo = nac.exterior_orientation()
    short = ExteriorOrientation(eo.epoch, eo.times[:-5], eo.positions[:-5], eo.velocities[:-5],
                                eo.quaternions[:-5], eo.sun_times, eo.sun_positions, eo.body_frame)
    with pytest.raises(OrientationCoverageError, match="sim_nac_equator"):
        updated_image_support(nac, short)
    other = ExteriorOrientation(eo.epoch, eo.times, eo.positions, eo.velocities, eo.quaternions,
                                eo.sun_times, eo.sun_positions, "MOON_ME")
    with pytest.raises(OrientationCoverageError, match="body frame"):
        updated_image_support(nac, other)
    frame = isds["sim_frame_a"].exterior_orientation()
    moved = ExteriorOrientation(frame.epoch + 0.01, frame.times, frame.positions, frame.velocities,
                                frame.quaternions, frame.sun_times, frame.sun_positions, frame.body_frame)
    with pytest.raises(OrientationCoverageError):
        updated_image_support(isds["sim_frame_a"], moved)


def test_adjusted_isd_json(sim, tmp_path):
    import json
    _, isds = sim
    frame = isds["sim_frame_b"]
    new = updated_image_support(frame, perturbed(frame.exterior_orientation()))
    new.write_json(tmp_path / "adjusted.json")
    doc = json.loads((tmp_path / "adjusted.json").read_text())
    assert np.allclose(doc["instrument_position"]["positions"], new.positions, rtol=0, atol=1e-12)
    assert doc["lunarmap"]["orientation"] == "adjusted"
    assert not np.allclose(doc["instrument_position"]["positions"], frame.positions, rtol=0, atol=1e-3)


# ----------------------------------------------------------------------------- kernels: round trips

def test_synthetic_round_trip_through_new_kernels(sim, sim_mission, tmp_path):
    labels, isds = sim
    figures = round_trip(labels, isds, sim_mission, tmp_path, "sim NONE")
    assert set(figures) == set(SIM_IMAGES)


def test_synthetic_light_time_corrected_round_trip(sim_lt, tmp_path):
    labels, isds, kset = sim_lt
    round_trip(labels, isds, kset, tmp_path, "sim LT+S")
    comments = (tmp_path / "adjusted.tm").read_text()
    assert "pass(es)" in comments


@pytest.mark.shared
def test_lro_nac_round_trip(lro_set, tmp_path):
    label = lro_set / "M103595705LE_isis3.lbl"
    mk = lro_set / "lro_nac_M103595705LE.tm"
    isd = image_support(label, mk)
    round_trip({"nac": label}, {"nac": isd}, mk, tmp_path, "LRO NAC")
    # the NAC-L CK frame now hangs directly off J2000 where the new CK has data
    assert image_support(label, tmp_path / "adjusted.tm").pointing.time_dependent_frames == [-85600, 1]


@pytest.mark.shared
def test_kaguya_surface_light_time_round_trip(kaguya_set, tmp_path):
    label = kaguya_set / "TC1S2B0_01_06691S820E0465_pds3.lbl"
    mk = kaguya_set / "kaguya_tc_TC1S2B0.tm"
    isd = image_support(label, mk)
    assert isd.provenance["position_correction"] == "SURFACE"
    round_trip({"tc1": label}, {"tc1": isd}, mk, tmp_path, "Kaguya TC SURFACE")


@pytest.mark.shared
def test_clementine_frame_round_trip(clementine_set, tmp_path):
    # a frame camera on a bus through two TK frames: the CK is the bus's
    label = clementine_set / "LUA3107H.161_isis3.lbl"
    mk = clementine_set / "clementine_uvvis_LUA3107H161.tm"
    isd = image_support(label, mk)
    assert len(isd.pointing.constant_frames) == 3
    round_trip({"uvvis": label}, {"uvvis": isd}, mk, tmp_path, "Clementine UVVIS")


# ----------------------------------------------------------------------------- kernels: SPICE's own reading

def test_metakernel_layers_over_the_original_set_in_plain_spice(sim, sim_mission, tmp_path):
    _, isds = sim
    frame = isds["sim_frame_a"]
    eo = perturbed(frame.exterior_orientation())
    new = updated_image_support(frame, eo)
    mk = write_orientation_kernels([new], tmp_path, sim_mission, margin=0.5)
    et, far = float(frame.times[0]), float(frame.times[0]) + 100.0
    with kernels(KernelSet.from_metakernel(sim_mission)):
        original_far = np.array(spiceypy.spkez(-990, far, "J2000", "NONE", 301)[0])
        original_bus = np.array(spiceypy.pxform("J2000", "SIM_SC_BUS", far))
    with SPICE_LOCK:
        try:
            clear()
            spiceypy.furnsh(str(mk))  # plain SPICE: the new meta-kernel lists absolute paths
            # outside the new segments the original kernels answer, bit for bit
            assert np.array_equal(spiceypy.spkez(-990, far, "J2000", "NONE", 301)[0], original_far)
            assert np.array_equal(spiceypy.pxform("J2000", "SIM_SC_BUS", far), original_bus)
            state = np.array(spiceypy.spkez(-990, et, "J2000", "NONE", 301)[0])
            assert np.max(np.abs(state[:3] - new.positions[0])) < 1e-12
            # inside the margin: the straight line of the record's position and velocity ...
            later = et + 0.3
            inside = np.array(spiceypy.spkez(-990, later, "J2000", "NONE", 301)[0])
            step = later - et  # exact: ET near 8e8 s is spaced 1.2e-7 s, i.e. 0.2 mm of flight
            assert np.max(np.abs(inside[:3] - (new.positions[0] + step * new.velocities[0]))) < 1e-9
            # ... and the attitude turning at the record's angular velocity (sign checked by differences)
            # (between the records the rotation has a constant rate, so a long step is exact)
            tp, tm, t0 = et + 0.3, et + 0.1, et + 0.2
            qp, qm, q0 = (np.array(spiceypy.pxform("J2000", "SIM_SC_BUS", t)) for t in (tp, tm, t0))
            s = ((qp - qm) / (tp - tm)).T @ q0
            rate = 0.5 * np.array([s[2, 1] - s[1, 2], s[0, 2] - s[2, 0], s[1, 0] - s[0, 1]])
            w = new.pointing.angular_velocities[0]
            assert np.linalg.norm(rate - w) < 1e-6 * np.linalg.norm(w)
            cover = spiceypy.spkcov(str(tmp_path / "adjusted.bsp"), -990)
            assert spiceypy.wncard(cover) == 1
            assert np.allclose(spiceypy.wnfetd(cover, 0), (et - 0.5, et + 0.5), rtol=0, atol=1e-6)
        finally:
            clear()


def test_frame_taken_during_a_pushbroom_image_on_one_bus(sim, sim_mission, tmp_path):
    """Two instruments on one bus, simultaneous: one correction for both merges, two conflict."""
    labels, isds = sim
    nac = isds["sim_nac_equator"]
    text = labels["sim_frame_a"].read_text()
    nac_clock = re.search(r"SpacecraftClockStartCount\s*=\s*1/(\d+):(\d+)", labels["sim_nac_equator"].read_text())
    during = f"1/{int(nac_clock.group(1)) + 5:010d}:{nac_clock.group(2)}"
    label = tmp_path / "sim_frame_during.lbl"
    label.write_text(re.sub(r"(SpacecraftClockStartCount\s*=\s*)\S+", lambda m: m.group(1) + during, text))
    frame = image_support(label, sim_mission)
    assert nac.times[0] + 4.0 < frame.times[0] < nac.times[-1] - 4.0
    out = tmp_path / "kernels"
    out.mkdir()
    t_ref = float(nac.times[0])
    pairs = {"nac": (labels["sim_nac_equator"], nac), "frame": (label, frame)}
    shared = {n: perturbed(isd.exterior_orientation(), 1, t_ref) for n, (_, isd) in pairs.items()}
    mk = write_orientation_kernels([updated_image_support(isd, shared[n]) for n, (_, isd) in pairs.items()],
                                   out, sim_mission)
    for n, (lab, isd) in pairs.items():
        MEASURED[f"merged on one bus:{n}"] = fig = compare(image_support(lab, mk), isd, shared[n])
        assert_reproduced(fig)
    # adjusted independently: the spacecraft cannot be in two places ...
    other = perturbed(frame.exterior_orientation(), 2, t_ref)
    with pytest.raises(OrientationConflictError, match="spacecraft -990"):
        write_orientation_kernels([updated_image_support(nac, shared["nac"]), updated_image_support(frame, other)],
                                  out, sim_mission, name="conflict")
    # ... nor the bus in two attitudes
    eo = frame.exterior_orientation()
    turned = ExteriorOrientation(eo.epoch, eo.times, shared["frame"].positions, shared["frame"].velocities,
                                 other.quaternions, eo.sun_times, eo.sun_positions, eo.body_frame)
    with pytest.raises(OrientationConflictError, match="CK frame -990000"):
        write_orientation_kernels([updated_image_support(nac, shared["nac"]), updated_image_support(frame, turned)],
                                  out, sim_mission, name="conflict")
    assert sorted(p.name for p in out.iterdir()) == ["adjusted.bc", "adjusted.bsp", "adjusted.tm"]


def test_two_identical_images_merge_and_an_agreeing_overlap_is_kept(sim, sim_mission, tmp_path):
    labels, isds = sim
    frame = isds["sim_frame_b"]
    eo = perturbed(frame.exterior_orientation())
    new = updated_image_support(frame, eo)
    mk = write_orientation_kernels([new, new], tmp_path, sim_mission)
    fig = compare(image_support(labels["sim_frame_b"], mk), frame, eo)
    assert_reproduced(fig)


# ----------------------------------------------------------------------------- kernels: refusals, atomicity

def test_conflicting_overlaps_are_refused(sim, sim_mission, tmp_path):
    _, isds = sim
    frame = isds["sim_frame_a"]
    eo = frame.exterior_orientation()
    one = updated_image_support(frame, perturbed(eo, 1))
    other = updated_image_support(frame, perturbed(eo, 2))
    with pytest.raises(OrientationConflictError, match="spacecraft -990"):
        write_orientation_kernels([one, other], tmp_path, sim_mission)
    # same trajectory, different attitude: two instruments on one bus cannot both be right
    turned = ExteriorOrientation(eo.epoch, eo.times, perturbed(eo, 1).positions, perturbed(eo, 1).velocities,
                                 perturbed(eo, 2).quaternions, eo.sun_times, eo.sun_positions, eo.body_frame)
    with pytest.raises(OrientationConflictError, match="CK frame -990000"):
        write_orientation_kernels([one, updated_image_support(frame, turned)], tmp_path, sim_mission)
    assert list(tmp_path.iterdir()) == []


def test_the_run_writes_simultaneous_images_adjusted_apart_into_separate_kernel_sets(sim, sim_mission, tmp_path):
    """LRO NAC-L and NAC-R adjusted apart: one spacecraft cannot have two trajectories in one SPK, so the run's
    kernels step writes one set per group of images that do not overlap in time, each reproducing its images."""
    from lunarmap.workflows.steps import Done, kernel_sets, kernels_step
    from lunarmap.workflows.store import Store

    labels, isds = sim
    frame = isds["sim_frame_a"]
    eo = frame.exterior_orientation()
    eos = {"left": perturbed(eo, 1), "right": perturbed(eo, 2),
           "later": perturbed(isds["sim_frame_b"].exterior_orientation(), 1)}
    adjusted = {"left": updated_image_support(frame, eos["left"]), "right": updated_image_support(frame, eos["right"]),
                "later": updated_image_support(isds["sim_frame_b"], eos["later"])}
    folder = tmp_path / "adjustment"
    folder.mkdir()
    for n, isd in adjusted.items():
        isd.write_json(folder / f"{n}.adjusted.json")
    names = list(adjusted)
    sets = kernel_sets([adjusted[n] for n in names])
    assert not any(0 in g and 1 in g for g in sets)                  # the simultaneous images apart
    d = kernels_step(Store(tmp_path / "store"), "k", names, Done("adjust", "a", "", str(folder), True), [],
                     str(sim_mission))
    index = json.loads(Path(d.path).read_text())
    assert index["left"] != index["right"] and len(set(index.values())) == 2
    for n in names:
        label = labels["sim_frame_a" if n != "later" else "sim_frame_b"]
        assert_reproduced(compare(image_support(label, Path(d.path).parent / index[n]), adjusted[n], eos[n]))


def test_bad_input_is_refused_by_name(sim, sim_mission, tmp_path):
    _, isds = sim
    new = updated_image_support(isds["sim_frame_a"], isds["sim_frame_a"].exterior_orientation())
    with pytest.raises(InvalidInputError, match="does not exist"):
        write_orientation_kernels([new], tmp_path / "missing", sim_mission)
    with pytest.raises(InvalidInputError, match="no image support"):
        write_orientation_kernels([], tmp_path, sim_mission)
    for bad in ("../up", "a b", ""):
        with pytest.raises(InvalidInputError, match="base name"):
            write_orientation_kernels([new], tmp_path, sim_mission, name=bad)
    for bad in (-1.0, float("nan")):
        with pytest.raises(InvalidInputError, match="margin"):
            write_orientation_kernels([new], tmp_path, sim_mission, margin=bad)
    with pytest.raises(InvalidInputError, match="part of the original kernel set"):
        write_orientation_kernels([new], sim_mission.parent, sim_mission, name="lunarmap_sim_orbit")
    bare = dataclasses.replace(new, provenance={})
    with pytest.raises(InvalidInputError, match="position_correction"):
        write_orientation_kernels([bare], tmp_path, sim_mission)
    assert list(tmp_path.iterdir()) == []


def test_missing_clock_is_named(sim, sim_mission, tmp_path):
    _, isds = sim
    new = updated_image_support(isds["sim_frame_a"], isds["sim_frame_a"].exterior_orientation())
    full = KernelSet.from_metakernel(sim_mission)
    no_clock = KernelSet(tuple(p for p in full.paths if not p.endswith(".tsc")), "")
    with pytest.raises(MissingClockError, match="clock -990"):
        write_orientation_kernels([new], tmp_path, no_clock)
    assert list(tmp_path.iterdir()) == []


def test_unconverged_light_time_fit_leaves_nothing(sim_lt, tmp_path, monkeypatch):
    _, isds, kset = sim_lt
    frame = isds["sim_frame_a"]
    new = updated_image_support(frame, perturbed(frame.exterior_orientation()))
    monkeypatch.setattr(okernels, "MAX_FIT_ITERATIONS", 1)
    with pytest.raises(TrajectoryFitError, match="sim_frame_a"):
        write_orientation_kernels([new], tmp_path, kset)
    assert list(tmp_path.iterdir()) == []


def test_failing_ck_leaves_no_new_file_and_keeps_an_earlier_set(sim, sim_mission, tmp_path, monkeypatch):
    _, isds = sim
    frame = isds["sim_frame_a"]
    first = write_orientation_kernels([updated_image_support(frame, perturbed(frame.exterior_orientation(), 1))],
                                      tmp_path, sim_mission)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    real = okernels.write_ck

    def failing(path, *args, **kwargs):
        if Path(path).parent == tmp_path:  # the final CK, after the SPK has been written
            raise LunarmapError("disk full (simulated)")
        return real(path, *args, **kwargs)

    monkeypatch.setattr(okernels, "write_ck", failing)
    with pytest.raises(LunarmapError, match="simulated"):
        write_orientation_kernels([updated_image_support(frame, perturbed(frame.exterior_orientation(), 2))],
                                  tmp_path, sim_mission)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    assert first == tmp_path / "adjusted.tm"


def test_ck_segment_clock_overrides_the_file_default(sim_mission, tmp_path):
    # every real set here uses SPICE's default clock (id / 1000), so the round trips cannot tell
    kset = KernelSet.from_metakernel(sim_mission)
    et = 827324897.5 + np.array([0.0, 1.0])
    seg = CkSegment(-990000, "J2000", et, [[1.0, 0, 0, 0]] * 2, [[0.0, 0, 0]] * 2, "clock test", sclk_id=-990)
    with kernels(kset):
        write_ck(tmp_path / "a.bc", [seg], time_kernels=[], sclk_id=-123456)  # no such clock: unused
        with pytest.raises(LunarmapError, match="-123456"):
            write_ck(tmp_path / "b.bc", [dataclasses.replace(seg, sclk_id=None)], time_kernels=[], sclk_id=-123456)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bc"]


def test_report_measured_figures():
    """Print what the round trips measured (run with -s); always passes."""
    for key, fig in sorted(MEASURED.items()):
        print(key, {k: f"{v:.3g}" for k, v in fig.items()})

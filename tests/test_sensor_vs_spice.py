"""Rigorous sensor models built from SPICE, against SPICE's own ``sincpt``.

The synthetic mission's kernels are the truth. For each pixel the test derives
the sensor-frame look direction and the exposure time itself, from the raw IK
keywords and the label's clock string (not through lunarmap's drivers), asks
``spiceypy.sincpt`` for the surface point, and compares it with lunarmap's
``image_to_ground`` (distortion off, since sincpt is a pinhole model).
"""

from __future__ import annotations

import numpy as np
import pytest
import spiceypy

from lunarmap.camera.factory import camera_from_isd
from lunarmap.camera.geodesy import xyz_to_lonlat_height
from lunarmap.errors import InvalidInputError, KernelCoverageError, MissingKernelError, UnknownInstrumentError
from lunarmap.labels import load_label
from lunarmap.orientation.drivers import image_support
from lunarmap.spice import KernelSet, kernels

IMAGES = ["sim_nac_equator", "sim_nac_flipped", "sim_nac_85n", "sim_frame_a", "sim_frame_b"]


@pytest.fixture(scope="module")
def cameras(sim_mission):
    folder = sim_mission.parent
    out = {}
    for name in IMAGES:
        isd = image_support(folder / f"{name}.lbl", sim_mission)
        out[name] = (isd, camera_from_isd(isd, distortion=False), camera_from_isd(isd))
    return out


def _ik(ikid: int, key: str) -> np.ndarray:
    return np.asarray(spiceypy.gdpool(f"INS{ikid}_{key}", 0, 10), dtype=float)


@pytest.mark.parametrize("name", IMAGES)
def test_image_to_ground_equals_sincpt(name, sim_mission, cameras):
    isd, cam, _ = cameras[name]
    inst = load_label(sim_mission.parent / f"{name}.lbl")["IsisCube"]
    ikid = int(inst["Kernels"]["NaifFrameCode"])
    rng = np.random.default_rng(7)
    n_lines, n_samples = isd.image_lines, isd.image_samples
    with kernels(KernelSet.from_metakernel(sim_mission)):
        frame = spiceypy.frmnam(ikid)
        f = _ik(ikid, "FOCAL_LENGTH")[0]
        itranss, itransl = _ik(ikid, "ITRANSS"), _ik(ikid, "ITRANSL")
        bs, bl = _ik(ikid, "BORESIGHT_SAMPLE")[0] - 0.5, _ik(ikid, "BORESIGHT_LINE")[0]
        start = spiceypy.scs2e(-990, str(inst["Instrument"]["SpacecraftClockStartCount"]))
        linescan = "LineExposureDuration" in inst["Instrument"]
        if linescan:
            dt = float(inst["Instrument"]["LineExposureDuration"]) * 1e-3
            boresight = (n_lines / 2.0, bs)
        else:
            bl -= 0.5
            dt = 0.0
            start += float(inst["Instrument"].get("ExposureDuration", 0.0)) * 1e-3 / 2
            boresight = (bl, bs)
        lines = np.concatenate([[boresight[0]], rng.uniform(0, n_lines, 100)])
        samples = np.concatenate([[boresight[1]], rng.uniform(0, n_samples, 100)])
        # focal plane from the IK's affine transform, solved for (x, y)
        a = np.array([[itransl[1], itransl[2]], [itranss[1], itranss[2]]])
        det_line = np.zeros_like(lines) if linescan else lines - bl
        xy = np.linalg.solve(a, np.stack([det_line - itransl[0], samples - bs - itranss[0]]))
        truth = []
        for i in range(lines.size):
            et = start + lines[i] * dt if linescan else start
            d = np.array([xy[0, i], xy[1, i], f])
            spoint = spiceypy.sincpt("ELLIPSOID", "MOON", et, "IAU_MOON", "NONE", "LUNARMAP-SIM", frame, d)[0]
            truth.append(np.asarray(spoint) * 1000.0)
        if not linescan:
            bore = spiceypy.getfov(ikid, 10)[2]
            bore_pt = spiceypy.sincpt("ELLIPSOID", "MOON", start, "IAU_MOON", "NONE", "LUNARMAP-SIM", frame, bore)[0]
    ours = cam.image_to_ground(lines, samples)
    err = np.linalg.norm(ours - np.array(truth), axis=1)
    assert err.max() <= 1e-3, f"{name}: max {err.max() * 1e3:.3f} mm"
    if not linescan:  # the IK boresight vector is the detector centre
        assert np.linalg.norm(ours[0] - np.asarray(bore_pt) * 1000) <= 1e-3


@pytest.mark.parametrize("name", IMAGES)
@pytest.mark.parametrize("height", [-2000.0, 0.0, 2000.0])
def test_ground_to_image_round_trip_full_image(name, height, cameras):
    isd, _, cam = cameras[name]  # with distortion
    rng = np.random.default_rng(3)
    lines = rng.uniform(0, isd.image_lines, 2000)
    samples = rng.uniform(0, isd.image_samples, 2000)
    xyz = cam.image_to_ground(lines, samples, height=height)
    l2, s2 = cam.ground_to_image(xyz)
    assert np.abs(l2 - lines).max() <= 1e-4 and np.abs(s2 - samples).max() <= 1e-4


def test_images_are_where_their_names_say(cameras):
    lat = {name: xyz_to_lonlat_height(cam.image_to_ground([isd.image_lines / 2], [isd.image_samples / 2]))[1][0]
           for name, (isd, cam, _) in cameras.items()}
    assert abs(lat["sim_nac_85n"] - 85.0) < 1.0
    assert abs(lat["sim_nac_equator"]) < 1.0 and abs(lat["sim_nac_flipped"]) < 1.0


def test_flipped_image_scans_the_other_way(cameras):
    """In the yawed image, increasing sample runs the opposite way relative to the flight direction."""
    def cross_track_sign(name):
        isd, cam, _ = cameras[name]
        p = cam.image_to_ground([100.0, 100.0, 5000.0], [100.0, 4900.0, 100.0])
        along = p[2] - p[0]
        across = p[1] - p[0]
        up = p[0] / np.linalg.norm(p[0])
        return np.sign(np.dot(np.cross(along, across), up))

    assert cross_track_sign("sim_nac_equator") == -cross_track_sign("sim_nac_flipped")


# -- bad input: each raises a specific lunarmap exception naming the cause -------------------

def _label_copy(sim_mission, tmp_path, name, replace):
    text = (sim_mission.parent / f"{name}.lbl").read_text()
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / f"{name}.lbl"
    path.write_text(text)
    return path


def test_time_outside_coverage(sim_mission, tmp_path):
    text = (sim_mission.parent / "sim_frame_a.lbl").read_text()
    clock = [ln.split("=")[1].strip() for ln in text.splitlines() if "SpacecraftClockStartCount" in ln][0]
    label = _label_copy(sim_mission, tmp_path, "sim_frame_a", {clock: "1/0000000001:00000"})
    with pytest.raises(KernelCoverageError, match=r"ET -?\d+"):
        image_support(label, sim_mission)


def test_unknown_instrument_id(sim_mission, tmp_path):
    label = _label_copy(sim_mission, tmp_path, "sim_frame_a", {"-990200": "-990777"})
    with pytest.raises(UnknownInstrumentError, match="-990777"):
        image_support(label, sim_mission)


def test_missing_kernel_file(sim_mission, tmp_path):
    import shutil

    copy = tmp_path / "mission"
    shutil.copytree(sim_mission.parent, copy)
    (copy / "lunarmap_sim_bus.bc").unlink()
    with pytest.raises(MissingKernelError, match="lunarmap_sim_bus.bc"):
        image_support(copy / "sim_frame_a.lbl", copy / sim_mission.name)


def test_nan_pixel(cameras):
    _, cam, _ = cameras["sim_nac_equator"]
    with pytest.raises(InvalidInputError):
        cam.image_to_ground([np.nan], [10.0])
    with pytest.raises(InvalidInputError):
        cam.ground_to_image(np.array([[np.nan, 0.0, 0.0]]))


def test_synthetic_cameras_carry_their_ik_distortion(cameras):
    assert cameras["sim_nac_equator"][0].optical_distortion == {"lrolrocnac": {"coefficients": [1.81e-05]}}
    assert cameras["sim_frame_a"][0].optical_distortion == {"radial": {"coefficients": [0.0, -2.42e-05, 0.0]}}
    # and the distorted model really differs from the pinhole one away from the centre
    _, pinhole, distorted = cameras["sim_frame_a"]
    d = np.linalg.norm(pinhole.image_to_ground([5.0], [5.0]) - distorted.image_to_ground([5.0], [5.0]))
    assert d > 1.0


@pytest.mark.parametrize("name", IMAGES)
def test_image_edges_and_corners_round_trip(name, cameras):
    """The first and last lines too: a sampled EO grid in absolute ET ends ~1e-8 s short of them."""
    isd, _, cam = cameras[name]
    nl, ns = isd.image_lines, isd.image_samples
    lines = np.array([0.0, 0.5, 0.5, nl - 0.5, nl - 0.5, nl - 0.01, nl, nl / 2])
    samples = np.array([0.0, 0.5, ns - 0.5, 0.5, ns - 0.5, 10.0, ns, 0.0])
    xyz = cam.image_to_ground(lines, samples)
    l2, s2 = cam.ground_to_image(xyz)
    assert np.abs(l2 - lines).max() <= 1e-4 and np.abs(s2 - samples).max() <= 1e-4

"""A reconstructed Ranger sequence written as SPICE kernels: loaded back like any mission, then adjusted.

Oracle: the flight-parameter cameras (five rotations) that were written; the round trip
kernels -> labels -> generic driver -> camera must reproduce them (<= 1 mm, <= 0.001 arcsec). The
adjustment path is checked against simulated truth.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import lunarmap
from lunarmap.adjust import ControlNetwork, NavigationSpec, build_block
from lunarmap.errors import FlightParameterError, KernelError
from lunarmap.missions import FlightParameters
from lunarmap.missions.flight_parameters import COLUMNS
from lunarmap.missions.ranger_kernels import load_ranger_cameras, write_ranger_kernels
from lunarmap.missions.ranger_simulation import ranger_sequence

PHOTOS = ("431", "433", "435", "437", "439")
ARCSEC = np.pi / 180 / 3600


@pytest.fixture(scope="module")
def seq():
    return ranger_sequence(photos=PHOTOS)


@pytest.fixture(scope="module")
def written(seq, tmp_path_factory):
    folder = tmp_path_factory.mktemp("ranger")
    return write_ranger_kernels(seq.table, seq.camera, folder), folder


def test_kernel_set_contents(written):
    ks, folder = written
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted([f"{p}.lbl" for p in PHOTOS] + ["ranger.bc", "ranger.bsp", "ranger.tf", "ranger.tls",
                                                           "ranger.tm", "ranger.tpc", "ranger.tsc",
                                                           "ranger_981002.ti", "ranger_planets.bsp"])
    assert ks.metakernel == folder / "ranger.tm" and set(ks.labels) == set(PHOTOS)


def test_kernels_reproduce_the_flight_parameter_cameras(seq, written):
    ks, _ = written
    cams = load_ranger_cameras(ks)
    worst_pos = worst_rot = worst_ground = worst_px = 0.0
    n = seq.camera.size
    lines = np.array([0.5, n - 0.5, 0.5, n - 0.5, n / 2, 1234.5])
    samples = np.array([0.5, 0.5, n - 0.5, n - 0.5, n / 2, 15000.25])
    for photo in PHOTOS:
        cam, ref = cams[photo], seq.cameras[photo]
        assert cam.interior.focal_length == ref.interior.focal_length
        worst_pos = max(worst_pos, float(np.linalg.norm(cam.sensor_position(0.0, 0.0) - ref.sensor_position(0.0, 0.0))))
        a = cam.look_vector(lines, samples)
        b = ref.look_vector(lines, samples)
        ang = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ni,ni->n", a, b))  # exact for tiny angles
        worst_rot = max(worst_rot, float(ang.max()))
        ga, gb = cam.image_to_ground(lines, samples), ref.image_to_ground(lines, samples)
        worst_ground = max(worst_ground, float(np.abs(ga - gb).max()))
        l2, s2 = cam.ground_to_image(gb)
        worst_px = max(worst_px, float(max(np.abs(l2 - lines).max(), np.abs(s2 - samples).max())))
    print(f"kernels -> cameras vs flight parameters: position {worst_pos * 1e3:.2e} mm, look vectors "
          f"{worst_rot / ARCSEC:.2e} arcsec, ground {worst_ground * 1e3:.2e} mm, {worst_px:.2e} px")
    assert worst_pos <= 1e-3 and worst_rot <= 1e-3 * ARCSEC and worst_ground <= 1e-3 and worst_px <= 1e-4


def test_lunarmap_isd_on_a_ranger_label(written, tmp_path):
    ks, _ = written
    out = tmp_path / "439.json"
    res = subprocess.run([sys.executable, "-m", "lunarmap", "isd", str(ks.labels["439"]), "--kernels",
                          str(ks.metakernel), "-o", str(out)], capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    isd = json.loads(out.read_text())
    assert isd["name_platform"] == "RANGER 9" and isd["center_ephemeris_time"] == ks.et["439"]
    assert isd["lunarmap"]["driver"] == "generic" and isd["radii"]["semimajor"] == 1736.6


def test_writing_refuses_bad_input_and_leaves_nothing(seq, tmp_path):
    cols = {c: getattr(seq.table, c) for c in COLUMNS}
    no_times = FlightParameters.from_columns({"photo": seq.table.photo, **cols}, radius=seq.table.radius)
    with pytest.raises(FlightParameterError, match="needs the exposure times"):
        write_ranger_kernels(no_times, seq.camera, tmp_path / "a")
    with pytest.raises(KernelError, match="-981xxx"):
        write_ranger_kernels(seq.table, seq.camera, tmp_path / "b", camera_id=-990200)
    same = FlightParameters.from_columns({"photo": seq.table.photo, **cols, "et": np.full(len(PHOTOS), 1e8)},
                                         radius=seq.table.radius)
    with pytest.raises(FlightParameterError, match="share one clock tick"):
        write_ranger_kernels(same, seq.camera, tmp_path / "c")
    assert not any(p.is_file() for p in tmp_path.rglob("*"))


def test_reconstructed_sequence_goes_through_the_block_adjustment(seq, tmp_path):
    """Navigation = flight parameters with errors (AZN/AZSC 0.005 deg, LATs/LONs 0.0005 deg, R 30 m), written as
    kernels and loaded from the labels; tie points measured on the true cameras (0.33 mm on the print), 6 control
    points (5 m), 34 check points; 6 exterior-orientation corrections per photo with navigation observations."""
    rng = np.random.default_rng(5)
    t = seq.table
    cols = {c: getattr(t, c).copy() for c in COLUMNS}
    cols["AZN"] += rng.normal(0, 0.005, 5)
    cols["AZSC"] += rng.normal(0, 0.005, 5)
    cols["LATs"] += rng.normal(0, 0.0005, 5)
    cols["LONs"] += rng.normal(0, 0.0005, 5)
    cols["R"] += rng.normal(0, 30.0, 5)
    nav = FlightParameters.from_columns({"photo": t.photo, **cols, "et": t.et}, radius=t.radius)
    cams = load_ranger_cameras(write_ranger_kernels(nav, seq.camera, tmp_path))
    pts = seq.ground_points(150, rng)
    sig = 0.33 / seq.camera.pixel
    mp, mi, xy = [], [], []
    for j, photo in enumerate(PHOTOS):
        li, sa = seq.cameras[photo].ground_to_image(pts, on_miss="nan")
        ok = np.isfinite(li)
        mp.append(np.flatnonzero(ok))
        mi.append(np.full(int(ok.sum()), j))
        xy.append(np.column_stack([li[ok], sa[ok]]) + rng.normal(0, sig, (int(ok.sum()), 2)))
    n = len(pts)
    kind = np.array(["tie"] * n, dtype=object)
    kind[:6], kind[6:40] = "control", "check"
    ref = np.full((n, 3), np.nan)
    ref[:6] = pts[:6] + rng.normal(0, 5.0, (6, 3))
    ref[6:40] = pts[6:40]
    cov = np.full((n, 3, 3), np.nan)
    cov[:6] = np.eye(3) * 25.0
    net = ControlNetwork(point_id=[f"P{i}" for i in range(n)], point_type=kind, xyz=ref,
                         measure_point=np.concatenate(mp), measure_image=np.concatenate(mi),
                         line_sample=np.concatenate(xy), measure_sigma=np.full(sum(map(len, mp)), sig),
                         image_id=list(PHOTOS), xyz_cov=cov, radius=t.radius)
    spec = NavigationSpec(orbit={p: "descent" for p in PHOTOS}, position_sigma=40.0, attitude_sigma=np.radians(0.01))
    block = build_block(cams, net, navigation=spec)
    result = lunarmap.solve(block)
    before = result.check_points(block.problem.points).attrs["rms_m"]
    after = result.check_points()
    print(f"Ranger block: sigma0 {result.sigma0:.3f}; check points E/N/U RMS {np.round(before)} m -> "
          f"{np.round(after.attrs['rms_m'])} m, errors/sigma RMS {after.attrs['normalized_rms']:.2f}")
    assert result.converged and 0.8 < result.sigma0 < 1.2
    assert np.all(after.attrs["rms_m"] < 0.5 * before)
    assert 0.6 < after.attrs["normalized_rms"] < 1.4


def test_command_line_writes_a_table_as_kernels(seq, tmp_path):
    from lunarmap.cli import main

    cols = {c: getattr(seq.table, c) for c in COLUMNS}
    utc = ["1965-03-24T14:07:45.000", "1965-03-24T14:07:50.120", "1965-03-24T14:07:55.240",
           "1965-03-24T14:08:00.360", "1965-03-24T14:08:05.480"]
    FlightParameters.from_columns({"photo": seq.table.photo, **cols, "utc": utc},
                                  radius=seq.table.radius).to_csv(tmp_path / "fp.csv")
    assert main(["ranger-kernels", str(tmp_path / "fp.csv"), "-o", str(tmp_path / "k"), "--focal-length", "1140",
                 "--format", "165", "--pixel", "0.01"]) == 0
    cam = lunarmap.load_camera(tmp_path / "k" / "439.lbl", tmp_path / "k" / "ranger.tm")
    g = cam.image_to_ground(8250.0, 8250.0)
    assert np.linalg.norm(g - seq.cameras["439"].image_to_ground(8250.0, 8250.0)) < 1e-3
    assert main(["ranger-kernels", str(tmp_path / "absent.csv"), "-o", str(tmp_path / "x")]) == 2
    bad = tmp_path / "bad.csv"
    bad.write_text((tmp_path / "fp.csv").read_text().replace(",AZSC,", ",AZX,"))
    assert main(["ranger-kernels", str(bad), "-o", str(tmp_path / "y")]) == 2
    assert not (tmp_path / "y").exists() and not (tmp_path / "x").exists()

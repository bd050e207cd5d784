"""Cameras from ISIS spiceinit tables (no kernels) vs cameras from the kernels, and adjusted tables written back.

The real cube ``M103595705LE.cub`` (ALE's 1 x 1 stand-in of the 52,224-line image, its label and
spiceinit tables as ISIS wrote them) against the same image's kernel set.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import spiceypy
from scipy.spatial.transform import Rotation, Slerp

from lunarmap.camera import LineScanCamera
from lunarmap.camera.cube import camera_from_cube
from lunarmap.camera.factory import load_camera
from lunarmap.errors import (CubeFormatError, LabelError, MissingSpiceTablesError, OrientationCoverageError,
                             UnknownInstrumentError)
from lunarmap.io import IsisCube, Table, copy_cube_with_tables, write_cube
from lunarmap.labels import read_isis_table
from lunarmap.orientation import ExteriorOrientation
from lunarmap.orientation.cube import image_support_from_cube, write_cube_orientation

pytestmark = pytest.mark.shared

SIZE = (400, 5064)  # the image of the ISIS label the kernel camera is built from
ARCSEC = np.pi / 180 / 3600


def rotation_angle(r1, r2):
    """Angles (rad) between rotation-matrix stacks, accurate for tiny angles (no arccos)."""
    return Rotation.from_matrix(np.swapaxes(r1, -1, -2) @ r2).magnitude()


def grid(cam, n=41):
    line, sample = np.meshgrid(np.linspace(0, cam.n_lines, n), np.linspace(0, cam.n_samples, n), indexing="ij")
    return line.ravel(), sample.ravel()


def pixel_difference(cam_a, cam_b, heights=(-2000.0, 0.0, 2000.0)):
    line, sample = grid(cam_a)
    worst = 0.0
    for h in heights:
        l2, s2 = cam_b.ground_to_image(cam_a.image_to_ground(line, sample, height=h), within_image=False)
        worst = max(worst, float(np.hypot(l2 - line, s2 - sample).max()))
    return worst


@pytest.fixture(scope="module")
def cameras(lro_set):
    cube = lro_set / "M103595705LE.cub"
    return (camera_from_cube(cube, image_size=SIZE),
            load_camera(lro_set / "M103595705LE_isis3.lbl", lro_set / "lro_nac_M103595705LE.tm"))


def _isis_sampled_kernel_camera(lro_set, kernel_cam):
    """The kernel camera with its pointing replaced by SPICE at ISIS's table epochs, slerped between them.

    This is what ISIS does with the kernels (sample the CK on a uniform grid, interpolate
    linearly); built here with spiceypy and scipy, independently of lunarmap's cube reader.
    """
    table, _ = read_isis_table(lro_set / "M103595705LE.cub", "InstrumentPointing")
    eo = kernel_cam.eo
    t_abs = eo.epoch + eo.times
    et = table["ET"]
    lo, hi = max(np.searchsorted(et, t_abs[0], "right") - 1, 0), np.searchsorted(et, t_abs[-1])
    knots = et[lo:hi + 1]
    assert knots[0] - 1e-6 <= t_abs[0] and knots[-1] >= t_abs[-1]
    folder = lro_set
    text = (folder / "lro_nac_M103595705LE.tm").read_text().split("KERNELS_TO_LOAD", 1)[1]
    import re

    spiceypy.kclear()
    try:
        for rel in re.findall(r"'\$KERNELS/([^']+)'", text):
            spiceypy.furnsh(str(folder / rel))
        q_knots = Rotation.from_matrix(np.array([spiceypy.pxform("J2000", "LRO_LROCNACL", t) for t in knots]))
        body = np.array([spiceypy.pxform("J2000", "MOON_ME", t) for t in t_abs])
    finally:
        spiceypy.kclear()
    j2000_to_sensor = Slerp(knots, q_knots)(np.clip(t_abs, knots[0], knots[-1])).as_matrix()
    sensor_to_body = body @ np.swapaxes(j2000_to_sensor, 1, 2)
    quats = Rotation.from_matrix(sensor_to_body).as_quat()[:, [3, 0, 1, 2]]
    new = ExteriorOrientation(epoch=eo.epoch, times=eo.times, positions=eo.positions, velocities=eo.velocities,
                              quaternions=quats, sun_times=eo.sun_times, sun_positions=eo.sun_positions,
                              body_frame=eo.body_frame)
    return LineScanCamera(kernel_cam.interior, new, kernel_cam.shape, line_times=kernel_cam.line_times)


def test_cube_camera_vs_kernel_camera(lro_set, cameras):
    """Tables vs kernels over the image; the difference is ISIS's resampling of the CK, nothing else.

    ISIS sampled the CK every 64 lines (66.2 ms, CkTableOriginalSize = 816) and interpolates
    linearly between those records; the CK's own records lie elsewhere, so the corners of the
    CK's piecewise rotation between two table records are cut: up to 0.05 px here. The
    kernel camera resampled the same way (SPICE at the table epochs, slerp) agrees with the
    cube camera to 1e-3 px, and positions agree to a micrometre.
    """
    cube_cam, kernel_cam = cameras
    assert cube_cam.n_lines == 400 and cube_cam.n_samples == 5064
    assert cube_cam.interior.focal2pixel_lines == kernel_cam.interior.focal2pixel_lines  # flight direction
    assert cube_cam.eo.body_frame == kernel_cam.eo.body_frame == "MOON_ME"
    t = np.linspace(kernel_cam.eo.times[0], kernel_cam.eo.times[-1], 500)
    position = np.linalg.norm(cube_cam.eo.position_at(t) - kernel_cam.eo.position_at(t), axis=-1).max()
    assert position < 1e-6
    raw = pixel_difference(kernel_cam, cube_cam)
    print(f"\ncube tables vs kernels: positions {position:.2e} m, pixels max {raw:.4f} px")
    assert 0.01 < raw < 0.06          # ISIS's table is a 66 ms resampling of the CK (docstring)
    resampled = _isis_sampled_kernel_camera(lro_set, kernel_cam)
    matched = pixel_difference(resampled, cube_cam)
    print(f"kernel pointing resampled at the table epochs vs cube camera: {matched:.2e} px")
    assert matched <= 1e-3


def test_write_back_reproduces_adjusted_camera(lro_set, cameras, tmp_path):
    cube = lro_set / "M103595705LE.cub"
    digest = hashlib.sha256(cube.read_bytes()).hexdigest()
    cube_cam, _ = cameras
    corr = cube_cam.corrections(degree=1)
    params = np.zeros(corr.n_params)
    params[:6] = [2e-5, -1e-5, 3e-5, 30.0, -20.0, 10.0]   # rad, m (constant part)
    params[6:12] = [1e-6, 2e-6, 0.0, 1.0, 2.0, 3.0]      # per unit of normalised time
    adjusted = corr.apply(params)
    out = write_cube_orientation(cube, tmp_path / "adjusted.cub", adjusted.eo, image_size=SIZE)
    assert hashlib.sha256(cube.read_bytes()).hexdigest() == digest        # original untouched
    back = camera_from_cube(out, image_size=SIZE)
    t = np.linspace(adjusted.eo.times[0], adjusted.eo.times[-1], 5000)    # the whole 54 s of the tables
    dpos = np.linalg.norm(back.eo.position_at(t) - adjusted.eo.position_at(t), axis=-1).max()
    dang = rotation_angle(back.eo.rotation_at(t), adjusted.eo.rotation_at(t)).max()
    dpx = pixel_difference(adjusted, back)
    print(f"\nadjusted tables read back: {dpos:.2e} m, {dang / ARCSEC:.2e} arcsec, {dpx:.2e} px")
    assert dpos <= 1e-3 and dang <= 1e-3 * ARCSEC and dpx < 1e-6
    assert pixel_difference(cube_cam, back) > 10.0                         # the correction did arrive
    cols, meta = read_isis_table(out, "InstrumentPointing")
    assert meta["Description"] == "Adjusted by lunarmap" and list(meta["TimeDependentFrames"]) == [-85600, -85000, 1]
    assert IsisCube(out).table_names == IsisCube(cube).table_names
    with pytest.raises(OrientationCoverageError):
        short = ExteriorOrientation(epoch=adjusted.eo.epoch, times=adjusted.eo.times[:10],
                                    positions=adjusted.eo.positions[:10], velocities=adjusted.eo.velocities[:10],
                                    quaternions=adjusted.eo.quaternions[:10], sun_times=adjusted.eo.sun_times,
                                    sun_positions=adjusted.eo.sun_positions, body_frame="MOON_ME")
        write_cube_orientation(cube, tmp_path / "never.cub", short, image_size=SIZE)
    assert not (tmp_path / "never.cub").exists()


def test_cube_without_tables_and_other_bad_cubes(lro_set, tmp_path):
    bare = write_cube(tmp_path / "bare.cub", np.zeros((4, 4)),
                      groups=[("Group", "Instrument", [("InstrumentHostId", "LRO"), ("InstrumentId", "NACL")])])
    with pytest.raises(MissingSpiceTablesError, match="InstrumentPointing, InstrumentPosition, BodyRotation, "
                                                      "SunPosition.*spiceinit") as err:
        camera_from_cube(bare)
    assert "bare.cub" in str(err.value) and isinstance(err.value, LabelError)
    cube = lro_set / "M103595705LE.cub"
    with pytest.raises(CubeFormatError, match="AlphaCube.*scaled"):
        camera_from_cube(cube)                                # 1 x 1 stand-in of a 5064-line image
    truncated = tmp_path / "truncated.cub"
    truncated.write_bytes(cube.read_bytes()[:100000])
    with pytest.raises(CubeFormatError, match="truncated"):
        camera_from_cube(truncated, image_size=SIZE)
    other = tmp_path / "other.cub"
    other.write_bytes(cube.read_bytes().replace(b"InstrumentId                = NACL", b"InstrumentId                = WACX"))
    with pytest.raises(UnknownInstrumentError, match="WACX"):
        camera_from_cube(other, image_size=SIZE)
    no_clock = tmp_path / "no_clock.cub"
    no_clock.write_bytes(cube.read_bytes().replace(b"CLOCK_ET_-85_1/270649237", b"CLOCK_ET_-85_1/999999999"))
    with pytest.raises(MissingSpiceTablesError, match="CLOCK_ET_-85_1/270649237:07208_COMPUTED"):
        image_support_from_cube(no_clock, image_size=SIZE)


def _edit_label(blob: bytes, *replacements: tuple[str, str]) -> bytes:
    """The cube with its label text edited (the label space, 65,536 bytes, is re-padded with NUL)."""
    end = blob.index(b"\nEnd\n") + 5
    text = blob[:end].decode("latin-1")
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new)
    head = text.encode("latin-1")
    assert len(head) <= 65536
    return head + b"\0" * (65536 - len(head)) + blob[65536:]


def test_crop_follows_alpha_cube(lro_set, cameras, tmp_path):
    """A cube cropped by ISIS (AlphaCube: an offset, no scale) is the same camera, shifted by the crop."""
    blob = (lro_set / "M103595705LE.cub").read_bytes()
    start = blob.index(b"  Group = AlphaCube")
    old = blob[start:blob.index(b"End_Group", start)].decode("latin-1")
    new = ("  Group = AlphaCube\n    AlphaSamples = 5064\n    AlphaLines = 400\n    AlphaStartingSample = 100.5\n"
           "    AlphaStartingLine = 50.5\n    AlphaEndingSample = 1100.5\n    AlphaEndingLine = 250.5\n"
           "    BetaSamples = 1000\n    BetaLines = 200\n  ")
    # a real 200 x 1000 core (zeros) after the tables, in 1 x 1 tiles like the stand-in's
    edited = _edit_label(blob, (old, new), ("StartByte   = 65537", f"StartByte   = {len(blob) + 1}"),
                         ("      Samples = 1\n      Lines   = 1\n", "      Samples = 1000\n      Lines   = 200\n"))
    cropped = tmp_path / "crop.cub"
    cropped.write_bytes(edited + np.zeros(200 * 1000, "<f4").tobytes())
    cam = camera_from_cube(cropped)
    assert (cam.n_lines, cam.n_samples) == (200, 1000)
    full = cameras[0]
    line, sample = np.array([0.5, 100.0, 199.5]), np.array([0.5, 500.0, 999.5])
    l2, s2 = full.ground_to_image(cam.image_to_ground(line, sample), within_image=False)
    # 2e-5 px: the two cameras sample the tables' interpolants on different line grids
    np.testing.assert_allclose(l2, line + 50.0, atol=1e-4)
    np.testing.assert_allclose(s2, sample + 100.0, atol=1e-4)

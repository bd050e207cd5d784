"""The API a new user meets first (issue 29): top-level calls documented with types and Returns, ground
points to degrees at the top level, ``lunarmap --help`` without markup, radars named as radars."""

from __future__ import annotations

import inspect
import re

import numpy as np
import pytest

import lunarmap

TOP_LEVEL = ["image_support", "camera_from_isd", "camera_from_isd_file", "load_camera", "fit_rpc", "find_tiepoints",
             "network_from_tiepoints", "build_block", "write_adjusted", "camera_from_cube", "open_image",
             "read_isis_network", "write_isis_network", "solve", "xyz_to_lonlat_height", "lonlat_height_to_xyz"]


@pytest.mark.parametrize("name", TOP_LEVEL)
def test_top_level_calls_have_numpydoc_parameters_and_returns(name):
    fn = getattr(lunarmap, name)
    doc = inspect.getdoc(fn) or ""
    assert "Parameters\n----------" in doc and "Returns\n-------" in doc, name
    params = [p for p in inspect.signature(fn).parameters.values() if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)]
    for p in params:                                        # every parameter is described
        assert re.search(rf"^{p.name}\b|, {p.name}\b|^{p.name},", doc, re.M), (name, p.name)


def test_solve_has_real_types():
    sig = inspect.signature(lunarmap.solve)
    assert "Block" in str(sig.parameters["block_or_problem"].annotation)
    assert "BlockResult" in str(sig.return_annotation) and "Any" not in str(sig.return_annotation)
    doc = inspect.getdoc(lunarmap.solve)
    assert "sigma0" in doc and "adjusted_sensors" in doc and "DatumDefectError" in doc


def test_ground_points_to_degrees_at_the_top_level():
    from lunarmap.camera.geodesy import pyproj_xyz_to_lonlat_height

    rng = np.random.default_rng(29)
    lon, lat, h = rng.uniform(-180, 180, 50), rng.uniform(-89, 89, 50), rng.uniform(-9000, 9000, 50)
    xyz = lunarmap.lonlat_height_to_xyz(lon, lat, h)
    # closed form: radius and direction
    r = 1737400.0 + h
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=1), r, rtol=0, atol=1e-6)
    np.testing.assert_allclose(xyz[:, 2], r * np.sin(np.radians(lat)), atol=1e-6)
    back = lunarmap.xyz_to_lonlat_height(xyz)
    np.testing.assert_allclose(back[0], lon, atol=1e-10)
    np.testing.assert_allclose(back[1], lat, atol=1e-10)
    np.testing.assert_allclose(back[2], h, atol=1e-6)
    # and PROJ on the 1737.4 km sphere agrees
    p = pyproj_xyz_to_lonlat_height(xyz)
    for a, b, tol in zip(back, p, (1e-9, 1e-9, 1e-5)):
        np.testing.assert_allclose(a, b, atol=tol)


def test_cli_help_has_no_markup(capsys):
    from lunarmap.cli import build_parser

    for argv in ([], ["run"]):
        with pytest.raises(SystemExit):
            build_parser().parse_args([*argv, "--help"])
        out = capsys.readouterr().out
        assert "``" not in out and ":func:" not in out and ":mod:" not in out
    assert "--dry-run" in out


def test_a_radar_label_is_named_as_a_radar_not_a_missing_focal_length(tmp_path):
    from lunarmap.errors import UnknownInstrumentError
    from lunarmap.labels import load_label
    from lunarmap.orientation.drivers import driver_for

    label = tmp_path / "dfsar.lbl"
    label.write_text("""Object = IsisCube
  Object = Core
    Group = Dimensions
      Samples = 100
      Lines   = 100
      Bands   = 1
    End_Group
  End_Object
  Group = Instrument
    SpacecraftName   = CHANDRAYAAN-2
    InstrumentId     = DFSAR
    StartTime        = 2020-01-01T00:00:00
    LookDirection    = RIGHT
  End_Group
  Group = Kernels
    NaifFrameCode = -152900
  End_Group
End_Object
End
""")
    with pytest.raises(UnknownInstrumentError, match=r"'DFSAR' is a radar \(SAR\) instrument.*not supported yet"):
        driver_for(load_label(label), str(label))

"""RationalFunctionModel: terms, evaluation, analytic partials, inverse, storage.

Oracles: a model whose coefficients encode a closed-form projective map
(evaluated independently here), central finite differences for the
partials, GDAL's published RPC evaluation (re-implemented here from
``RPCTransformPoint``) for the text files.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import xarray as xr

from lunarmap.camera.geodesy import lonlat_height_to_xyz
from lunarmap.errors import InvalidInputError
from lunarmap.rpc import (RationalFunctionModel, RpcFormatError, RpcInputError, read_netcdf, read_rpc_txt,
                          rpc_term_gradients, rpc_terms, write_netcdf, write_rpc_txt)
from lunarmap.rpc.terms import TERM_NAMES

OFF = np.array([26112.0, 2532.0, 10.0, 179.9, 500.0])   # line, sample, lat, lon, height
SCALE = np.array([26112.0, 2532.0, 0.4, 0.2, 11000.0])


def _projective_model() -> RationalFunctionModel:
    """line_n = (0.1 + 0.9 Y + 0.02 X + 0.01 Z) / (1 + 0.05 Z), samp_n = (X - 0.03 Y + 0.2 Z) / (1 + 0.05 Z + 0.01 X)."""
    c = np.zeros((4, 20))
    c[0, [0, 2, 1, 3]] = [0.1, 0.9, 0.02, 0.01]
    c[1, [0, 3]] = [1.0, 0.05]
    c[2, [1, 2, 3]] = [1.0, -0.03, 0.2]
    c[3, [0, 3, 1]] = [1.0, 0.05, 0.01]
    return RationalFunctionModel(c, OFF, SCALE, n_lines=52224, n_samples=5064, attrs={"note": "test"})


def _closed_form(lon, lat, h):
    X = (np.remainder(lon - OFF[3] + 180, 360) - 180) / SCALE[3]
    Y = (lat - OFF[2]) / SCALE[2]
    Z = (h - OFF[4]) / SCALE[4]
    line = (0.1 + 0.9 * Y + 0.02 * X + 0.01 * Z) / (1 + 0.05 * Z) * SCALE[0] + OFF[0]
    samp = (X - 0.03 * Y + 0.2 * Z) / (1 + 0.05 * Z + 0.01 * X) * SCALE[1] + OFF[1]
    return line, samp


def _ground(n=200, seed=1):
    rng = np.random.default_rng(seed)
    lon = OFF[3] + SCALE[3] * rng.uniform(-1, 1, n)
    lon = np.remainder(lon + 180, 360) - 180  # crosses the 180 degree meridian
    lat = OFF[2] + SCALE[2] * rng.uniform(-1, 1, n)
    h = OFF[4] + SCALE[4] * rng.uniform(-1, 1, n)
    return lon, lat, h


def test_terms_follow_rpc00b_order():
    x, y, z = 2.0, 3.0, 5.0
    by_name = {"1": 1, "L": x, "P": y, "H": z}
    expect = [np.prod([by_name[ch] for ch in name]) if name != "1" else 1.0 for name in TERM_NAMES]
    np.testing.assert_array_equal(rpc_terms(x, y, z), expect)
    # GDAL's RPCComputeTerms: index 10 is lon*lat*h, 14 lon^2*lat, 17 lon^2*h, 18 lat^2*h
    t = rpc_terms(x, y, z)
    assert (t[10], t[14], t[17], t[18]) == (x * y * z, x * x * y, x * x * z, y * y * z)


def test_term_gradients_match_finite_differences():
    rng = np.random.default_rng(0)
    p = rng.uniform(-1.2, 1.2, (3, 50))
    g = rpc_term_gradients(*p)
    eps = 1e-6
    for k in range(3):
        d = np.zeros((3, 1))
        d[k] = eps
        fd = (rpc_terms(*(p + d)) - rpc_terms(*(p - d))) / (2 * eps)
        np.testing.assert_allclose(g[:, k, :], fd, atol=1e-8)


def test_ground_to_image_matches_closed_form_across_the_dateline():
    m = _projective_model()
    lon, lat, h = _ground()
    assert lon.min() < -179 and lon.max() > 179
    line, samp = m.lonlat_to_image(lon, lat, h)
    el, es = _closed_form(lon, lat, h)
    np.testing.assert_allclose(line, el, atol=1e-7)
    np.testing.assert_allclose(samp, es, atol=1e-7)
    xyz = lonlat_height_to_xyz(lon, lat, h, m.radius)
    l2, s2 = m.ground_to_image(xyz, within_image=False)
    np.testing.assert_allclose(l2, el, atol=1e-6)
    np.testing.assert_allclose(s2, es, atol=1e-6)


def test_jacobian_matches_finite_differences():
    m = _projective_model()
    lon, lat, h = _ground(50)
    line, samp, jac = m.jacobian(lon, lat, h)
    assert jac.shape == (50, 2, 3)
    steps = (1e-6, 1e-6, 1e-3)  # degrees, degrees, metres
    for k, d in enumerate(steps):
        args_p = [lon, lat, h]
        args_m = [lon, lat, h]
        args_p[k] = args_p[k] + d
        args_m[k] = args_m[k] - d
        fd = (np.stack(_closed_form(*args_p), -1) - np.stack(_closed_form(*args_m), -1)) / (2 * d)
        np.testing.assert_allclose(jac[:, :, k], fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())


def test_jacobian_xyz_matches_finite_differences():
    m = _projective_model()
    lon, lat, h = _ground(30)
    xyz = lonlat_height_to_xyz(lon, lat, h, m.radius)
    _, _, jac = m.ground_partials(xyz)
    eps = 0.01  # metres
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        fd = (np.stack(m.ground_to_image(xyz + d, within_image=False), -1) - np.stack(m.ground_to_image(xyz - d, within_image=False), -1)) / (2 * eps)
        np.testing.assert_allclose(jac[:, :, k], fd, atol=1e-6)


def test_image_to_ground_inverts_closed_form():
    m = _projective_model()
    lon, lat, h = _ground(300, seed=3)
    line, samp = _closed_form(lon, lat, h)
    lon2, lat2 = m.image_to_lonlat(line, samp, h)
    dlon = np.remainder(lon2 - lon + 180, 360) - 180
    assert np.abs(dlon).max() < 1e-10 and np.abs(lat2 - lat).max() < 1e-10
    xyz = m.image_to_ground(line, samp, h)
    np.testing.assert_allclose(xyz, lonlat_height_to_xyz(lon, lat, h, m.radius), atol=1e-4)


def test_bad_input_is_rejected():
    m = _projective_model()
    with pytest.raises(RpcInputError, match="NaN"):
        m.lonlat_to_image([180.0, np.nan], [10.0, 10.0], 0.0)
    with pytest.raises(InvalidInputError):
        m.image_to_ground(np.inf, 3.0)
    with pytest.raises(RpcInputError, match="shape"):
        m.ground_to_image(np.zeros((4, 2)))
    with pytest.raises(RpcFormatError, match="shape"):
        RationalFunctionModel(np.zeros((3, 20)), OFF, SCALE)
    with pytest.raises(RpcFormatError, match="scale of height is zero"):
        RationalFunctionModel(np.eye(4, 20), OFF, np.where(np.arange(5) == 4, 0.0, SCALE))


def test_dataset_and_netcdf_round_trip(tmp_path):
    m = _projective_model().with_attrs(check_rms=0.001, flag=True, layers=(1.0, 2.0))
    ds = m.to_dataset()
    assert ds["coefficients"].dims == ("polynomial", "term")
    assert list(ds["coordinate"].values) == ["line", "sample", "lat", "lon", "height"]
    path = write_netcdf(m, tmp_path / "m.nc")
    back = read_netcdf(path)
    np.testing.assert_array_equal(back.coefficients, m.coefficients)
    np.testing.assert_array_equal(back.offsets, m.offsets)
    assert back.attrs["check_rms"] == 0.001 and back.n_lines == 52224
    assert [p.name for p in tmp_path.iterdir()] == ["m.nc"]
    with pytest.raises(RpcFormatError):
        RationalFunctionModel.from_dataset(xr.Dataset())


def test_failed_netcdf_write_leaves_nothing(tmp_path, monkeypatch):
    def boom(self, path, *a, **k):
        with open(path, "wb") as fh:
            fh.write(b"half")
        raise OSError("disk full")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", boom)
    with pytest.raises(OSError, match="disk full"):
        write_netcdf(_projective_model(), tmp_path / "m.nc")
    assert list(tmp_path.iterdir()) == []


def _gdal_rpc_transform(kw: dict[str, float], lon, lat, h):
    """GDAL's RPCTransformPoint (alg/gdal_rpc.cpp): RPC pixel (0,0) = centre of the first pixel, +0.5 to GDAL's."""
    X = (lon - kw["LONG_OFF"]) / kw["LONG_SCALE"]
    Y = (lat - kw["LAT_OFF"]) / kw["LAT_SCALE"]
    Z = (h - kw["HEIGHT_OFF"]) / kw["HEIGHT_SCALE"]
    t = np.stack([np.ones_like(X), X, Y, Z, X * Y, X * Z, Y * Z, X * X, Y * Y, Z * Z, X * Y * Z, X ** 3, X * Y * Y,
                  X * Z * Z, X * X * Y, Y ** 3, Y * Z * Z, X * X * Z, Y * Y * Z, Z ** 3], -1)

    def poly(name):
        return t @ np.array([kw[f"{name}_{j}"] for j in range(1, 21)])

    pixel = poly("SAMP_NUM_COEFF") / poly("SAMP_DEN_COEFF") * kw["SAMP_SCALE"] + kw["SAMP_OFF"] + 0.5
    line = poly("LINE_NUM_COEFF") / poly("LINE_DEN_COEFF") * kw["LINE_SCALE"] + kw["LINE_OFF"] + 0.5
    return line, pixel


def _parse(path):
    kw = {}
    for ln in open(path):
        if ln.startswith("#"):
            continue
        k, v = ln.split(":", 1)
        kw[k.strip()] = float(v)
    return kw


def test_rpc_txt_round_trip_and_gdal_pixel_convention(tmp_path):
    m = _projective_model()
    path = write_rpc_txt(m, tmp_path / "img_RPC.TXT")
    kw = _parse(path)
    # the file's (0, 0) is the centre of the first pixel: the image centre
    # (CSM 26112, 2532) is RPC (26111.5, 2531.5)
    assert kw["LINE_OFF"] == 26111.5 and kw["SAMP_OFF"] == 2531.5
    assert kw["LINE_SCALE"] == 26112.0 and kw["LONG_OFF"] == 179.9
    lon, lat, h = _ground(100, seed=5)
    lon = np.where(lon < 0, lon + 360, lon)  # GDAL does not wrap longitudes
    gl, gs = _gdal_rpc_transform(kw, lon, lat, h)
    line, samp = m.lonlat_to_image(lon, lat, h)
    # GDAL's corner-based pixel == lunarmap's CSM pixel
    np.testing.assert_allclose(gl, line, atol=1e-6)
    np.testing.assert_allclose(gs, samp, atol=1e-6)
    back = read_rpc_txt(path)
    l2, s2 = back.lonlat_to_image(lon, lat, h)
    assert np.abs(l2 - line).max() <= 1e-6 and np.abs(s2 - samp).max() <= 1e-6
    assert back.n_lines == 52224 and back.radius == m.radius


def _edit(text: str, old: str, new: str) -> str:
    """``text`` with ``old`` replaced once; fails if ``old`` is not there (an edit that did nothing tests nothing)."""
    assert text.count(old) == 1, f"{old!r} is not in the file exactly once"
    return text.replace(old, new)


def test_rpc_txt_reads_geoeye_style_values_and_rejects_missing_keywords(tmp_path):
    m = _projective_model()
    path = write_rpc_txt(m, tmp_path / "a_RPC.TXT")
    text = path.read_text()
    # GeoEye spelling (sign, zero padding, unit) of a *different* value, so reading it is seen
    (tmp_path / "b_RPC.TXT").write_text(_edit(text, "LINE_OFF: 26111.5\n", "LINE_OFF: +026100.25 pixels\n"))
    b = read_rpc_txt(tmp_path / "b_RPC.TXT")
    assert b.offsets[0] == 26100.75 and np.array_equal(b.offsets[1:], m.offsets[1:])
    lines = [ln for ln in text.splitlines() if not ln.startswith("SAMP_DEN_COEFF_7:")]
    assert len(lines) == len(text.splitlines()) - 1
    (tmp_path / "c_RPC.TXT").write_text("\n".join(lines))
    with pytest.raises(RpcFormatError, match="SAMP_DEN_COEFF_7 is missing"):
        read_rpc_txt(tmp_path / "c_RPC.TXT")
    (tmp_path / "d_RPC.TXT").write_text(_edit(text, "LAT_SCALE: 0.40000000000000002", "LAT_SCALE: nan"))
    with pytest.raises(RpcFormatError, match="LAT_SCALE"):
        read_rpc_txt(tmp_path / "d_RPC.TXT")
    # the comment lines lunarmap writes are checked too (fuzzing found a raw ValueError / IndexError here)
    for k, (old, new) in enumerate([("# lunarmap reference radius (m): 1737400", "# lunarmap reference radius (m): 1.2.3"),
                                    ("# lunarmap image size (lines samples): 52224 5064",
                                     "# lunarmap image size (lines samples): 52224")]):
        bad = tmp_path / f"e{k}_RPC.TXT"
        bad.write_text(_edit(text, old, new))
        with pytest.raises(RpcFormatError, match="comment line"):
            read_rpc_txt(bad)
        bad.unlink()
    with pytest.raises(FileNotFoundError):
        read_rpc_txt(tmp_path / "none.txt")
    assert sorted(os.listdir(tmp_path)) == ["a_RPC.TXT", "b_RPC.TXT", "c_RPC.TXT", "d_RPC.TXT"]

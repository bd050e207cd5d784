"""ISIS cube pixels: written by lunarmap, read back exactly and lazily, and read by GDAL as an independent reader."""

from __future__ import annotations

import os

import numpy as np
import pytest

from lunarmap.errors import CubeFormatError, LabelError, LunarmapError
from lunarmap.io import SPECIAL_CODES, IsisCube, Table, copy_cube_with_tables, open_cube, write_cube
from lunarmap.io.special import special_values

TYPES = ["UnsignedByte", "SignedWord", "UnsignedWord", "SignedInteger", "UnsignedInteger", "Real"]


def _data(shape, pixel_type, seed=0):
    rng = np.random.default_rng(seed)
    data = rng.uniform(10, 200, shape)
    if pixel_type != "Real":
        data = np.round(data)
    else:
        data = data.astype(np.float32).astype(np.float64)  # representable exactly
    codes = np.zeros(shape, np.int8)
    flat = codes.reshape(-1)
    pick = rng.choice(flat.size, 60, replace=False)
    flat[pick] = rng.integers(1, 6, 60)
    if pixel_type == "UnsignedByte":  # only 0 (Null) and 255 (Hrs) exist
        codes[np.isin(codes, (2, 3))] = SPECIAL_CODES["Null"]
        codes[codes == 4] = SPECIAL_CODES["Hrs"]
    return data, codes


@pytest.mark.parametrize("fmt", ["Tile", "BandSequential"])
@pytest.mark.parametrize("pixel_type", TYPES)
def test_cube_round_trip_with_special_pixels(tmp_path, pixel_type, fmt):
    data, codes = _data((2, 45, 61), pixel_type)
    path = write_cube(tmp_path / "c.cub", data, pixel_type=pixel_type, special=codes, fmt=fmt, tile=(16, 24),
                      byte_order="Msb" if pixel_type in ("SignedWord", "Real") else "Lsb")
    cube = IsisCube(path)
    assert cube.shape == (2, 45, 61)
    dn = cube.pixels()
    assert dn.dims == ("band", "line", "sample") and dn.chunks is not None   # lazy (dask-backed)
    assert dn["line"].values[0] == 0.5 and dn["sample"].values[-1] == 60.5  # CSM pixel centres
    expected = np.where(codes != 0, np.nan, data)
    np.testing.assert_array_equal(dn.values, expected)                      # exact, NaN where special
    np.testing.assert_array_equal(cube.special().values, codes)             # every special kind kept
    window = cube.pixels(chunks="tile" if fmt == "Tile" else None).isel(line=slice(7, 40), sample=slice(3, 50))
    np.testing.assert_array_equal(window.values, expected[:, 7:40, 3:50])


def test_base_multiplier_and_stored_values(tmp_path):
    data = np.array([[0.0, 1.5, 3.0], [100.5, -7.5, np.nan]])
    path = write_cube(tmp_path / "s.cub", data, pixel_type="SignedWord", base=-10.0, multiplier=0.5)
    cube = IsisCube(path)
    raw = cube.raw().compute()[0]
    assert raw[0, 0] == 20 and raw[1, 2] == special_values("i2")["Null"]
    np.testing.assert_array_equal(cube.pixels(dtype=np.float64).values[0], data)


def test_gdal_reads_our_cube(tmp_path):
    """GDAL's ISIS3 driver, an independent reader, sees the same stored values and the same Null."""
    rasterio = pytest.importorskip("rasterio")
    import warnings

    for pixel_type, order in (("Real", "Lsb"), ("SignedWord", "Msb"), ("UnsignedWord", "Lsb"), ("UnsignedByte", "Lsb")):
        data, codes = _data((2, 37, 53), pixel_type, seed=3)
        path = write_cube(tmp_path / f"{pixel_type}.cub", data, pixel_type=pixel_type, special=codes, tile=(16, 8),
                          byte_order=order)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # not georeferenced
            with rasterio.open(path) as ds:
                assert ds.driver == "ISIS3"
                gdal = ds.read()
                nodata = ds.nodata
        ours = IsisCube(path).raw().compute()
        np.testing.assert_array_equal(gdal, ours)
        assert nodata == pytest.approx(special_values(ours.dtype.str[1:])["Null"], rel=1e-7)


def test_large_cube_opens_lazily_and_reads_one_tile(tmp_path):
    """A 52,224 x 5,064 Real cube (1.06 GB, sparse file): opening reads only the label."""
    lines, samples, tl, ts = 52224, 5064, 512, 422
    path = tmp_path / "big.cub"
    label = write_cube(tmp_path / "seed.cub", np.zeros((tl, ts), np.float32), tile=(tl, ts))
    text = label.read_bytes()[:65536].replace(b"      Samples = 422\n", b"      Samples = 5064\n")
    text = text.replace(b"      Lines   = 512\n", b"      Lines   = 52224\n")[:65536]
    assert b"Lines   = 52224" in text and b"TileSamples = 422" in text
    with open(path, "wb") as fh:
        fh.write(text)
        fh.truncate(65536 + lines * samples * 4)       # sparse: the core reads as zeros
        tile = np.arange(tl * ts, dtype="<f4").reshape(tl, ts)
        fh.seek(65536 + (10 * 12 + 3) * tl * ts * 4)   # tile row 10, tile column 3
        fh.write(tile.tobytes())
    dn = open_cube(path, chunks="tile")
    assert dn.shape == (1, lines, samples) and len(dn.chunks[1]) == 102 and len(dn.chunks[2]) == 12
    got = dn.isel(line=slice(10 * tl, 11 * tl), sample=slice(3 * ts, 4 * ts)).values[0]
    np.testing.assert_array_equal(got, tile)
    rows = IsisCube(path).pixels()                      # default chunks: one row of tiles
    assert rows.chunks[1][0] == tl and rows.chunks[2] == (samples,)


def test_truncated_cube_is_named(tmp_path):
    data, _ = _data((1, 40, 40), "Real")
    path = write_cube(tmp_path / "t.cub", data, tables=[Table("T", {"A": np.arange(5.0)})])
    blob = path.read_bytes()
    short = tmp_path / "short.cub"
    short.write_bytes(blob[:65536 + 1000])
    with pytest.raises(CubeFormatError, match="truncated") as err:
        IsisCube(short)
    assert "short.cub" in str(err.value) and isinstance(err.value, LabelError)
    no_table = tmp_path / "no_table.cub"
    no_table.write_bytes(blob[:-8])                     # core complete, table cut
    with pytest.raises(CubeFormatError, match="object T ends at byte"):
        IsisCube(no_table)
    with pytest.raises(CubeFormatError, match="not an ISIS cube"):
        (tmp_path / "x.lbl").write_text("Object = Foo\nEnd_Object\nEnd\n")
        IsisCube(tmp_path / "x.lbl")
    with pytest.raises(FileNotFoundError):
        IsisCube(tmp_path / "missing.cub")


def test_bad_writes_leave_nothing(tmp_path):
    with pytest.raises(CubeFormatError, match="pixel type"):
        write_cube(tmp_path / "a.cub", np.zeros((3, 3)), pixel_type="Complex")
    with pytest.raises(CubeFormatError, match="outside the range"):
        write_cube(tmp_path / "b.cub", np.full((3, 3), 300.0), pixel_type="UnsignedByte")
    with pytest.raises(CubeFormatError, match="special pixels"):
        write_cube(tmp_path / "c.cub", np.full((3, 3), 65535.0), pixel_type="UnsignedWord")
    assert os.listdir(tmp_path) == []


def test_copy_with_tables_keeps_source(tmp_path):
    data, codes = _data((1, 30, 30), "Real")
    src = write_cube(tmp_path / "src.cub", data, special=codes,
                     tables=[Table("A", {"X": np.arange(3.0), "ET": np.arange(3.0) + 1e8}, keywords=[("Note", "first")]),
                             Table("B", {"Y": np.arange(4.0)}, types={"Y": "Integer"})])
    before = src.read_bytes()
    new = Table("A", {"X": np.arange(7.0) * 2, "ET": np.arange(7.0)}, keywords=[("Note", "replaced")])
    out = copy_cube_with_tables(src, tmp_path / "copy.cub", [new, Table("C", {"Z": np.ones(2)})])
    assert src.read_bytes() == before
    cube = IsisCube(out)
    cols, meta = cube.table("A")
    np.testing.assert_array_equal(cols["X"], np.arange(7.0) * 2)
    assert meta["Note"] == "replaced" and int(meta["Records"]) == 7
    np.testing.assert_array_equal(cube.table("B")[0]["Y"], np.arange(4))
    np.testing.assert_array_equal(cube.table("C")[0]["Z"], np.ones(2))
    np.testing.assert_array_equal(cube.pixels().values, IsisCube(src).pixels().values)
    with pytest.raises(CubeFormatError, match="is the source"):
        copy_cube_with_tables(src, src, [new])
    assert issubclass(CubeFormatError, LunarmapError)

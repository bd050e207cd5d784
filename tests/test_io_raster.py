"""PDS3 images and GeoTIFF through the same lazy reader as ISIS cubes; GDAL as the independent reader."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from lunarmap.errors import CubeFormatError
from lunarmap.io import write_cube
from lunarmap.io.raster import image_kind, open_image

rasterio = pytest.importorskip("rasterio")


def _pds3(tmp_path, detached=False, lines=37, samples=53, prefix=4):
    rng = np.random.default_rng(0)
    data = rng.integers(-1000, 3000, (lines, samples)).astype(">i2")
    data[3, 4] = -32768
    record = prefix + samples * 2
    pointer = '("IMAGE.DAT", 2)' if detached else "11"
    label = ("PDS_VERSION_ID = PDS3\r\nRECORD_TYPE = FIXED_LENGTH\r\nRECORD_BYTES = %d\r\n^IMAGE = %s\r\n"
             "OBJECT = IMAGE\r\n  LINES = %d\r\n  LINE_SAMPLES = %d\r\n  SAMPLE_TYPE = MSB_INTEGER\r\n"
             "  SAMPLE_BITS = 16\r\n  LINE_PREFIX_BYTES = %d\r\n  OFFSET = 10.0\r\n  SCALING_FACTOR = 0.5\r\n"
             "  MISSING_CONSTANT = -32768\r\nEND_OBJECT = IMAGE\r\nEND\r\n") % (record, pointer, lines, samples, prefix)
    rows = b"".join(b"\x01\x02\x03\x04"[:prefix] + data[i].tobytes() for i in range(lines))
    if detached:
        (tmp_path / "image.lbl").write_text(label)
        (tmp_path / "IMAGE.DAT").write_bytes(b"\0" * record + rows)   # first record skipped by the pointer
        path = tmp_path / "image.lbl"
    else:
        path = tmp_path / "image.img"
        path.write_bytes(label.encode().ljust(10 * record, b" ") + rows)
    expected = 10.0 + 0.5 * data.astype(float)
    expected[3, 4] = np.nan
    return path, data, expected


@pytest.mark.parametrize("detached", [False, True])
def test_pds3_image(tmp_path, detached):
    path, data, expected = _pds3(tmp_path, detached)
    assert image_kind(path) == "pds3"
    dn = open_image(path, chunks=(10, 53))
    assert dn.chunks[1] == (10, 10, 10, 7) and dn["line"].values[0] == 0.5
    np.testing.assert_array_equal(dn.values[0], expected)
    np.testing.assert_array_equal(dn.isel(line=slice(5, 20), sample=slice(2, 9)).values[0], expected[5:20, 2:9])
    if not detached:   # GDAL's PDS driver reads the same stored values, scale, offset and nodata
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with rasterio.open(path) as ds:
                np.testing.assert_array_equal(ds.read(1), data.astype(np.int16))
                assert (ds.nodata, ds.scales[0], ds.offsets[0]) == (-32768.0, 0.5, 10.0)


def test_pds3_truncated_and_unsupported(tmp_path):
    path, _, _ = _pds3(tmp_path)
    blob = path.read_bytes()
    short = tmp_path / "short.img"
    short.write_bytes(blob[:-50])
    with pytest.raises(CubeFormatError, match="truncated"):
        open_image(short)
    odd = tmp_path / "odd.img"
    odd.write_bytes(blob.replace(b"MSB_INTEGER", b"VAX_REAL   "))
    with pytest.raises(CubeFormatError, match="SAMPLE_TYPE VAX_REAL"):
        open_image(odd)


def test_geotiff_through_gdal(tmp_path):
    rng = np.random.default_rng(1)
    data = rng.normal(0, 100, (2, 300, 257)).astype(np.float32)
    data[0, 7, 9] = -9999.0
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=257, height=300, count=2, dtype="float32", nodata=-9999.0,
                       tiled=True, blockxsize=128, blockysize=128, compress="deflate",
                       transform=rasterio.Affine(5.0, 0.0, 0.0, 0.0, -5.0, 0.0)) as ds:
        ds.write(data)
    assert image_kind(path) == "gdal"
    dn = open_image(path, chunks=(100, 257))
    assert dn.shape == (2, 300, 257) and dn.attrs["format"] == "GTiff" and dn.attrs["transform"][0] == 5.0
    expected = data.astype(np.float32)
    expected[0, 7, 9] = np.nan
    np.testing.assert_array_equal(dn.values, expected)
    np.testing.assert_array_equal(dn.isel(band=1, line=slice(150, 260)).values, expected[1, 150:260])


def test_isis_cube_through_the_same_entry(tmp_path):
    data = np.arange(12.0).reshape(3, 4)
    data[1, 1] = np.nan
    path = write_cube(tmp_path / "c.cub", data)
    assert image_kind(path) == "isis"
    np.testing.assert_array_equal(open_image(path).values[0], data)
    with pytest.raises(FileNotFoundError):
        open_image(tmp_path / "none.tif")
    (tmp_path / "junk.bin").write_bytes(b"\x00\x01not an image")
    with pytest.raises(CubeFormatError, match="GDAL cannot read"):
        open_image(tmp_path / "junk.bin")

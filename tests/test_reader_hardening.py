"""Issue 28: one regression test per raw exception the readers let out (cube core keywords, tables,
ISIS networks, PDS3 images, GeoTIFF tiles at compute time, netCDF memory), and the run
configuration's empty ``pixels``. Each input now raises a named lunarmap exception naming the file."""

from __future__ import annotations

import time

import numpy as np
import pytest

from lunarmap.errors import CubeFormatError, IsisNetworkFormatError, LabelError, LunarmapError
from fuzz_targets import isis_cube_bytes


# --- ISIS cube core keywords ----------------------------------------------------------------------

def _core_cube(tmp_path, edit=None):
    from lunarmap.io import write_cube

    path = write_cube(tmp_path / "c.cub", np.arange(12.0).reshape(3, 4), tile=(2, 2))
    if edit is not None:
        data = path.read_bytes()
        end = data.index(b"\nEnd\n")
        head = data[:end].decode("latin-1")
        import re

        new, n = re.subn(edit[0], edit[1], head, count=1)
        assert n == 1, edit
        new = (new + "\nEnd\n").encode("latin-1")
        assert len(new) <= 65536 and data[end:end + 5] == b"\nEnd\n"
        path.write_bytes(new.ljust(65536, b"\0") + data[65536:])
    return path


@pytest.mark.parametrize("edit, match", [
    ((r"StartByte\s*=\s*\d+", "StartByte = abc"), "StartByte 'abc' is not an integer"),       # was ValueError
    ((r"TileSamples\s*=\s*\d+", "TileSamples = 1e999"), "TileSamples"),                       # was OverflowError
    ((r"StartByte\s*=\s*\d+", "StartByte = -5"), "StartByte -5 is less than 1"),               # was os.pread error
    ((r"Lines\s*=\s*\d+", "Lines = 2.5"), "Lines 2.5 is not an integer"),
    ((r"Multiplier\s*=\s*[-\d.eE+]+", "Multiplier = 1e999"), "not finite"),
])
def test_cube_core_keywords_are_checked(tmp_path, edit, match):
    from lunarmap.io import IsisCube
    from lunarmap.io.raster import open_image

    path = _core_cube(tmp_path, edit)
    with pytest.raises(CubeFormatError, match=match) as info:
        IsisCube(path).pixels().values
    assert str(path) in str(info.value)
    with pytest.raises(CubeFormatError):
        open_image(path)


def test_table_field_without_a_name(tmp_path):
    from lunarmap.labels import read_isis_table

    data = isis_cube_bytes({"InstrumentPosition": {"J2000X": np.arange(5.0), "ET": np.arange(5.0)}})
    data = data.replace(b"Name = J2000X", b'Name = ""      ', 1)
    p = tmp_path / "c.cub"
    p.write_bytes(data)
    with pytest.raises(LabelError, match="empty or non-text Name"):                         # was KeyError
        read_isis_table(p, "InstrumentPosition")


@pytest.mark.parametrize("et, match", [([0.0, 1.0, 1.0, 3.0], "do not increase at record 2"),
                                       ([0.0, 2.0, 1.0, 3.0], "do not increase"),
                                       ([0.0, np.nan, 1.0, 3.0], "not finite")])
def test_cube_table_epochs_must_increase(tmp_path, et, match):
    from lunarmap.orientation.cube import _state_block

    cols = {k: np.arange(4.0) for k in ("J2000X", "J2000Y", "J2000Z", "J2000XV", "J2000YV", "J2000ZV")}
    cols["ET"] = np.array(et)
    p = tmp_path / "c.cub"
    p.write_bytes(isis_cube_bytes({"InstrumentPosition": cols}))
    class Tables:          # the tables of the cube (the helper's cube has no pixel core)
        path = str(p)

        def table(self, name):
            from lunarmap.labels import read_isis_table
            return read_isis_table(p, name)

    with pytest.raises(CubeFormatError, match=match):      # was scipy's "x must be strictly increasing"
        _state_block(Tables(), "InstrumentPosition")


# --- ISIS control networks ------------------------------------------------------------------------

@pytest.fixture
def isis_net(tmp_path):
    from lunarmap.io.isis_network import write_isis_network
    from isisnet_help import random_network

    ds = random_network(6, per_point=3, n_img=3, rich=False)
    return write_isis_network(ds, tmp_path / "n.net"), write_isis_network(ds, tmp_path / "n2.net", version=2), ds


@pytest.mark.parametrize("version", ["abc", "5.5", "1e999"])
def test_binary_network_version_not_an_integer(isis_net, tmp_path, version):
    from lunarmap.io.isis_network import read_isis_network

    data = isis_net[0].read_bytes()
    head = data[:4096].decode("latin-1")
    import re

    new = re.sub(r"Version\s*=\s*5", f"Version = {version}", head, count=1).encode("latin-1")
    p = tmp_path / "bad.net"
    p.write_bytes(new + data[4096 + len(new) - 4096:] if len(new) <= 4096 else new)
    with pytest.raises(IsisNetworkFormatError, match="Version"):                            # was ValueError
        read_isis_network(p)


def test_binary_network_short_header_field(isis_net, tmp_path):
    """A header whose last fixed-size field (targetRadii, wire type 1) is cut short: was struct.error."""
    from lunarmap.io import isis_network as m

    buf = b"\x0a\x01a\x12\x04MOON" + b"\x51" + b"\x00\x00\x00"     # field 10, wire 1, three of eight bytes
    with pytest.raises(IsisNetworkFormatError, match="truncated header"):
        m._header_fields(buf, tmp_path / "x.net", 5)
    buf = b"\x0a\x01a\x12\x04MOON" + b"\x52\x05" + b"\x00" * 5       # packed radii of 5 bytes
    with pytest.raises(IsisNetworkFormatError, match="multiple of 8"):
        m._header_fields(buf, tmp_path / "x.net", 5)


def test_pvl_network_version_not_an_integer(isis_net, tmp_path):
    from lunarmap.io.isis_network import read_isis_network
    from lunarmap.io.isis_network_pvl import write_pvl_network

    p = write_pvl_network(isis_net[2], tmp_path / "n.pvl")
    text = p.read_text()
    import re

    for v in ("abc", "1e999", "nan"):
        bad = tmp_path / f"bad_{v}.pvl"
        bad.write_text(re.sub(r"Version\s*=\s*5", f"Version = {v}", text, count=1))
        with pytest.raises(IsisNetworkFormatError, match="Version"):                        # was ValueError
            read_isis_network(bad)


# --- PDS3 images ----------------------------------------------------------------------------------

def _pds3(tmp_path, edit=None):
    lines, samples = 6, 5
    data = np.arange(lines * samples, dtype=">i2").reshape(lines, samples)
    record = samples * 2
    label = ("PDS_VERSION_ID = PDS3\r\nRECORD_TYPE = FIXED_LENGTH\r\nRECORD_BYTES = %d\r\n^IMAGE = 31\r\n"
             "OBJECT = IMAGE\r\n  LINES = %d\r\n  LINE_SAMPLES = %d\r\n  SAMPLE_TYPE = MSB_INTEGER\r\n"
             "  SAMPLE_BITS = 16\r\n  LINE_SUFFIX_BYTES = 0\r\n  OFFSET = 10.0\r\n  SCALING_FACTOR = 0.5\r\n"
             "END_OBJECT = IMAGE\r\nEND\r\n") % (record, lines, samples)
    if edit is not None:
        assert edit[0] in label
        label = label.replace(edit[0], edit[1], 1)
    p = tmp_path / "image.img"
    p.write_bytes(label.encode().ljust(30 * record, b" ") + data.tobytes())
    return p


@pytest.mark.parametrize("edit, match", [
    (("SCALING_FACTOR = 0.5", "SCALING_FACTOR = abc"), "SCALING_FACTOR 'abc' is not a finite number"),
    (("OFFSET = 10.0", "OFFSET = 1e999"), "OFFSET"),
    (("^IMAGE = 31", "^IMAGE = ()"), "pointer"),
    (("^IMAGE = 31", '^IMAGE = ""'), "pointer"),
    (("LINE_SAMPLES = 5", "LINE_SAMPLES = -5"), "LINE_SAMPLES -5 is less than 1"),
    (("LINE_SUFFIX_BYTES = 0", "LINE_SUFFIX_BYTES = -12"), "LINE_SUFFIX_BYTES -12 is less than 0"),
    (("^IMAGE = 31", "^IMAGE = -3"), "position -3 is less than 1"),
])
def test_pds3_label_values_are_checked(tmp_path, edit, match):
    from lunarmap.io.raster import open_image

    assert np.isfinite(open_image(_pds3(tmp_path)).values).all()
    p = _pds3(tmp_path, edit)
    with pytest.raises(CubeFormatError, match=match):
        open_image(p).values


# --- GeoTIFF tiles at compute time ----------------------------------------------------------------

def test_damaged_geotiff_tile_is_named_when_computed(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from lunarmap.io.raster import open_image
    from lunarmap.io.window import PixelSource
    from lunarmap.errors import ImageWindowError

    path = tmp_path / "img.tif"
    data = np.random.default_rng(0).normal(0, 100, (1, 256, 256)).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=256, height=256, count=1, dtype="float32",
                       tiled=True, blockxsize=128, blockysize=128, compress="deflate") as ds:
        ds.write(data)
    with rasterio.open(path) as ds:
        offset = int(ds.get_tag_item("BLOCK_OFFSET_1_1", "TIFF", bidx=1))
    blob = bytearray(path.read_bytes())
    blob[offset:offset + 64] = b"\xff" * 64                  # the last tile's deflate stream destroyed
    path.write_bytes(bytes(blob))
    dn = open_image(path, chunks=(128, 128))                   # the header reads fine
    with pytest.raises(CubeFormatError, match="GDAL cannot read lines"):           # was RasterioIOError
        dn.values
    with pytest.raises(ImageWindowError):
        PixelSource(path).read(128, 256, 128, 256)


# --- netCDF: memory and time bounded by the file's size -------------------------------------------

def test_netcdf_declaring_more_than_its_size_allows(tmp_path, monkeypatch):
    import lunarmap.ncread as ncread
    from lunarmap.adjust.network import read_network
    from lunarmap.adjust.network import write_network
    from lunarmap.errors import NetworkFormatError
    from fuzz_targets import _network_seed

    p = write_network(_network_seed(), tmp_path / "net.nc")
    read_network(p)
    monkeypatch.setattr(ncread, "memory_bound", lambda n: 100)     # as if every variable were huge
    t = time.perf_counter()
    with pytest.raises(NetworkFormatError, match="10 x"):
        read_network(p)
    assert time.perf_counter() - t < 2.0


# --- run configuration ----------------------------------------------------------------------------

def test_empty_pixels_in_a_run_configuration(tmp_path):
    from lunarmap.errors import ConfigError
    from lunarmap.workflows.config import load_config

    (tmp_path / "a.lbl").write_text("x")
    (tmp_path / "m.tm").write_text("x")
    for pixels in ('""', '"  "', '"."'):
        (tmp_path / "run.toml").write_text('[run]\noutput = "out"\n[kernels]\nmetakernel = "m.tm"\n'
                                           '[[images]]\nname = "a"\nlabel = "a.lbl"\npixels = %s\n'
                                           '[[images]]\nname = "b"\nlabel = "a.lbl"\npixels = "a.lbl"\n' % pixels)
        with pytest.raises(ConfigError, match=r"images\[0\]\.pixels|pixels"):
            load_config(tmp_path / "run.toml")


def test_pvl_network_target_radii_not_numbers(isis_net, tmp_path):
    from lunarmap.io.isis_network import read_isis_network
    from lunarmap.io.isis_network_pvl import write_pvl_network

    p = write_pvl_network(isis_net[2], tmp_path / "n.pvl")
    text = p.read_text()
    import re

    m = re.search(r"TargetRadii\s*=\s*\(([^)]*)\)", text)
    if m is None:
        pytest.skip("the written network has no TargetRadii")
    bad = tmp_path / "bad.pvl"
    bad.write_text(text.replace(m.group(1), "\x881737400.0, 1737400.0, 1737400.0", 1))   # found by fuzzing
    with pytest.raises(IsisNetworkFormatError, match="TargetRadii"):                        # was ValueError
        read_isis_network(bad)


def test_lro_summing_that_overflows(lro_set, tmp_path):
    from lunarmap.orientation.drivers import image_support
    from lunarmap.spice import KernelSet

    lab = next(lro_set.glob("*_pds3.lbl"), None) or next(lro_set.glob("*.lbl"))
    text = lab.read_text()
    import re

    new, n = re.subn(r"(CROSSTRACK_SUMMING\s*=\s*)\S+", r"\g<1>1e999", text, count=1)
    if not n:
        new, n = re.subn(r"(SpatialSumming\s*=\s*)\S+", r"\g<1>1e999", text, count=1)
    assert n
    bad = tmp_path / lab.name
    bad.write_text(new)
    with pytest.raises(LabelError, match="summing"):                                        # was OverflowError
        image_support(bad, KernelSet.from_metakernel(next(lro_set.glob("*.tm"))))


def test_cube_pointing_table_without_angular_velocities(lro_set, tmp_path):
    """Found by the issue-28 fuzzing of camera_from_cube: a pointing table whose AV fields are gone took a
    code path importing a function that does not exist (raw ImportError); now the camera is built."""
    from lunarmap.camera.cube import camera_from_cube

    cube = lro_set / "M103595705LE.cub"
    if not cube.is_file():
        pytest.skip("no LRO NAC cube in the shared set")
    data = cube.read_bytes()
    end = data.index(b"\nEnd\n")
    head = data[:end]
    import re

    # the InstrumentPointing table's AV fields renamed (same length: the binary records are unchanged)
    start = head.index(b"Name        = InstrumentPointing") if b"Name        = InstrumentPointing" in head else \
        re.search(rb"Name\s*=\s*InstrumentPointing", head).start()
    stop = head.index(b"End_Object", start)
    block = head[start:stop]
    new_block = re.sub(rb"Name(\s*)= AV([123])", rb"Name\1= XV\2", block)
    assert new_block != block
    bad = tmp_path / "no_av.cub"
    bad.write_bytes(head[:start] + new_block + head[stop:] + data[end:])
    cam = camera_from_cube(bad, image_size=(400, 5064))
    ref = camera_from_cube(cube, image_size=(400, 5064))
    xyz = ref.image_to_ground(np.array([200.0]), np.array([2532.0]), 0.0)
    np.testing.assert_allclose(cam.image_to_ground(np.array([200.0]), np.array([2532.0]), 0.0), xyz, atol=1e-3)


def test_geotiff_header_declaring_more_pixels_than_the_file_holds():
    """Found by the issue-28 fuzzing: a 6.5 kB mutated GeoTIFF declaring 59,762 bands of 40 x 40 pixels was
    read chunk by chunk (GDAL opened once per chunk) for more than 18 minutes; now refused at once."""
    pytest.importorskip("rasterio")
    from pathlib import Path

    from lunarmap.io.raster import open_image

    path = Path(__file__).parent / "data" / "fuzz_geotiff_59762_bands.tif"
    t = time.perf_counter()
    with pytest.raises(CubeFormatError, match="59762 band"):
        open_image(path)
    assert time.perf_counter() - t < 2.0


def _tiny_tiff(endian: str, samples: int, directories: int, tile: int = 0) -> bytes:
    """A classic TIFF of 1 x 1 pixel directories each declaring ``samples`` samples per pixel (closed form)."""
    import struct

    e = "<" if endian == "II" else ">"
    out = bytearray(endian.encode() + struct.pack(e + "HI", 42, 8))
    tags = [(256, 3, 1, 1), (257, 3, 1, 1), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 1),
            (273, 4, 1, 0), (277, 3, 1, samples), (278, 3, 1, 1), (279, 4, 1, 1), (284, 3, 1, 2)]
    if tile:   # TileWidth, TileLength, TileOffsets, TileByteCounts instead of the strip tags
        tags = [t for t in tags if t[0] not in (273, 278, 279)] + [(322, 4, 1, tile), (323, 4, 1, tile),
                                                                   (324, 4, 1, 0), (325, 4, 1, 1)]
        tags.sort()
    for d in range(directories):
        start = len(out)
        nxt = start + 2 + 12 * len(tags) + 4 if d + 1 < directories else 0
        out += struct.pack(e + "H", len(tags))
        for tag, typ, cnt, val in tags:
            value = struct.pack(e + "HH", val, 0) if typ == 3 else struct.pack(e + "I", val)
            out += struct.pack(e + "HHI", tag, typ, cnt) + value
        out += struct.pack(e + "I", nxt)
    return bytes(out)


@pytest.mark.parametrize("endian", ["II", "MM"])
def test_tiff_declaring_thousands_of_bands_is_refused_before_gdal_opens_it(tmp_path, endian):
    """Found by the issue-28 fuzzing: a 6 kB strip TIFF grew the process by 92 MB inside GDAL's open (one band
    object per declared sample of every directory: 65,535 samples in two directories of a 274-byte file).
    Refused from the TIFF directories before GDAL opens the file; memory growth inside the readers' budget."""
    pytest.importorskip("rasterio")
    from lunarmap.io.raster import open_image

    path = tmp_path / "bands.tif"
    path.write_bytes(_tiny_tiff(endian, 65535, 2))
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")
    before = _vm_hwm_mb()
    with pytest.raises(CubeFormatError, match="131070 bands"):
        open_image(path)
    assert _vm_hwm_mb() - before < 10 * path.stat().st_size / 2**20 + 64
    # the same directories with 3 samples: opened (the preflight refuses only what no file of this size holds)
    path.write_bytes(_tiny_tiff(endian, 3, 2))
    try:
        img = open_image(path)
    except CubeFormatError as err:  # GDAL may refuse the pixel-less strips, but not for their bands
        assert "bands in all" not in str(err)
    else:
        assert img.shape[0] == 3


def _vm_hwm_mb() -> float:
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmHWM")) / 1024


@pytest.mark.parametrize("endian", ["II", "MM"])
def test_tiff_declaring_blocks_larger_than_the_file_could_hold_is_refused(tmp_path, endian):
    """Found by the issue-28 fuzzing after the band bound: a 6 kB tiled TIFF of 40 x 40 pixels grew the process by
    84 MB (a window is decoded in whole tiles, whatever the image's size): 16,384 x 16,384 tiles of 3 bands in a
    file of a few hundred bytes are refused before GDAL opens it; 256 x 256 tiles (the usual) are not."""
    pytest.importorskip("rasterio")
    from lunarmap.io.raster import open_image

    path = tmp_path / "tiles.tif"
    path.write_bytes(_tiny_tiff(endian, 3, 1, tile=16384))
    with pytest.raises(CubeFormatError, match="blocks"):
        open_image(path)
    path.write_bytes(_tiny_tiff(endian, 3, 1, tile=256))
    try:
        open_image(path)
    except CubeFormatError as err:     # GDAL may refuse the pixel-less tile, but not for its size
        assert "blocks" not in str(err)

"""Pixels by window (issue 25): window sources of every image format, stored pyramids, the matcher on
windowed images (the same matches as on whole images in memory), a bounded pixel cache, per-pair thinning."""

from __future__ import annotations

import pickle
import warnings

import numpy as np
import pytest
import xarray as xr

from lunarmap.errors import ImageWindowError, InvalidInputError, PyramidError
from lunarmap.io import write_cube
from lunarmap.io.pyramid import Pyramid, pyramid_shapes, write_pyramid
from lunarmap.io.window import ArraySource, PixelSource
from lunarmap.matching import MatchParams, TiePointParams, foerstner, match_points
from lunarmap.matching.pyramid import build_pyramid
from lunarmap.matching.resample import bicubic, bicubic_with_gradient, bilinear
from lunarmap.matching.thinning import thin_points
from lunarmap.matching.tiepoints import match_pair
from lunarmap.matching.windowed import WindowedImage, cache_info, set_cache_bytes
from lunarmap.simulate import render_image, stereo_pair, synthetic_scene


def _image(shape=(157, 211), seed=0, integer=False):
    rng = np.random.default_rng(seed)
    a = rng.normal(100.0, 30.0, shape)
    return np.round(a) if integer else a


# -- window sources ----------------------------------------------------------------------------

def _pds3(path, data):
    lines, samples = data.shape
    record = samples * 2
    label = ("PDS_VERSION_ID = PDS3\r\nRECORD_TYPE = FIXED_LENGTH\r\nRECORD_BYTES = %d\r\n^IMAGE = 3\r\n"
             "OBJECT = IMAGE\r\n  LINES = %d\r\n  LINE_SAMPLES = %d\r\n  SAMPLE_TYPE = LSB_INTEGER\r\n"
             "  SAMPLE_BITS = 16\r\n  MISSING_CONSTANT = -32768\r\nEND_OBJECT = IMAGE\r\nEND\r\n") % (record, lines, samples)
    path.write_bytes(label.encode().ljust(2 * record, b" ") + data.astype("<i2").tobytes())


def _geotiff(rasterio, path, data):
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1,
                       dtype="int16", nodata=-32768, tiled=True, blockxsize=64, blockysize=64) as ds:
        ds.write(data.astype(np.int16), 1)


def test_every_format_reads_by_window_what_an_independent_reader_sees(tmp_path):
    truth = _image(integer=True)
    truth[10, 20] = np.nan
    stored = np.where(np.isnan(truth), -32768, truth)
    files = {}
    files["cube"] = write_cube(tmp_path / "a.cub", truth, pixel_type="SignedWord", tile=(32, 48))
    _pds3(tmp_path / "a.img", stored)
    files["pds3"] = tmp_path / "a.img"
    xr.DataArray(truth.astype(np.float32), dims=("line", "sample"), name="dn").to_netcdf(tmp_path / "a.nc")
    files["netcdf"] = tmp_path / "a.nc"
    rasterio = pytest.importorskip("rasterio")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                    # NotGeoreferencedWarning: a plain image
        _geotiff(rasterio, tmp_path / "a.tif", stored)
    files["geotiff"] = tmp_path / "a.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(files["geotiff"]) as ds:        # GDAL: the independent reader
            raw = ds.read(1).astype(float)
    gdal = np.where(raw == -32768, np.nan, raw)
    np.testing.assert_array_equal(gdal, truth)
    for kind, path in files.items():
        src = PixelSource(path)
        assert src.shape == truth.shape, kind
        for l0, l1, s0, s1 in ((0, 157, 0, 211), (5, 40, 17, 200), (100, 157, 0, 1), (10, 11, 20, 21)):
            np.testing.assert_array_equal(src.read(l0, l1, s0, s1), truth[l0:l1, s0:s1], err_msg=kind)
        again = pickle.loads(pickle.dumps(src))          # by path: each process opens the file itself
        assert again._handle is None
        np.testing.assert_array_equal(again.read(3, 9, 4, 90), truth[3:9, 4:90], err_msg=kind)


def test_windows_outside_and_damaged_files_are_named(tmp_path):
    truth = _image((64, 80), integer=True)
    path = write_cube(tmp_path / "a.cub", truth, pixel_type="SignedWord", tile=(16, 16))
    src = PixelSource(path)
    for window in ((0, 65, 0, 10), (-1, 3, 0, 10), (5, 5, 0, 10), (0, 10, 70, 81)):
        with pytest.raises(ImageWindowError, match="outside"):
            src.read(*window)
    with pytest.raises(ImageWindowError, match="does not exist"):
        PixelSource(tmp_path / "missing.cub")
    blob = path.read_bytes()
    (tmp_path / "short.cub").write_bytes(blob[:len(blob) - 2000])   # smaller than its label says
    with pytest.raises(ImageWindowError, match="short.cub"):
        PixelSource(tmp_path / "short.cub").read(0, 64, 0, 80)
    (tmp_path / "junk.nc").write_bytes(b"CDF\x01" + b"\0" * 50)
    with pytest.raises(ImageWindowError, match="junk.nc"):
        PixelSource(tmp_path / "junk.nc")
    with pytest.raises(ImageWindowError, match="2-D"):
        ArraySource(np.zeros(5))


def test_pixels_in_memory_are_viewed_only_where_no_pixel_needs_masking():
    img = _image((40, 50), seed=3)
    v = ArraySource(img).view(3, 20, 5, 31)
    assert np.shares_memory(v, img) and not v.flags.writeable and np.array_equal(v, img[3:20, 5:31])
    assert ArraySource(img).view(3, 20, 5, 31, saturation=float(img.max())) is None     # a saturated pixel
    assert ArraySource(img).view(0, 40, 0, 50, saturation=float(img.max()) + 1.0) is not None
    assert ArraySource(img.astype(np.float32)).view(0, 4, 0, 4) is None                 # not float64
    bad = img.copy()
    bad[39, 49] = np.inf
    assert ArraySource(bad).view(0, 4, 0, 4) is None
    with pytest.raises(ImageWindowError, match="outside"):
        ArraySource(img).view(0, 41, 0, 4)
    # a windowed image serves them as they are, caching nothing; masked images as before
    win = WindowedImage(img)
    before = cache_info()["regions"]
    assert np.shares_memory(win.region(2, 9, 4, 30), img) and cache_info()["regions"] == before
    sat = WindowedImage(img, saturation=float(img.max()))
    got = sat.region(0, 40, 0, 50)
    assert not np.shares_memory(got, img) and np.isnan(got).sum() == 1


# -- pyramids --------------------------------------------------------------------------------

@pytest.mark.parametrize("integer", [True, False])
def test_stored_pyramid_is_build_pyramid_of_the_masked_image(tmp_path, integer):
    img = _image((1237, 333), integer=integer)
    img[5, 7] = np.nan
    img[900:903, 100:104] = 260.0                     # saturated
    p = write_pyramid(ArraySource(img), tmp_path / "p.nc", 4, saturation=250.0, stripe_lines=100)
    py = Pyramid(p, shape=img.shape)
    ref = build_pyramid(np.where(img >= 250.0, np.nan, img), 4)
    assert py.levels == 4 == len(ref) - 1 and [s for s in pyramid_shapes(img.shape, 9)][:4] == [r.shape for r in ref[1:]]
    for k in range(1, 5):
        lev = py.level(k)
        got = lev.read(0, lev.shape[0], 0, lev.shape[1])
        if integer:       # means of integers are exact in float32 at these levels
            np.testing.assert_array_equal(got, ref[k])
        else:
            np.testing.assert_allclose(got, ref[k], rtol=1e-7, atol=0)
            assert np.array_equal(np.isnan(got), np.isnan(ref[k]))


def test_pyramid_of_another_image_or_damaged_is_refused(tmp_path):
    img = _image((200, 150))
    p = write_pyramid(ArraySource(img), tmp_path / "p.nc", 3, digest="abc")
    Pyramid(p, shape=(200, 150), digest="abc")
    with pytest.raises(PyramidError, match="150"):
        Pyramid(p, shape=(201, 150))
    with pytest.raises(PyramidError, match="another image"):
        Pyramid(p, digest="xyz")
    (tmp_path / "cut.nc").write_bytes(p.read_bytes()[:3000])
    with pytest.raises(PyramidError, match="cut.nc"):
        Pyramid(tmp_path / "cut.nc")
    with pytest.raises(PyramidError, match="does not exist"):
        Pyramid(tmp_path / "none.nc")


# -- the resamplers on windowed images ------------------------------------------------------------

@pytest.mark.parametrize("invalid", [True, False])    # False: regions are views of the image, not copies
def test_resamplers_give_the_whole_images_values_bit_for_bit(invalid):
    rng = np.random.default_rng(4)
    img = _image((300, 260))
    if invalid:
        img[40:44, 50:53] = np.nan
    win = WindowedImage(img)
    # points everywhere: inside, on integer coordinates, at and beyond the edges, NaN
    line = np.concatenate([rng.uniform(-3, 303, 4000), np.arange(0, 300.5, 0.5), [np.nan, 1.5, 299.5]])
    sample = np.concatenate([rng.uniform(-3, 263, 4000), np.linspace(0, 260, 601), [3.0, np.nan, 259.5]])
    windows = (line[:, None, None] + np.arange(-3, 4)[None, :, None], sample[:, None, None] + np.arange(-3, 4))
    for fn in (bilinear, bicubic, bicubic_with_gradient):
        for args in ((line, sample), windows):
            a, b = fn(img, *args), fn(win, *args)
            for x, y in zip(a if isinstance(a, tuple) else (a,), b if isinstance(b, tuple) else (b,)):
                assert np.array_equal(x, y, equal_nan=True), fn.__name__
    assert bilinear(win, 10.2, 20.7) == bilinear(img, 10.2, 20.7)        # 0-d in, 0-d out


@pytest.mark.parametrize("sigma", [0.7, 1.0, 2.0])
@pytest.mark.parametrize("invalid", [True, False])
def test_smoothed_regions_computed_where_needed_are_scipy_s_smoothing_bit_for_bit(sigma, invalid):
    from scipy.ndimage import gaussian_filter

    img = _image((300, 260), seed=8)
    if invalid:
        img[40:44, 50:53] = np.nan
        img[0, 7] = np.nan
    # the oracle: scipy on the whole image, NaN-aware by normalised convolution where NaN pixels are
    bad = ~np.isfinite(img)
    num = gaussian_filter(np.where(bad, 0.0, img), sigma, mode="nearest")
    den = gaussian_filter((~bad).astype(float), sigma, mode="nearest")
    ref = np.where(bad, np.nan, num / den) if invalid else gaussian_filter(img, sigma, mode="nearest")
    sm = WindowedImage(img).smoothed(sigma)
    assert sm.fills_on_demand
    # whole regions, at the edges and inside
    for l0, l1, s0, s1 in ((0, 300, 0, 260), (30, 61, 40, 75), (281, 300, 0, 9), (5, 6, 250, 260)):
        assert np.array_equal(sm.region(l0, l1, s0, s1), ref[l0:l1, s0:s1], equal_nan=True)
    # only the boxes asked for, in a larger region that is then filled further
    sm = WindowedImage(img).smoothed(sigma)
    need = np.array([[100, 113, 20, 31], [0, 4, 255, 260], [190, 191, 130, 150]])
    got = sm.region(0, 300, 0, 260, need=need)
    for l0, l1, s0, s1 in need:
        assert np.array_equal(got[l0:l1, s0:s1], ref[l0:l1, s0:s1], equal_nan=True)
    got = sm.region(60, 140, 10, 90)
    assert np.array_equal(got, ref[60:140, 10:90], equal_nan=True) and not got.flags.writeable


@pytest.fixture(scope="module")
def pair():
    dtm, alb = synthetic_scene(30.0, 0.0, 250.0, 0.5, seed=3)
    c1, c2 = stereo_pair("linescan", 10.0, n_lines=200, n_samples=200)
    i1 = render_image(c1, dtm, alb, noise_sigma=2.0, sun="eo", seed=1).values.astype(float)
    i2 = render_image(c2, dtm, alb, noise_sigma=2.0, sun="eo", seed=2).values.astype(float)
    i2[50:53, 60:70] = np.nan                             # invalid pixels
    i1[150:152, 20:24] = 300.0                            # saturated pixels
    return c1, c2, i1, i2


@pytest.mark.parametrize("search", [12.0, 40.0])          # 40: the pair's common offset is measured first
def test_matching_windowed_images_gives_the_in_memory_matches(pair, tmp_path, search):
    c1, c2, i1, i2 = pair
    pts = foerstner(i1, cell=12, per_cell=1)
    p = MatchParams(search=search, bias_sample=16, local_search=8.0, saturation=255.0)
    from lunarmap.matching.pairs import as_array

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = match_points(as_array(i1, "a", 255.0), as_array(i2, "b", 255.0), c1, c2, pts.line, pts.sample,
                           params=p)
    assert ref.ok.sum() > 150
    # derived pyramid levels (block means of level-0 windows): bit for bit
    w = match_points(WindowedImage(i1, 255.0), WindowedImage(i2, 255.0), c1, c2, pts.line, pts.sample, params=p)
    for k in ("line2", "sample2", "sigma_line", "sigma_sample", "correlation", "status"):
        assert np.array_equal(getattr(ref, k), getattr(w, k), equal_nan=True), k
    # pyramids stored as float32 on disk: the same matches within 1e-6 px
    stores = [Pyramid(write_pyramid(ArraySource(im), tmp_path / f"{n}{search}.nc", 4, saturation=255.0))
              for n, im in (("a", i1), ("b", i2))]
    s = match_points(WindowedImage(i1, 255.0, pyramid=stores[0]), WindowedImage(i2, 255.0, pyramid=stores[1]), c1,
                     c2, pts.line, pts.sample, params=p)
    assert np.array_equal(ref.status, s.status)
    assert np.nanmax(np.abs(ref.line2 - s.line2)) < 1e-6 and np.nanmax(np.abs(ref.sample2 - s.sample2)) < 1e-6


def test_the_pixel_cache_stays_within_its_bytes_and_changes_no_result(pair):
    c1, c2, i1, i2 = pair
    pts = foerstner(i1, cell=12, per_cell=1)
    p = MatchParams(search=12.0)
    full = match_points(WindowedImage(i1), WindowedImage(i2), c1, c2, pts.line, pts.sample, params=p)
    before = cache_info()["max_bytes"]
    try:
        set_cache_bytes(150_000)                       # smaller than one image: regions are evicted
        a, b = WindowedImage(i1), WindowedImage(i2)
        small = match_points(a, b, c1, c2, pts.line, pts.sample, params=p)
        info = cache_info()
        assert info["bytes"] <= 150_000 or info["regions"] == 1
        assert np.array_equal(full.line2, small.line2, equal_nan=True)
        with pytest.raises(InvalidInputError):
            set_cache_bytes(-1)
    finally:
        set_cache_bytes(before)


# -- thinning -----------------------------------------------------------------------------------

def test_thinning_keeps_the_strongest_point_per_cell_inside_the_overlap(pair):
    c1, c2, i1, i2 = pair
    rng = np.random.default_rng(2)
    line, sample = rng.uniform(0, 200, 5000), rng.uniform(0, 200, 5000)
    strength = rng.uniform(0, 1, 5000)
    keep = thin_points(line, sample, strength, 100, cell=8.0)
    assert 50 <= keep.size <= 100 and np.all(np.diff(keep) > 0)
    # one point per cell of the chosen size, each the strongest of its cell
    for size in 8.0 * 2.0 ** (np.arange(12) / 2.0):
        cells = (line // size).astype(int) * 1000 + (sample // size).astype(int)
        if np.unique(cells).size <= 100:
            break
    assert np.unique(cells[keep]).size == keep.size == np.unique(cells).size
    for k in keep[:20]:
        assert strength[k] == strength[cells == cells[k]].max()
    assert np.array_equal(keep, thin_points(line, sample, strength, 100, cell=8.0))     # deterministic
    # with the sensors: only points image 2 can see. Pretend image 2 has half its samples: the kept points
    # are those predicted inside it, plus the edge cells' (the overlap test is cell by cell, 6.25 px cells)
    g = c1.image_to_ground(line, sample, height=0.0, on_miss="nan")
    l2, s2 = (np.asarray(v) for v in c2.ground_to_image(g, on_miss="nan"))
    inside = thin_points(line, sample, strength, 10_000, c1, c2, (200, 200), (200, 100), 0.0, cell=8.0)
    kept = np.zeros(line.size, bool)
    kept[inside] = True
    assert kept[(s2 > 2) & (s2 < 90) & (l2 > 2) & (l2 < 198)].all()       # all seen well inside are kept
    assert not kept[s2 > 120].any() and kept.sum() < 0.7 * line.size     # none far outside
    with pytest.raises(InvalidInputError):
        thin_points(line, sample, strength, 0)


def test_match_pair_thins_to_max_points_and_keeps_the_rows_of_every_point(pair):
    c1, c2, i1, i2 = pair
    pts = foerstner(i1, cell=8, per_cell=2)
    params = TiePointParams(match=MatchParams(search=12.0), max_points=60)
    m = match_pair(i1, i2, c1, c2, pts, 0.0, params, "pair")
    assert m.line1.size == pts.line.size and m.meta["thinned"] >= pts.line.size - 60
    assert np.count_nonzero(m.status != 6) <= 60 and m.ok.sum() >= 30
    np.testing.assert_array_equal(m.line1, pts.line)


class _Shift:
    """A toy sensor pair: image 2 is image 1 shifted by ``ds`` samples (ground = image-1 pixels)."""

    def __init__(self, ds: float = 0.0) -> None:
        self.ds = ds

    def image_to_ground(self, line, sample, height=0.0, on_miss="nan"):
        return np.column_stack([line, sample, np.zeros_like(np.asarray(line, float))])

    def ground_to_image(self, g, on_miss="nan"):
        g = np.atleast_2d(g)
        return g[:, 0], g[:, 1] - self.ds


def test_thinning_finds_a_narrow_overlap_along_a_long_image():
    """LRO NAC-L / NAC-R: a 10-pixel strip along the 20,000-line side of 200-sample images."""
    rng = np.random.default_rng(5)
    line, sample = rng.uniform(0, 20_000, 40_000), rng.uniform(0, 200, 40_000)
    strength = rng.uniform(size=40_000)
    args = (_Shift(), _Shift(190.0), (20_000, 200), (20_000, 200))
    every = thin_points(line, sample, strength, 40_000, *args, cell=8.0)
    assert np.isin(np.flatnonzero(sample >= 190.0), every).all()      # every point of the strip is a candidate
    assert np.all(sample[every] > 140.0)                             # and only those near it (one dilated cell)
    keep = thin_points(line, sample, strength, 500, *args, cell=8.0)
    assert 250 <= keep.size <= 500 and np.all(sample[keep] > 140.0)


def test_reading_a_chunked_netcdf_image_by_window_keeps_no_chunk_cache(tmp_path):
    """HDF5's per-variable chunk cache (64 MB by default) filled as windows were read and stayed while the file
    was open: a worker matching eight full-size images grew by ~1 GB through their pyramid levels. Reading a
    64 MB image window by window now leaves the process's resident memory within a few MB of where it was."""
    import gc

    import netCDF4

    from lunarmap.io.window import NETCDF_CHUNK_CACHE_BYTES
    from lunarmap.procmem import release_free_memory, rss_mb

    path = tmp_path / "big.nc"
    n = 4096
    with netCDF4.Dataset(path, "w") as ds:
        ds.createDimension("line", n)
        ds.createDimension("sample", n)
        v = ds.createVariable("level_1", "f4", ("line", "sample"), chunksizes=(256, 256))
        for k in range(0, n, 512):
            v[k:k + 512] = np.arange(k, k + 512, dtype=np.float32)[:, None] + np.zeros(n, np.float32)
    src = PixelSource(path)
    assert src._open().var.get_var_chunk_cache()[0] == NETCDF_CHUNK_CACHE_BYTES
    # freed heap pages the allocator keeps (left by earlier tests, or by this one's reads) are not a cache:
    # they are given back before each measurement, so only memory still held counts
    gc.collect()
    release_free_memory()
    before = rss_mb()
    for k in range(100, n - 256, 256):      # windows across chunk borders, as the matcher's regions are
        block = src.read(k, k + 256, 100, n - 100)
        assert block[0, 0] == k and block[-1, -1] == k + 255
    del block
    gc.collect()
    release_free_memory()
    assert rss_mb() - before < 8.0, f"{rss_mb() - before:.1f} MB kept after reading a 64 MB image by window"
    src.close()


def test_release_free_memory_gives_freed_heap_pages_back():
    """glibc keeps freed mid-size numpy temporaries resident once its mmap threshold has risen (a full-size
    match worker grew ~250 MB per batch); after ``release_free_memory`` the process's RSS is back down."""
    import sys

    import numpy as np

    from lunarmap.procmem import release_free_memory, rss_mb

    if not sys.platform.startswith("linux"):
        pytest.skip("glibc's malloc_trim: Linux only")
    big = np.ones(2 << 20)            # 16 MB from mmap, freed: glibc raises its mmap threshold to its size
    del big
    keep = []
    arrays = [np.ones(1 << 17) for _ in range(300)]     # 300 x 1 MB, now from the heap
    keep = arrays[::50]                                  # a few survivors pin the heap's top
    del arrays
    before = rss_mb()
    release_free_memory()
    after = rss_mb()
    assert before - after > 100, (before, after)
    assert len(keep) == 6


@pytest.mark.parametrize("cache", [True, False])
def test_derived_levels_reduce_the_level_above_and_equal_build_pyramid_bit_for_bit(cache):
    # issue 32, item 5: without a stored pyramid, level k is one 2 x 2 reduction of level k-1's (cached)
    # regions; its values must be build_pyramid's (of the masked image) wherever and in whatever order
    # regions are asked for, with the cache on or off, of the raw or of a smoothed level 0
    rng = np.random.default_rng(21)
    img = _image((301, 277), seed=5)
    img[100:103, 30:90] = np.nan
    img[7, 9] = 400.0                                       # saturated
    masked = np.where(img >= 300.0, np.nan, img)
    ref = build_pyramid(masked, 4)
    set_cache_bytes(8 << 20 if cache else 0)
    try:
        for smooth in (0.0, 1.0):
            pyr = WindowedImage(img, saturation=300.0, smooth=smooth).pyramid(4)
            assert len(pyr) == len(ref) == 5
            for k in rng.permutation(np.arange(1, 5).repeat(6)):
                h, w = ref[k].shape
                assert pyr[k].shape == (h, w)
                l0, s0 = rng.integers(0, h - 1), rng.integers(0, w - 1)
                l1, s1 = rng.integers(l0 + 1, h + 1), rng.integers(s0 + 1, w + 1)
                assert np.array_equal(pyr[k].region(l0, l1, s0, s1), ref[k][l0:l1, s0:s1], equal_nan=True), k
            assert pyr[3]._parent is pyr[2] and pyr[1]._parent.smooth == 0.0
            # a pickled level (a worker's copy) still gives the same values
            lev = pickle.loads(pickle.dumps(pyr[3]))
            assert np.array_equal(lev.region(0, ref[3].shape[0], 0, ref[3].shape[1]), ref[3], equal_nan=True)
    finally:
        set_cache_bytes(64 << 20)


def test_derived_levels_read_level_0_once_per_region():
    # the level above's cached region serves the next level: once level 1 is held whole, no level under it
    # reads level-0 pixels again (before: each level read and reduced its own 4^k-times larger region)
    img = _image((256, 256), seed=6)
    calls = []

    class Counting(ArraySource):
        def read(self, l0, l1, s0, s1):
            calls.append((l1 - l0) * (s1 - s0))
            return super().read(l0, l1, s0, s1)

        def view(self, l0, l1, s0, s1, saturation=None):      # pixels in memory are seen without a copy
            calls.append((l1 - l0) * (s1 - s0))
            return super().view(l0, l1, s0, s1, saturation)

    pyr = WindowedImage(Counting(img)).pyramid(3)
    whole = pyr[1].region(0, 128, 0, 128)
    assert calls == [256 * 256]
    for k in (2, 3, 2, 3):
        f = 2 ** k
        got = pyr[k].region(40 // f, 200 // f, 8 // f, 256 // f)
        assert np.array_equal(got, build_pyramid(img, k)[k][40 // f:200 // f, 8 // f:256 // f])
    assert len(calls) == 1
    assert np.array_equal(whole, build_pyramid(img, 1)[1])


def test_a_second_pair_of_the_same_windowed_images_reads_no_pixel_again(pair, tmp_path):
    # a worker's pairs share their images: the pyramid levels and the smoothed image of a windowed image are kept
    # with it, so matching it again reads neither the image nor its stored pyramid, with the same matches
    c1, c2, i1, i2 = pair
    i1 = i1.astype(float).copy()
    i1[0, 0] = np.nan                         # a pixel to mask: regions are read and cached, not viewed
    pts = foerstner(i1, cell=12, per_cell=1)
    p = MatchParams(search=12.0, saturation=255.0)
    stores = [Pyramid(write_pyramid(ArraySource(im), tmp_path / f"{n}.nc", 4, saturation=255.0))
              for n, im in (("a", i1), ("b", i2))]
    reads = []

    class Counting(PixelSource):
        def read(self, l0, l1, s0, s1):
            reads.append(self.path)
            return super().read(l0, l1, s0, s1)

    class CountingArray(ArraySource):
        def read(self, l0, l1, s0, s1):
            reads.append("level 0")
            return super().read(l0, l1, s0, s1)

    def counting(store):
        level = store.level

        def lev(k):
            src = level(k)
            src.__class__ = Counting
            return src
        store.level = lev
        return store

    a = WindowedImage(CountingArray(i1), 255.0, pyramid=counting(stores[0]))
    b = WindowedImage(CountingArray(i2), 255.0, pyramid=counting(stores[1]))
    assert a.pyramid(4)[1] is a.pyramid(4)[1] and a.smoothed(1.0) is a.smoothed(1.0)
    first = match_points(a, b, c1, c2, pts.line, pts.sample, params=p)
    assert "level 0" in reads and len(set(reads)) > 1    # the image and its stored levels were read the first time
    n = len(reads)
    again = match_points(a, b, c1, c2, pts.line, pts.sample, params=p)
    assert len(reads) == n
    fresh = match_points(WindowedImage(ArraySource(i1), 255.0, pyramid=stores[0]),
                         WindowedImage(ArraySource(i2), 255.0, pyramid=stores[1]), c1, c2, pts.line, pts.sample,
                         params=p)
    for k in ("line2", "sample2", "sigma_line", "sigma_sample", "correlation", "status"):
        assert np.array_equal(getattr(first, k), getattr(again, k), equal_nan=True), k
        assert np.array_equal(getattr(fresh, k), getattr(again, k), equal_nan=True), k

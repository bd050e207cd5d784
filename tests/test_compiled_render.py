"""The compiled, tiled renderer against the camera's own DTM intersection and the numpy renderer; the tiled
albedo; the streaming ISIS cube writer (stripes, faults, nothing half-written)."""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest
import xarray as xr

from lunarmap.camera import DtmSampler
from lunarmap.errors import CubeFormatError, CubeWriteError, InvalidInputError
from lunarmap.io import CubeWriter, IsisCube, open_image, write_cube
from lunarmap.simulate import pointed_camera, render_image, synthetic_albedo, synthetic_dtm
from lunarmap.simulate.albedo import tiled_albedo
from lunarmap.simulate.compiled_render import RenderScene, render_cube, render_window
from lunarmap.simulate.orbits import frame_interior, nac_like_interior

LON0, LAT0 = 30.0, 20.0
SUN = np.array([0.55, 0.25, 0.80])


@pytest.fixture(scope="module")
def scene():
    """Craters over rolling terrain (2 m), a raster albedo (1 m) and a small tiled albedo."""
    dtm = synthetic_dtm(LON0, LAT0, 1600.0, 2.0, relief=3.0, crater_density=0.02, d_min=16.0, d_max=150.0, seed=3)
    raster = synthetic_albedo(LON0, LAT0, 1600.0, 1.0, feature_size=3.0, seed=4)
    tiled = tiled_albedo(LON0, LAT0, 5, feature_size=3.0, blur=0.5, spacing=0.5, tile_nodes=(512, 480))
    return dtm, raster, tiled


@pytest.fixture(scope="module")
def cameras():
    """A NAC-like pushbroom (LRO's k1: 5 px at 256 px from the centre) and a framing camera with radial
    distortion, both 20 degrees off nadir over rough terrain."""
    ls = pointed_camera("linescan", LON0, LAT0, 20.0, n_lines=128, n_samples=256,
                        interior=nac_like_interior(n_lines=128, n_samples=256, k1=1.81e-5))
    fr = pointed_camera("frame", LON0, LAT0, -25.0, altitude=10e3, interior=frame_interior())
    return {"linescan": ls, "frame": fr}


WINDOWS = {"linescan": [(0, 24, 0, 40), (60, 76, 216, 256)], "frame": [(0, 20, 0, 30), (130, 150, 350, 384)]}


@pytest.mark.parametrize("kind", ["linescan", "frame"])
@pytest.mark.parametrize("k", [1, 2])
def test_compiled_rays_meet_the_dtm_where_the_camera_says(scene, cameras, kind, k):
    """Oracle: the camera's own image_to_ground(l, s, dtm=DtmSampler(dtm)) (numpy EO table, intersect_dtm),
    converged far below the bound; windows at the image corners, where distortion is largest."""
    dtm = scene[0]
    cam = cameras[kind]
    rscene = RenderScene.of(dtm, scene[1])
    worst = 0.0
    for win in WINDOWS[kind]:
        _, xyz = render_window(cam, rscene, win, supersample=k, ground=True, sun=SUN)
        l0, l1, s0, s1 = win
        sub = (np.arange(k) + 0.5) / k
        L, S = np.meshgrid((np.arange(l0, l1)[:, None] + sub).ravel(), (np.arange(s0, s1)[:, None] + sub).ravel(),
                           indexing="ij")
        truth = cam.image_to_ground(L, S, dtm=DtmSampler(dtm), tol=1e-8)
        worst = max(worst, float(np.max(np.linalg.norm(xyz - truth, axis=-1))))
    assert worst < 1e-3          # the acceptance bound: 1 mm
    assert worst < 1e-5          # what the 10 um height convergence and the linearisations give (~1 um)


@pytest.mark.parametrize("kind", ["linescan", "frame"])
@pytest.mark.parametrize("albedo", ["raster", "tiled"])
def test_compiled_grey_values_equal_render_image(scene, cameras, kind, albedo):
    """Oracle: the numpy renderer (dask blocks, float32) on the same scene, supersampling and Sun."""
    dtm, raster, tiled = scene
    alb = raster if albedo == "raster" else tiled
    cam = cameras[kind]
    for win in WINDOWS[kind]:
        for k in (1, 2):
            got, _ = render_window(cam, RenderScene.of(dtm, alb), win, supersample=k, sun=SUN)
            ref = render_image(cam, dtm, alb, supersample=k, sun=SUN, gain=1.0, window=win).values
            assert np.all(np.isfinite(got))
            np.testing.assert_allclose(got, ref, rtol=2e-6, atol=1e-7)   # float32 rounding of the reference


def test_tiled_albedo_is_periodic_deterministic_band_limited(scene):
    tiled = scene[2]
    t1 = tiled.tiles[0].astype(float)
    # the tile wraps without a seam: the step across its edge is like any other step
    step_inside = np.abs(np.diff(t1, axis=1)).mean()
    assert np.abs(t1[:, 0] - t1[:, -1]).mean() < 1.2 * step_inside
    assert abs(t1.mean()) < 1e-6 and t1.std() == pytest.approx(1.0, rel=1e-5)
    # same seed, same albedo at the same ground point; another seed, another albedo
    lon = LON0 + np.linspace(-0.01, 0.01, 500)
    lat = LAT0 + np.linspace(-0.01, 0.01, 500)
    again = tiled_albedo(LON0, LAT0, 5, feature_size=3.0, blur=0.5, spacing=0.5, tile_nodes=(512, 480))
    np.testing.assert_array_equal(tiled(lon, lat), again(lon, lat))
    other = tiled_albedo(LON0, LAT0, 6, feature_size=3.0, blur=0.5, spacing=0.5, tile_nodes=(512, 480))
    assert abs(np.corrcoef(tiled(lon, lat), other(lon, lat))[0, 1]) < 0.2
    # band limit: the sum of the two rotated tiles sampled on a fine grid (Hann window) has almost no power
    # at wavelengths below 1 m, the Nyquist wavelength of the 0.5 m pixels this 0.5 m blur is for
    # (the Gaussian leaves 5e-5 of the power there; the tiles' bilinear interpolation ~8e-4)
    e = np.arange(1024) * 0.25
    tex = tiled.texture(e[None, :], e[:, None])
    k = np.hypot(*np.meshgrid(np.fft.fftfreq(1024, 0.25), np.fft.fftfreq(1024, 0.25)))
    power = np.abs(np.fft.fft2((tex - tex.mean()) * np.outer(np.hanning(1024), np.hanning(1024)))) ** 2
    assert power[k > 1.0].sum() < 2e-3 * power.sum()
    assert power[(k > 1 / 3.0) & (k < 1 / 1.5)].sum() > 3e-3 * power.sum()   # but texture down to ~2 m
    a = tiled(lon[:, None], lat[None, :])
    assert 0.02 <= a.min() and a.max() <= 0.98 and a.std() == pytest.approx(0.125, rel=0.3)
    with pytest.raises(InvalidInputError, match="tile_nodes"):
        tiled_albedo(LON0, LAT0, 1, tile_nodes=(256, 256))


def _cube_bytes(path) -> bytes:
    with open(path, "rb") as fh:
        return fh.read()


def test_cube_writer_stripes_in_any_order_equal_write_cube(tmp_path):
    """Oracle: write_cube of the whole array (the same bytes), and lunarmap's tile reader."""
    rng = np.random.default_rng(1)
    data = rng.integers(1, 255, (70, 45)).astype(float)
    data[3, 4] = np.nan
    whole = write_cube(tmp_path / "whole.cub", data, pixel_type="UnsignedByte", tile=(16, 16))
    with CubeWriter(tmp_path / "stripes.cub", 70, 45, pixel_type="UnsignedByte", tile=(16, 16)) as cube:
        for l0 in (32, 0, 64, 16, 48):          # out of order; the last stripe is short (6 lines)
            cube.write(data[l0:l0 + 16], l0)
        assert not (tmp_path / "stripes.cub").exists()       # nothing under the name before finish
    assert _cube_bytes(tmp_path / "stripes.cub") == _cube_bytes(whole)
    back = open_image(tmp_path / "stripes.cub").values[0]
    np.testing.assert_array_equal(np.isnan(back), np.isnan(data))
    np.testing.assert_array_equal(back[~np.isnan(back)], data[~np.isnan(data)])
    # a stripe that is not whole rows of tiles, a missing row: named errors, nothing left behind
    w = CubeWriter(tmp_path / "bad.cub", 70, 45, pixel_type="UnsignedByte", tile=(16, 16))
    with pytest.raises(CubeFormatError, match="whole"):
        w.write(data[5:21], 5)
    w.write(data[:16], 0)
    with pytest.raises(CubeFormatError, match="never written"):
        w.finish()
    assert sorted(os.listdir(tmp_path)) == ["stripes.cub", "whole.cub"]


def test_cube_writer_faults_leave_nothing(tmp_path, monkeypatch):
    data = np.full((32, 20), 7.0)
    # an exception inside the with block (a failed or interrupted render)
    with pytest.raises(RuntimeError):
        with CubeWriter(tmp_path / "a.cub", 32, 20, pixel_type="UnsignedByte", tile=(16, 16)) as cube:
            cube.write(data[:16], 0)
            raise RuntimeError("render failed")
    assert os.listdir(tmp_path) == []
    # a missing folder, a read-only folder, a full disk (the operating system's errors, simulated:
    # root writes into read-only folders; bench/bench_render.py --faults shows them on real mounts)
    with pytest.raises(CubeWriteError, match="does not exist"):
        CubeWriter(tmp_path / "no" / "a.cub", 32, 20)
    import tempfile

    def read_only(*a, **k):
        raise PermissionError(errno.EROFS, "Read-only file system")

    with monkeypatch.context() as m:
        m.setattr(tempfile, "mkstemp", read_only)
        with pytest.raises(CubeWriteError, match="Read-only"):
            CubeWriter(tmp_path / "a.cub", 32, 20)

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    for target in ("posix_fallocate", "pwrite"):
        with monkeypatch.context() as m:
            if target == "pwrite":
                cube = CubeWriter(tmp_path / "a.cub", 32, 20, pixel_type="UnsignedByte", tile=(16, 16))
                m.setattr(os, "pwrite", full)
                with pytest.raises(CubeWriteError, match="disk is full"):
                    cube.write(data[:16], 0)
                cube.abort()
            else:
                m.setattr(os, "posix_fallocate", full)
                with pytest.raises(CubeWriteError, match="disk is full"):
                    CubeWriter(tmp_path / "a.cub", 32, 20)
        assert os.listdir(tmp_path) == []
    assert issubclass(CubeWriteError, OSError)


def test_render_cube_quantises_adds_seeded_noise_and_fails_cleanly(scene, cameras, tmp_path, monkeypatch):
    dtm, raster, _ = scene
    cam = cameras["linescan"]
    rscene = RenderScene.of(dtm, raster)
    values, _ = render_window(cam, rscene, sun=SUN)
    quiet = render_cube(cam, rscene, tmp_path / "quiet.cub", sun=SUN, gain=160.0, noise_sigma=0.0,
                        stripe_lines=32, tile=(16, 64))
    dn = open_image(quiet.path).values[0]
    np.testing.assert_array_equal(dn, np.clip(np.rint(160.0 * values), 1, 254))   # UnsignedByte, 1..254
    assert quiet.n_null == 0 and quiet.nbytes == os.path.getsize(quiet.path)
    lab = IsisCube(quiet.path)
    assert lab.layout.fmt == "Tile" and lab.layout.dtype == np.uint8 and lab.shape == (1, 128, 256)
    # the noise: a pixel's draw depends on (seed, line, sample) only, not on the stripes
    a = render_cube(cam, rscene, tmp_path / "a.cub", sun=SUN, noise_sigma=2.0, seed=9, stripe_lines=16, tile=(16, 64))
    b = render_cube(cam, rscene, tmp_path / "b.cub", sun=SUN, noise_sigma=2.0, seed=9, stripe_lines=64, tile=(16, 64))
    assert _cube_bytes(a.path) == _cube_bytes(b.path)
    diff = open_image(a.path).values[0] - dn
    assert diff.std() == pytest.approx(np.sqrt(4.0 + 1.0 / 12.0), rel=0.05) and abs(diff.mean()) < 0.05
    assert abs(np.corrcoef(diff[:, :-1].ravel(), diff[:, 1:].ravel())[0, 1]) < 0.03
    # a render that fails half-way leaves no cube and no temporary file
    from lunarmap.simulate import compiled_render

    calls = {"n": 0}
    real = compiled_render.render_window

    def failing(*args, **kw):
        calls["n"] += 1
        if calls["n"] == 2:
            raise MemoryError("simulated")
        return real(*args, **kw)

    monkeypatch.setattr(compiled_render, "render_window", failing)
    with pytest.raises(MemoryError):
        render_cube(cam, rscene, tmp_path / "half.cub", sun=SUN, stripe_lines=32, tile=(16, 64))
    assert sorted(os.listdir(tmp_path)) == ["a.cub", "b.cub", "quiet.cub"]
    with pytest.raises(InvalidInputError, match="seed"):
        render_cube(cam, rscene, tmp_path / "x.cub", seed=-1)
    with pytest.raises(InvalidInputError, match="projected"):
        RenderScene.of(dtm, xr.DataArray(np.zeros((2, 2)), dims=("y", "x")))


def test_render_cube_real_pixels_are_not_rounded(scene, cameras, tmp_path):
    dtm, raster, _ = scene
    cam = cameras["frame"]
    rscene = RenderScene.of(dtm, raster)
    values, _ = render_window(cam, rscene, sun=SUN)
    r = render_cube(cam, rscene, tmp_path / "real.cub", sun=SUN, gain=160.0, noise_sigma=0.0, pixel_type="Real",
                    stripe_lines=64, tile=(64, 64))
    np.testing.assert_allclose(open_image(r.path).values[0], (160.0 * values).astype(np.float32), rtol=1e-7)

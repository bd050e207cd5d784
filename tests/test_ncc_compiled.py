"""The compiled NCC kernels (issue 32) against independent oracles: a brute-force correlation coefficient
per shift (np.corrcoef), bilinear resampling at explicitly formed coordinates, and whole pyramid
searches of the numpy path."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from lunarmap.matching import bilinear, build_pyramid, ncc_compiled, ncc_match
from lunarmap.matching.ncc import window_offsets
from lunarmap.matching.windowed import WindowedImage

pytestmark = pytest.mark.skipif(not ncc_compiled.AVAILABLE, reason="numba not installed")


def _image(shape=(240, 260), seed=0):
    rng = np.random.default_rng(seed)
    img = gaussian_filter(rng.normal(100.0, 40.0, shape), 1.5)
    img[40:52, 60:85] = np.nan                      # invalid pixels: windows touching them fail
    return img


def _brute_force_valid(rho, search, tmpl) -> int:
    """Every shift of ``rho`` (b, k, k) against np.corrcoef of its window of ``search`` and the template: NaN where
    the window holds a NaN, the correlation coefficient elsewhere; returns the number of valid shifts."""
    b, k, _ = rho.shape
    t = tmpl.shape[-1]
    n_valid = 0
    for i in range(b):
        for p in range(k):
            for q in range(k):
                w = search[i, p:p + t, q:q + t]
                if np.isnan(w).any():
                    assert np.isnan(rho[i, p, q])
                    continue
                n_valid += 1
                assert rho[i, p, q] == pytest.approx(np.corrcoef(w.ravel(), tmpl[i].ravel())[0, 1], abs=1e-10)
    return n_valid


def test_affine_windows_are_bilinear_at_the_affine_grid_also_by_window():
    img = _image()
    rng = np.random.default_rng(1)
    b, r = 25, 11
    cl, cs = rng.uniform(-15, 255, b), rng.uniform(-15, 275, b)      # some windows leave the image
    a = np.eye(2) + rng.normal(0.0, 0.25, (b, 2, 2))
    u, v = window_offsets(r)
    gl = cl[:, None, None] + a[:, 0, 0, None, None] * u + a[:, 0, 1, None, None] * v
    gs = cs[:, None, None] + a[:, 1, 0, None, None] * u + a[:, 1, 1, None, None] * v
    ref = bilinear(img, gl, gs)
    for image in (img, WindowedImage(img)):
        out = ncc_compiled.affine_windows(image, cl, cs, a, r)
        assert np.array_equal(np.isnan(out), np.isnan(ref))
        assert np.nanmax(np.abs(out - ref)) < 1e-12


@pytest.mark.parametrize("fft", [False, True])
def test_surface_is_the_correlation_coefficient_of_every_shift(fft, monkeypatch):
    # force either way of forming the cross products
    monkeypatch.setattr(ncc_compiled, "DIRECT_COST", 1.0 if fft else 0.0)
    img = _image(seed=2)
    rng = np.random.default_rng(3)
    b, t, m = 6, 9, 31
    l0 = rng.integers(20, 200, b)
    s0 = rng.integers(20, 220, b)
    search = np.stack([img[y:y + m, x:x + m] for y, x in zip(l0, s0)])
    tmpl = np.stack([img[y + 7:y + 7 + t, x + 5:x + 5 + t] + rng.normal(0, 5, (t, t)) for y, x in zip(l0, s0)])
    tmpl[np.isnan(tmpl)] = 100.0
    rho = ncc_compiled.ncc_surface(tmpl, search)
    k = m - t + 1
    assert rho.shape == (b, k, k)
    assert _brute_force_valid(rho, search, tmpl) > 0.5 * b * k * k
    peak = [np.unravel_index(np.nanargmax(r), r.shape) for r in rho]
    assert all(pk == (7, 5) for pk in peak)          # the template's own position


def test_pyramid_search_equals_the_numpy_path():
    img1 = _image((300, 300), seed=4)
    rng = np.random.default_rng(5)
    a = np.array([[1.05, 0.1], [-0.08, 0.97]])
    ll, ss = np.meshgrid(np.arange(300) + 0.5, np.arange(300) + 0.5, indexing="ij")
    # image 2: image 1 under the affine map about the centre, moved by (13, -9) pixels
    inv = np.linalg.inv(a)
    dl, ds = ll - 150.0 - 13.0, ss - 150.0 + 9.0
    img2 = bilinear(img1, 150.0 + inv[0, 0] * dl + inv[0, 1] * ds, 150.0 + inv[1, 0] * dl + inv[1, 1] * ds)
    n = 80
    l1, s1 = rng.uniform(20, 280, n), rng.uniform(20, 280, n)
    pl = 150.0 + a[0, 0] * (l1 - 150.0) + a[0, 1] * (s1 - 150.0)
    ps = 150.0 + a[1, 0] * (l1 - 150.0) + a[1, 1] * (s1 - 150.0)
    aff = np.broadcast_to(a, (n, 2, 2)).copy()
    p1, p2 = build_pyramid(img1, 3), build_pyramid(img2, 3)
    for search in (6.0, 40.0):
        old = ncc_match(p1, p2, l1, s1, pl, ps, aff, search=search, compiled=False)
        new = ncc_match(p1, p2, l1, s1, pl, ps, aff, search=search, compiled=True)
        assert np.array_equal(np.isnan(old.line), np.isnan(new.line))
        ok = np.isfinite(old.line)
        assert ok.sum() > 0.5 * n
        assert np.max(np.abs(new.line[ok] - old.line[ok])) < 1e-8
        assert np.max(np.abs(new.sample[ok] - old.sample[ok])) < 1e-8
        assert np.max(np.abs(new.correlation[ok] - old.correlation[ok])) < 1e-9
        if search > 10:        # the found shift is the constructed one
            good = ok & (new.correlation > 0.9)
            assert good.sum() > 0.3 * n
            assert np.median(np.abs(new.line[good] - pl[good] - 13.0)) < 0.2
            assert np.median(np.abs(new.sample[good] - ps[good] + 9.0)) < 0.2


@pytest.mark.parametrize("fft", [False, True])
def test_surface_of_windows_reaching_past_the_image_is_the_brute_force_correlation(fft, monkeypatch):
    # issue 32, item 5: the cross products are formed over each window's valid box only (windows that
    # reach past the image edge, as a wide search on a coarse level does); every shift is checked against
    # np.corrcoef of its window, with boxes of different shapes in one batch
    monkeypatch.setattr(ncc_compiled, "DIRECT_COST", 1.0 if fft else 0.0)
    rng = np.random.default_rng(11)
    b, t, m = 9, 7, 29
    search = gaussian_filter(rng.normal(100.0, 40.0, (b, m, m)), (0, 1.0, 1.0))
    tmpl = rng.normal(100.0, 40.0, (b, t, t))
    cuts = [(0, 0, 0, 0), (5, 0, 0, 3), (0, 9, 2, 0), (3, 4, 5, 6), (12, 0, 0, 0), (0, 0, 0, 23), (0, 0, 0, 0),
            (2, 2, 2, 2), (11, 11, 0, 0)]
    search[3, 15, 12] = np.nan                   # an invalid pixel inside the box as well
    whole = []
    for i, (top, bottom, left, right) in enumerate(cuts):
        search[i, :top] = np.nan
        search[i, m - bottom:] = np.nan
        search[i, :, :left] = np.nan
        search[i, :, m - right:] = np.nan
        own = search[i, 14:14 + t, 10:10 + t]
        if np.isfinite(own).all():
            tmpl[i] = own
            whole.append(i)
    rho = ncc_compiled.ncc_surface(tmpl, search)
    k = m - t + 1
    n_valid = _brute_force_valid(rho, search, tmpl)
    assert np.all(np.isnan(rho[5]))              # 6 valid columns: no 7-px template fits
    assert 0 < n_valid < b * k * k
    assert len(whole) >= 4
    for i in whole:                              # the template's own position, where it is still whole
        assert np.unravel_index(np.nanargmax(rho[i]), rho[i].shape) == (14, 10)


def test_surface_equals_the_numpy_surface_on_random_windows():
    # the compiled surface (valid boxes, FFT or direct by cost) against ncc._ncc_surface (direct products
    # over the whole window, integral images by cumsum) on wide windows with invalid margins
    from lunarmap.matching.ncc import _ncc_surface

    rng = np.random.default_rng(12)
    for m, b in ((25, 40), (61, 12), (121, 4)):
        search = rng.normal(100.0, 30.0, (b, m, m))
        for i in range(b):
            a, c = rng.integers(0, m // 2, 2)
            search[i, :a] = np.nan
            search[i, :, m - c:] = np.nan
        tmpl = rng.normal(100.0, 30.0, (b, 15, 15))
        ref = _ncc_surface(tmpl, search)
        out = ncc_compiled.ncc_surface(tmpl, search)
        assert np.array_equal(np.isnan(out), np.isnan(ref))
        assert np.isfinite(ref).any()
        assert np.nanmax(np.abs(out - ref)) < 1e-12


def test_templates_under_the_identity_are_bilinear_bit_for_bit():
    # ncc_match and lsm_match sample their templates by affine_windows under the identity (issue 32,
    # item 5): the very values bilinear gives at the template grid, also by window and at the edges
    img = _image(seed=13)
    rng = np.random.default_rng(14)
    b, r = 40, 7
    cl, cs = rng.uniform(-5, 245, b), rng.uniform(-5, 265, b)
    cl[:5] = np.round(cl[:5]) + 0.5                   # on pixel centres
    u, v = window_offsets(r)
    ref = bilinear(img, cl[:, None, None] + u, cs[:, None, None] + v)
    eye = np.broadcast_to(np.eye(2), (b, 2, 2))
    for image in (img, WindowedImage(img)):
        out = ncc_compiled.affine_windows(image, cl, cs, eye, r)
        assert np.array_equal(out, ref, equal_nan=True)
    assert np.isnan(ref).any() and np.isfinite(ref).any()

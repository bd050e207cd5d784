"""Matching building blocks against closed forms: resampling, pyramid, Förstner, NCC, LSM, RANSAC, tracks."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.errors import InvalidInputError
from lunarmap.matching import (
    BlankTileWarning,
    Observations,
    RansacParams,
    bicubic,
    bicubic_with_gradient,
    bilinear,
    build_pyramid,
    build_tracks,
    foerstner,
    lsm_match,
    ncc_match,
    predict_conjugates,
    ransac_local_affine,
)
from lunarmap.simulate import stereo_pair

RNG = np.random.default_rng(11)
# A band-limited analytic texture with a red spectrum (as real images have, so that pyramid
# levels still hold texture): 60 sinusoids, wavelengths 4 to 64 pixels, amplitude ~ wavelength^0.5.
_F = np.exp(RNG.uniform(np.log(1 / 64), np.log(1 / 4), 60))
_DIR = RNG.uniform(0, 2 * np.pi, 60)
_K = 2 * np.pi * _F[:, None] * np.column_stack([np.cos(_DIR), np.sin(_DIR)])
_PH = RNG.uniform(0, 2 * np.pi, 60)
_AM = 3.0 * _F ** -0.5 / np.sqrt(np.mean(1 / _F)) * RNG.uniform(0.5, 1.5, 60)


def texture(line: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """Grey levels of the analytic texture at continuous CSM coordinates."""
    arg = line[..., None] * _K[:, 0] + sample[..., None] * _K[:, 1] + _PH
    return 120.0 + np.sum(_AM * np.cos(arg), axis=-1)


def raster(shape: tuple[int, int], fn) -> np.ndarray:
    li, si = np.meshgrid(np.arange(shape[0]) + 0.5, np.arange(shape[1]) + 0.5, indexing="ij")
    return fn(li, si)


def test_bilinear_and_bicubic_reproduce_polynomials() -> None:
    f = lambda l, s: 3 + 0.5 * l - 0.2 * s + 0.01 * l * l + 0.02 * l * s - 0.03 * s * s  # noqa: E731
    img = raster((20, 30), f)
    lq = RNG.uniform(3, 17, 200)
    sq = RNG.uniform(3, 27, 200)
    v, dl, ds = bicubic_with_gradient(img, lq, sq)
    assert np.allclose(v, f(lq, sq), atol=1e-10)
    assert np.allclose(dl, 0.5 + 0.02 * lq + 0.02 * sq, atol=1e-10)
    assert np.allclose(ds, -0.2 + 0.02 * lq - 0.06 * sq, atol=1e-10)
    lin = raster((20, 30), lambda l, s: 2 * l - s)
    assert np.allclose(bilinear(lin, lq, sq), 2 * lq - sq)
    # CSM edges: pixel centres 0.5 .. H - 0.5 exist, beyond is NaN
    assert np.isnan(bilinear(lin, 0.4, 5.0)) and np.isfinite(bilinear(lin, 0.5, 5.0))
    assert np.isnan(bicubic_with_gradient(img, 1.4, 5.0)[0])
    # values alone: the same numbers, the same NaN border, scalars stay 0-d
    assert np.array_equal(bicubic(img, lq, sq), v)
    assert np.isnan(bicubic(img, 1.4, 5.0)) and np.ndim(bicubic(img, 5.0, 5.0)) == 0
    assert bicubic(img, 5.0, 5.0) == pytest.approx(f(5.0, 5.0), abs=1e-10)


def test_pyramid_keeps_csm_coordinates() -> None:
    ramp = raster((64, 48), lambda l, s: 3 * l + s)
    pyr = build_pyramid(ramp, 3)
    assert [p.shape for p in pyr] == [(64, 48), (32, 24)]  # stops before images under 32 px
    # A linear ramp: level-1 value at x / 2 equals level-0 value at x.
    assert np.allclose(bilinear(pyr[1], 20.0 / 2, 13.0 / 2), 3 * 20.0 + 13.0)


def test_foerstner_finds_blobs_spreads_and_flags_blank_tiles() -> None:
    centres = np.array([[20.5, 30.5], [60.5, 20.5], [90.5, 100.5], [40.5, 80.5]])
    def blobs(l, s):  # noqa: E306
        return 50 + sum(100 * np.exp(-((l - c[0]) ** 2 + (s - c[1]) ** 2) / 8.0) for c in centres)
    img = raster((120, 128), blobs)
    pts = foerstner(img, cell=128, per_cell=4, border=5)
    found = np.column_stack([pts.line, pts.sample])
    d = np.linalg.norm(found[:, None] - centres[None], axis=-1).min(axis=0)
    assert np.all(d <= 1.0)
    many = foerstner(raster((128, 128), texture), cell=32, per_cell=2)
    cells = (many.line // 32).astype(int) * 10 + (many.sample // 32).astype(int)
    assert np.bincount(cells).max() <= 2 and len(many) >= 20
    with pytest.warns(BlankTileWarning, match="no texture"):
        assert len(foerstner(np.full((64, 64), 255.0), label="saturated tile")) == 0
    with pytest.warns(BlankTileWarning, match="NaN"):
        assert len(foerstner(np.full((64, 64), np.nan))) == 0


def _affine_pair(shift: tuple[float, float], a: np.ndarray, gain: float = 1.2, offset: float = -15.0,
                 noise: float = 0.0, seed: int = 0):
    """image2(x2) = offset + gain * texture(A^-1 (x2 - c - t) + c): x1 maps to x2 = c + A (x1 - c) + t."""
    c = np.array([64.0, 64.0])
    ainv = np.linalg.inv(a)
    def img2(l, s):  # noqa: E306
        d = np.stack([l - c[0] - shift[0], s - c[1] - shift[1]], axis=-1)
        x1 = d @ ainv.T + c
        return offset + gain * texture(x1[..., 0], x1[..., 1])
    rng = np.random.default_rng(seed)
    i1 = raster((128, 128), texture) + rng.normal(0, noise, (128, 128))
    i2 = raster((128, 128), img2) + rng.normal(0, noise, (128, 128))

    def truth(l1: np.ndarray, s1: np.ndarray) -> np.ndarray:
        return (np.stack([l1, s1], -1) - c) @ a.T + c + np.asarray(shift)
    return i1, i2, truth


def test_lsm_recovers_affine_and_radiometry() -> None:
    a = np.array([[1.05, 0.08], [-0.06, 0.93]])
    i1, i2, truth = _affine_pair((2.3, -1.7), a)
    l1 = np.array([40.5, 64.5, 80.5, 50.5])
    s1 = np.array([40.5, 64.5, 70.5, 90.5])
    true2 = truth(l1, s1)
    # Start 0.4 px off with the identity's affine part off by a few percent.
    start_aff = np.broadcast_to(a + 0.03, (4, 2, 2))
    res = lsm_match(i1, i2, l1, s1, true2[:, 0] + 0.4, true2[:, 1] - 0.3, start_aff, half=7)
    assert res.converged.all()
    assert np.max(np.hypot(res.line - true2[:, 0], res.sample - true2[:, 1])) < 0.02
    assert np.allclose(res.params[:, [1, 2, 4, 5]], a.ravel()[None, [0, 1, 2, 3]], atol=0.01)
    # g1 = h0 + h1 g2 -> h1 = 1 / gain (cubic interpolation slightly damps the shortest waves)
    assert np.allclose(res.params[:, 7], 1 / 1.2, atol=0.02)
    assert np.allclose(res.params[:, 6], 15.0 / 1.2, atol=3.0)
    assert np.all(res.correlation > 0.99)


@pytest.mark.parametrize("a, shift", [(np.eye(2), (0.0, 0.0)), (np.eye(2), (0.25, 0.6)),
                                      (np.array([[1.05, 0.08], [-0.06, 0.93]]), (2.3, -1.7))],
                         ids=["whole-pixel", "sub-pixel", "affine-warped"])
def test_lsm_sigma_matches_monte_carlo_scatter(a, shift) -> None:
    """Issue 11: RMS of error / sigma is 1 +- 0.2 with noise in both images (sigma 3 grey levels).

    Before the pre-smoothing and the correlated-noise covariance the matches locked onto half
    pixels (mean error 0.11 px at a 0.25 px shift) and error / sigma had an RMS of 1.7-4.4.
    """
    errs, sig = [], []
    for seed in range(6):
        i1, i2, truth = _affine_pair(shift, a, noise=3.0, seed=seed)
        g = np.arange(20.5, 108, 8.0)
        l1, s1 = (x.ravel() for x in np.meshgrid(g, g, indexing="ij"))
        t2 = truth(l1, s1)
        r = lsm_match(i1, i2, l1, s1, t2[:, 0], t2[:, 1], np.broadcast_to(a, (l1.size, 2, 2)))
        ok = r.converged
        assert ok.mean() > 0.95
        errs.append(np.column_stack([r.line[ok] - t2[ok, 0], r.sample[ok] - t2[ok, 1]]))
        sig.append(np.column_stack([r.sigma_line[ok], r.sigma_sample[ok]]))
    e = np.concatenate(errs)
    z = np.sqrt(np.mean((e / np.concatenate(sig)) ** 2, axis=0))
    assert np.all((z > 0.8) & (z < 1.2)), z
    assert np.all(np.abs(e.mean(axis=0)) < 0.02), e.mean(axis=0)   # no sub-pixel locking


def test_lsm_relief_terms_and_bad_presmooth() -> None:
    """A quadratic displacement along the epipolar direction is recovered by the relief terms, not by the centre."""
    q = np.array([0.004, -0.002, 0.003])          # pixels per pixel^2 along e
    e = np.array([0.6, 0.8])
    c = np.array([64.0, 64.0])

    def img2(l, s):   # image 2 at x1 + e q(x1 - c) is image 1 at x1 (to first order in q)
        d = np.stack([l - c[0], s - c[1]], -1)
        quad = q[0] * d[..., 0] ** 2 + q[1] * d[..., 0] * d[..., 1] + q[2] * d[..., 1] ** 2
        return texture(l - e[0] * quad, s - e[1] * quad)
    i1 = raster((128, 128), texture)
    i2 = raster((128, 128), img2)
    l1 = np.array([64.5, 60.5, 70.5])
    s1 = np.array([64.5, 66.5, 58.5])
    d = np.stack([l1 - c[0], s1 - c[1]], -1)
    true_q = q[0] * d[:, 0] ** 2 + q[1] * d[:, 0] * d[:, 1] + q[2] * d[:, 1] ** 2
    true2 = np.stack([l1, s1], -1) + e * true_q[:, None]
    r = lsm_match(i1, i2, l1, s1, l1 + 0.3, s1 - 0.2, np.broadcast_to(np.eye(2), (3, 2, 2)),
                  epipolar=np.broadcast_to(e * 0.05, (3, 2)))
    assert r.converged.all()
    assert np.max(np.hypot(r.line - true2[:, 0], r.sample - true2[:, 1])) < 0.04
    np.testing.assert_allclose(r.relief, np.broadcast_to(q, (3, 3)), atol=6e-4)   # to first order in q
    flat = lsm_match(i1, i2, l1, s1, l1 + 0.3, s1 - 0.2, np.broadcast_to(np.eye(2), (3, 2, 2)))
    assert np.min(np.hypot(flat.line - true2[:, 0], flat.sample - true2[:, 1])) > 0.1   # the average plane
    with pytest.raises(InvalidInputError, match="presmooth"):
        lsm_match(i1, i2, l1, s1, l1, s1, np.broadcast_to(np.eye(2), (3, 2, 2)), presmooth=-1.0)


def test_pyramid_ncc_finds_large_shift_under_rotation() -> None:
    ang = np.radians(25.0)
    a = 1.3 * np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    i1, i2, truth = _affine_pair((9.0, -12.0), a)
    l1 = np.array([50.5, 60.5, 70.5])
    s1 = np.array([60.5, 70.5, 55.5])
    t2 = truth(l1, s1)
    pred_l = t2[:, 0] - 9.0  # prediction misses the shift (e.g. unknown height)
    pred_s = t2[:, 1] + 12.0
    res = ncc_match(build_pyramid(i1, 3), build_pyramid(i2, 3), l1, s1, pred_l, pred_s,
                    np.broadcast_to(a, (3, 2, 2)), half=7, search=16.0)
    assert np.all(np.hypot(res.line - t2[:, 0], res.sample - t2[:, 1]) < 0.5)
    assert np.all(res.correlation > 0.9)
    with pytest.raises(InvalidInputError):
        ncc_match([i1], [i2], l1, s1, pred_l, pred_s, np.broadcast_to(a, (3, 2, 2)), half=0)


def test_prediction_identity_and_epipolar_linearity() -> None:
    c1, c2 = stereo_pair("linescan", 0.0, n_lines=100, n_samples=100)
    p = predict_conjugates(c1, c2, [30.5, 70.5], [20.5, 80.5], 0.0)
    assert np.allclose(p.line, [30.5, 70.5], atol=1e-6) and np.allclose(p.affine, np.eye(2), atol=1e-5)
    c1, c2 = stereo_pair("linescan", 30.0, n_lines=100, n_samples=100)
    p0 = predict_conjugates(c1, c2, [50.0], [50.0], 0.0)
    p1 = predict_conjugates(c1, c2, [50.0], [50.0], 20.0)
    # Moving 20 m up moves the conjugate by ~20 e (linear over this range).
    assert np.allclose([p1.line[0] - p0.line[0], p1.sample[0] - p0.sample[0]], 20 * p0.epipolar[0], atol=0.02)
    # Closed form: parallax 2 tan(e) metres on the ground per metre of height, over the
    # oblique pixel footprint rho * (pitch / f) / cos(e) across track (e = 15 deg emission).
    target = c1.image_to_ground(50.0, 50.0, height=0.0)
    rho = np.linalg.norm(c2.sensor_position(50.0, 50.0) - target)
    e = np.radians(15.0)
    footprint = rho * (0.007 / 699.62) / np.cos(e)
    assert np.hypot(*p0.epipolar[0]) == pytest.approx(2 * np.tan(e) / footprint, rel=0.01)


def test_ransac_removes_mismatches_keeps_relief_parallax() -> None:
    rng = np.random.default_rng(7)
    n = 600
    p1 = rng.uniform(0, 500, (n, 2))
    e = np.tile([0.05, 0.7], (n, 1))  # epipolar direction, px per metre
    heights = rng.normal(0, 1.5, n)  # relief off the plane, metres -> parallax up to ~3 px along e
    resid = np.array([0.3, -0.8]) + p1 @ np.array([[1e-3, 0.0], [2e-4, -5e-4]]) + heights[:, None] * e
    resid += rng.normal(0, 0.05, (n, 2))
    bad = rng.random(n) < 0.2
    ang = rng.uniform(0, 2 * np.pi, bad.sum())
    mag = rng.uniform(3.5, 30.0, bad.sum())
    resid[bad] += np.column_stack([np.cos(ang), np.sin(ang)]) * mag[:, None]
    inl = ransac_local_affine(p1[:, 0], p1[:, 1], resid[:, 0], resid[:, 1], e,
                              RansacParams(tol_along=3.5 * 0.7 * 1.5, tol_cross=1.0))
    removed = np.mean(~inl[bad])
    kept = np.mean(inl[~bad])
    assert removed >= 0.99 and kept >= 0.95, (removed, kept)


def test_ransac_adapts_to_strong_relief_parallax_and_tolerates_missing_epipolar() -> None:
    """High convergence: relief parallax along the epipolar line far beyond ``tol_along``.

    True matches must stay (their cross-epipolar residual is tiny); mismatches are still
    removed; a few points without an epipolar direction (NaN) must not switch the test to
    the isotropic 1-pixel tolerance for the whole pair.
    """
    rng = np.random.default_rng(11)
    n = 600
    p1 = rng.uniform(0, 500, (n, 2))
    e = np.tile([0.1, 1.0], (n, 1))           # ~1 px per metre, as at 30 deg convergence
    heights = rng.normal(0, 3.0, n)            # relief off the plane -> parallax sigma 3 px along e
    resid = np.array([0.3, -0.8]) + heights[:, None] * e + rng.normal(0, 0.05, (n, 2))
    bad = rng.random(n) < 0.2
    ang = rng.uniform(0, 2 * np.pi, bad.sum())
    mag = rng.uniform(4.0, 40.0, bad.sum())
    resid[bad] += np.column_stack([np.cos(ang), np.sin(ang)]) * mag[:, None]
    e[rng.choice(n, 5, replace=False)] = np.nan
    inl = ransac_local_affine(p1[:, 0], p1[:, 1], resid[:, 0], resid[:, 1], e)
    removed, kept = np.mean(~inl[bad]), np.mean(inl[~bad])
    assert removed >= 0.95 and kept >= 0.97, (removed, kept)
    # the fixed tolerance (the old behaviour) would drop most true matches here
    fixed = ransac_local_affine(p1[:, 0], p1[:, 1], resid[:, 0], resid[:, 1], e, RansacParams(along_mad=0.0))
    assert np.mean(fixed[~bad]) < 0.8


def test_tracks_join_observations_and_drop_conflicts() -> None:
    obs = Observations(
        image=np.array([0, 1, 0, 2, 1, 2, 0, 1, 0, 1]), node=np.array([0, 10, 0, 11, 12, 13, 5, 20, 5, 21]),
        line=np.array([5., 7, 5, 9, 7.2, 9.1, 50, 60, 50, 70]), sample=np.array([5., 7, 5, 9, 7, 9, 50, 60, 50, 60]),
        sigma_line=np.full(10, 0.1), sigma_sample=np.full(10, 0.1), correlation=np.ones(10),
        edge_a=np.array([0, 2, 4, 6, 8]), edge_b=np.array([1, 3, 5, 7, 9]))
    table, conflicts = build_tracks(obs)
    # Feature 1 is in images 0, 1, 2; feature 2 has two different positions in image 1 -> dropped.
    assert conflicts == 1
    assert sorted(table["image_id"]) == [0, 1, 2] and table["point_id"].nunique() == 1
    assert table.loc[table.image_id == 1, "line"].item() == pytest.approx(7.1)

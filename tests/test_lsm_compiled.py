"""The compiled normal equations of least-squares matching (issue 32, item 5) against the numpy path
(design matrix, batched matrix products) and against a brute-force J^T J of an explicitly formed
Jacobian, on random images and matches (some failing, some with relief terms held)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from lunarmap.errors import InvalidInputError
from lunarmap.matching import lsm
from lunarmap.matching.lsm import lsm_match

pytestmark = pytest.mark.skipif(lsm._normals_kernel is None, reason="numba not installed")


def _pair(seed: int = 0, shape=(160, 170)):
    """Image 2 = image 1 under a small affine map and radiometric change, with independent noise."""
    from lunarmap.matching import bicubic

    rng = np.random.default_rng(seed)
    i1 = gaussian_filter(rng.normal(100.0, 40.0, shape), 1.6)
    a = np.array([[1.04, 0.07], [-0.05, 0.95]])
    ainv = np.linalg.inv(a)
    ll, ss = np.meshgrid(np.arange(shape[0]) + 0.5, np.arange(shape[1]) + 0.5, indexing="ij")
    dl, ds = ll - 80.0 - 1.3, ss - 85.0 + 0.8
    i2 = 10.0 + 1.1 * bicubic(i1, 80.0 + ainv[0, 0] * dl + ainv[0, 1] * ds, 85.0 + ainv[1, 0] * dl + ainv[1, 1] * ds)
    i1 = i1 + rng.normal(0.0, 2.0, shape)
    i2 = i2 + rng.normal(0.0, 2.0, shape)
    i2[100:110, 30:45] = np.nan                   # windows touching them fail
    n = 150
    l1, s1 = rng.uniform(6, shape[0] - 6, n), rng.uniform(6, shape[1] - 6, n)   # some windows leave the image
    d = np.stack([l1 - 80.0, s1 - 85.0], -1) @ a.T
    l2 = 80.0 + 1.3 + d[:, 0] + rng.normal(0.0, 0.4, n)
    s2 = 85.0 - 0.8 + d[:, 1] + rng.normal(0.0, 0.4, n)
    aff = np.broadcast_to(a + rng.normal(0.0, 0.02, (2, 2)), (n, 2, 2)).copy()
    epi = np.tile([0.03, 0.04], (n, 1))
    epi[::7] = 0.0                                # no epipolar direction: relief terms held at 0
    return i1, i2, l1, s1, l2, s2, aff, epi


@pytest.mark.parametrize("relief", [False, True])
@pytest.mark.parametrize("presmooth", [0.0, 1.0])
def test_compiled_normals_give_the_numpy_matches(relief, presmooth):
    i1, i2, l1, s1, l2, s2, aff, epi = _pair(1)
    kw = dict(presmooth=presmooth, epipolar=epi if relief else None)
    ref = lsm_match(i1, i2, l1, s1, l2, s2, aff, compiled=False, **kw)
    out = lsm_match(i1, i2, l1, s1, l2, s2, aff, compiled=True, **kw)
    assert np.array_equal(ref.converged, out.converged)
    assert 0.5 * l1.size < ref.converged.sum() < l1.size           # some fail (edges, NaN pixels)
    assert np.array_equal(ref.iterations, out.iterations)
    ok = ref.converged
    assert np.max(np.abs(out.line[ok] - ref.line[ok])) < 1e-10
    assert np.max(np.abs(out.sample[ok] - ref.sample[ok])) < 1e-10
    assert np.max(np.abs(out.sigma_line[ok] / ref.sigma_line[ok] - 1.0)) < 1e-9
    assert np.max(np.abs(out.correlation[ok] - ref.correlation[ok])) < 1e-12
    assert np.max(np.abs(out.params[ok] - ref.params[ok])) < 1e-9
    assert np.max(np.abs(out.relief[ok] - ref.relief[ok])) < 1e-12
    assert np.all(np.isnan(out.line[~ok]))


@pytest.mark.parametrize("relief", [False, True])
def test_compiled_normals_are_the_brute_force_normal_equations(relief):
    # J formed column by column from its definition (Eq. 14 linearised), J^T J and J^T r by np.dot
    rng = np.random.default_rng(2)
    k, t = 5, 9
    npx = t * t
    u, w = (x.ravel() for x in np.meshgrid(np.arange(t) - 4.0, np.arange(t) - 4.0, indexing="ij"))
    g1, g2, dl, ds = (rng.normal(0.0, 30.0, (k, npx)) for _ in range(4))
    h0, h1 = rng.normal(0.0, 5.0, k), rng.uniform(0.8, 1.2, k)
    direction = rng.normal(0.0, 1.0, (k, 2))
    bad = np.array([False, True, False, False, False])
    P = 11 if relief else 8
    nmat, rhs, r = np.empty((k, P, P)), np.empty((k, P)), np.empty((k, npx))
    lsm._normals_kernel(g1, g2, dl, ds, h0, h1, u, w, direction, relief, bad, nmat, rhs, r)
    for b in range(k):
        if bad[b]:
            assert not nmat[b].any() and not rhs[b].any() and not r[b].any()
            continue
        gl, gs = h1[b] * dl[b], h1[b] * ds[b]
        cols = [gl, gl * u, gl * w, gs, gs * u, gs * w, np.ones(npx), g2[b]]
        if relief:
            e = gl * direction[b, 0] + gs * direction[b, 1]
            cols += [e * u * u, e * u * w, e * w * w]
        jac = np.column_stack(cols)
        res = g1[b] - h0[b] - h1[b] * g2[b]
        np.testing.assert_allclose(r[b], res, rtol=1e-13, atol=1e-10)
        np.testing.assert_allclose(nmat[b], jac.T @ jac, rtol=1e-12)
        np.testing.assert_allclose(rhs[b], jac.T @ res, rtol=1e-12, atol=1e-8)


def test_compiled_without_numba_is_refused(monkeypatch):
    i1, i2, l1, s1, l2, s2, aff, _ = _pair(3)
    monkeypatch.setattr(lsm, "_normals_kernel", None)
    with pytest.raises(InvalidInputError, match="numba"):
        lsm_match(i1, i2, l1[:3], s1[:3], l2[:3], s2[:3], aff[:3], compiled=True)
    assert lsm_match(i1, i2, l1[:3], s1[:3], l2[:3], s2[:3], aff[:3]).line.shape == (3,)   # the numpy path

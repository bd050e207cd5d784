"""Reseau correction per grid cell (Ranger paper): a simulated 5 x 5 reseau with a known film distortion.

The film distortion (truth) maps calibrated photo coordinates to where they appear on the measured
print: an affine part (2 % scale difference, shear), a projective part (a tilted print/vidicon) and a
smooth non-projective radial part of 10 um at the corners of the 170 mm grid. The reseau marks are
measured with 10 um noise (the paper's glass-scale reading). The correction is compared with the
truth on a dense grid of check points.
"""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.errors import ReseauError
from lunarmap.missions import ReseauCorrection, ReseauGrid
from lunarmap.missions.reseau import apply_projective, fit_projective

SIGMA = 0.010          # mm, mark measurement noise
SPACING = 42.5         # mm on the print (the paper's Fig. 6)
RADIAL = 0.010         # mm, non-projective distortion at the grid corners


def film(x, y, radial=RADIAL):
    u = 1.02 * x + 0.006 * y + 0.3
    v = -0.004 * x + 0.985 * y - 0.2
    w = 1 + 2e-4 * x - 1e-4 * y
    u, v = u / w, v / w
    r2 = (x * x + y * y) / (2 * 85.0 ** 2)
    return u + radial * x / 85.0 * r2, v + radial * y / 85.0 * r2


@pytest.fixture(scope="module")
def grid():
    return ReseauGrid.regular(5, 5, SPACING)


def measured_marks(grid, rng=None, radial=RADIAL):
    cal = grid.calibrated
    m = np.stack(film(cal[..., 0], cal[..., 1], radial), axis=-1)
    return m if rng is None else m + rng.normal(0.0, SIGMA, m.shape)


def check_grid():
    X, Y = np.meshgrid(np.linspace(-85, 85, 121), np.linspace(-85, 85, 121))
    return X.ravel(), Y.ravel()


def test_projective_per_cell_removes_the_distortion_to_a_tenth_of_the_mark_noise(grid):
    corr = ReseauCorrection(grid, measured_marks(grid), "projective")
    X, Y = check_grid()
    u, v = film(X, Y)
    cx, cy = corr.apply(u, v)
    err = np.hypot(cx - X, cy - Y)
    raw = np.hypot(u - X, v - Y)
    rms = float(np.sqrt(np.mean(err ** 2)))
    print(f"reseau, projective per cell, noise-free marks: distortion up to {raw.max():.3f} mm -> residual RMS "
          f"{rms * 1e3:.2f} um ({rms / SIGMA:.3f} sigma), max {err.max() * 1e3:.2f} um ({err.max() / SIGMA:.3f} sigma)")
    assert rms <= 0.1 * SIGMA
    assert err.max() <= 0.2 * SIGMA
    assert raw.max() > 3.0     # the distortion itself is 300 sigma


def test_projective_per_cell_is_exact_for_a_projective_film(grid):
    corr = ReseauCorrection(grid, measured_marks(grid, radial=0.0), "projective")
    X, Y = check_grid()
    cx, cy = corr.apply(*film(X, Y, radial=0.0))
    assert np.abs(np.hypot(cx - X, cy - Y)).max() < 1e-9


def test_with_noisy_marks_the_error_is_the_propagated_mark_noise(grid):
    """Monte Carlo: the corrected coordinates carry a fraction of the mark noise (interpolation weights)."""
    rng = np.random.default_rng(4)
    errs = []
    for _ in range(150):
        corr = ReseauCorrection(grid, measured_marks(grid, rng), "projective")
        p = rng.uniform(-84, 84, (40, 2))
        cx, cy = corr.apply(*film(p[:, 0], p[:, 1]))
        errs.append(np.column_stack([cx - p[:, 0], cy - p[:, 1]]))
    e = np.concatenate(errs)
    rms = np.sqrt(np.mean(e ** 2, axis=0))
    print(f"noisy marks (sigma {SIGMA * 1e3:.0f} um): corrected coordinates RMS {rms[0] * 1e3:.2f} / "
          f"{rms[1] * 1e3:.2f} um, bias {np.abs(e.mean(axis=0)).max() * 1e3:.2f} um")
    assert np.all(rms < SIGMA) and np.all(rms > 0.5 * SIGMA)
    assert np.abs(e.mean(axis=0)).max() < 0.1 * SIGMA


def test_bilinear_is_continuous_and_exact_at_the_marks(grid):
    m = measured_marks(grid)
    corr = ReseauCorrection(grid, m, "bilinear")
    cx, cy = corr.apply(m[..., 0].ravel(), m[..., 1].ravel())
    assert np.abs(cx - grid.calibrated[..., 0].ravel()).max() < 1e-10
    # along a shared edge both neighbouring cells give the same point (within a hair of the edge)
    a, b = m[1, 2], m[2, 2]
    for s in np.linspace(0.05, 0.95, 7):
        p = a + s * (b - a)
        n = np.array([-(b - a)[1], (b - a)[0]]) / np.linalg.norm(b - a) * 1e-9
        left, right = corr.apply(*(p + n)), corr.apply(*(p - n))
        assert np.hypot(left[0] - right[0], left[1] - right[1]) < 1e-8
    # a bilinear cell cannot follow the projective part of this film: it is the paper's choice that works here
    X, Y = check_grid()
    bx, by = corr.apply(*film(X, Y))
    assert np.hypot(bx - X, by - Y).max() > 10 * SIGMA


def test_report_per_mark(grid):
    corr = ReseauCorrection(grid, measured_marks(grid), "projective")
    rep = corr.report()
    assert rep.sizes["mark"] == 25 and list(rep.mark.values[:2]) == ["r0c0", "r0c1"]
    # a global affine leaves the projective + radial film distortion, a global projective only the radial
    assert rep.attrs["rms_affine_mm"] > 0.2
    assert 0.1 * RADIAL < rep.attrs["rms_projective_mm"] < RADIAL
    assert float(np.abs(rep.residual_cells).max()) == 0.0


def test_fit_projective_recovers_a_homography():
    h = np.array([[1.01, 0.02, 3.0], [-0.01, 0.99, -2.0], [1e-4, -2e-4, 1.0]])
    src = np.random.default_rng(1).uniform(-80, 80, (12, 2))
    dst = np.column_stack(apply_projective(h, src[:, 0], src[:, 1]))
    assert np.abs(fit_projective(src, dst) - h).max() < 1e-12


# -- bad input ---------------------------------------------------------------------------------------

def test_missing_marks_are_named(grid):
    m = measured_marks(grid)
    m[0, 3] = np.nan
    m[4, 4] = np.nan
    with pytest.raises(ReseauError, match=r"2 of 25 reseau marks are missing \(r0c3, r4c4\).*25 are needed"):
        ReseauCorrection(grid, m)


def test_too_few_marks_for_a_grid():
    with pytest.raises(ReseauError, match="rows >= 2, cols >= 2"):
        ReseauGrid(np.zeros((1, 5, 2)))
    grid = ReseauGrid.regular(5, 5, SPACING)
    with pytest.raises(ReseauError, match="shape"):
        ReseauCorrection(grid, np.zeros((4, 5, 2)))


def test_folded_cell_and_outside_points(grid):
    m = measured_marks(grid)
    m[2, 2] = m[2, 3] + 1.0          # the centre mark lands beyond its neighbour
    with pytest.raises(ReseauError, match="cell .* not a convex quadrilateral"):
        ReseauCorrection(grid, m)
    corr = ReseauCorrection(grid, measured_marks(grid))
    with pytest.raises(ReseauError, match="outside the reseau"):
        corr.apply([200.0], [0.0])
    x, y = corr.apply([200.0, 0.0], [0.0, 0.0], outside="nan")
    assert np.isnan(x[0]) and np.isfinite(x[1])
    x, _ = corr.apply([90.0], [0.0], outside="extrapolate")
    assert np.isfinite(x[0])

"""Attitude jitter in the truth of the simulated line-scan site (issue 30, item 4): sinusoids of given
amplitude and frequency with random phases in the TRUE cameras only (oracle: the jitter-free block of the
same seed, and a least-squares sinusoid fit of the true cameras' relative attitude)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from lunarmap.errors import InvalidInputError
from lunarmap.orientation.rotation import matrix_to_rotvec
from lunarmap.simulate import linescan_site

KW = dict(rolls=(-10.0, 0.0, 10.0), n_points=30, n_lines=1500, n_samples=600, seed=5, point_extent=1.0)


@pytest.fixture(scope="module")
def blocks():
    return linescan_site(**KW), linescan_site(**KW, jitter=[(2e-6, 5.0), (1e-6, 9.0)], jitter_images=(0, 2))


def test_jitter_is_in_the_truth_only(blocks):
    free, jit = blocks
    t = free.nav_cameras[0].image_time(np.linspace(0, 1500, 50))
    for a, b in zip(free.nav_cameras, jit.nav_cameras):
        np.testing.assert_array_equal(a.eo.quaternions, b.eo.quaternions)
    np.testing.assert_allclose(free.true_points, jit.true_points)
    # the image without jitter: same truth, same measurements
    np.testing.assert_allclose(free.true_cameras[1].eo.rotation_at(t), jit.true_cameras[1].eo.rotation_at(t),
                               atol=1e-15)
    m1 = free.measurements.cam_idx == 1
    np.testing.assert_allclose(free.measurements.xy[m1], jit.measurements.xy[jit.measurements.cam_idx == 1])
    assert jit.true_jitter[1][0].size == 0 and jit.true_jitter[0][1].shape[1] == 3
    # a jittered image's measurements move by the jitter (0.1-0.3 px for 2 + 1 urad at 10 urad a pixel)
    m0 = free.measurements.cam_idx == 0
    d = np.abs(free.measurements.xy[m0] - jit.measurements.xy[jit.measurements.cam_idx == 0])
    assert 0.02 < np.max(d) < 0.5


def test_jitter_has_the_given_amplitudes_and_frequencies(blocks):
    free, jit = blocks
    for i in (0, 2):
        lines = np.linspace(0, 1500, 800)
        t = free.true_cameras[i].image_time(lines)
        # true jittered = smooth truth exp([j]x)^T  ->  j = rotvec(R_jit^T R_free)
        j = matrix_to_rotvec(np.swapaxes(jit.true_cameras[i].eo.rotation_at(t), -1, -2)
                             @ free.true_cameras[i].eo.rotation_at(t))
        A = np.column_stack([np.sin(2 * np.pi * 5 * t), np.cos(2 * np.pi * 5 * t),
                             np.sin(2 * np.pi * 9 * t), np.cos(2 * np.pi * 9 * t)])
        coef, *_ = np.linalg.lstsq(A, j, rcond=None)
        np.testing.assert_allclose(np.hypot(coef[0], coef[1]), 2e-6, rtol=1e-3)
        np.testing.assert_allclose(np.hypot(coef[2], coef[3]), 1e-6, rtol=1e-3)
        np.testing.assert_allclose(A @ coef, j, atol=1e-10)
        # the recorded truth is the same function (its records 2 ms apart, interpolated by a cubic spline)
        tj, aj = jit.true_jitter[i]
        np.testing.assert_allclose(CubicSpline(tj, aj)(t), j, atol=1e-11)


def test_noise_and_bad_input():
    sb = linescan_site(**KW, jitter_noise=1e-7)
    a = sb.true_jitter[0][1]
    assert 0.8e-7 < np.std(a) < 1.2e-7
    for bad in (dict(jitter=[(2e-6, 0.0)]), dict(jitter=[(-1e-6, 5.0)]), dict(jitter_noise=-1.0),
                dict(jitter=[(1e-6, 5.0)], jitter_step=0.0), dict(point_extent=0.0)):
        with pytest.raises(InvalidInputError):
            linescan_site(**{**KW, **bad})

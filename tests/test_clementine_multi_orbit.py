"""Clementine multi-orbit block through the real UVVIS camera (shared kernel set), navigation adjustment.

Truth: :func:`lunarmap.simulate.frame_block` with the interior orientation that the Clementine driver builds
from the real IK and label (with its OD_K distortion); navigation with per-orbit offsets and drifts. The
adjusted points, image corrections and offsets/drifts are compared with the truth through their posterior
sigma (normalised errors ~ 1).
"""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.missions.clementine import adjust_multi_orbit, clementine_multi_orbit, uvvis_interior

pytestmark = pytest.mark.shared


@pytest.fixture(scope="module")
def interior(clementine_set):
    return uvvis_interior(clementine_set / "LUA3107H.161_isis3.lbl", clementine_set / "clementine_uvvis_LUA3107H161.tm")


def test_real_uvvis_interior(interior):
    assert interior.focal_length == 89.874444 and (interior.n_samples, interior.n_lines) == (384, 288)
    assert interior.distortion_model == "radial"
    assert interior.distortion_coefficients == {"coefficients": [0.0, -2.422842e-05, 0.0]}
    assert interior.pixel_pitch == pytest.approx(0.023, rel=1e-9)
    assert (interior.detector_center_line, interior.detector_center_sample) == (144.0, 192.0)


@pytest.mark.slow
def test_multi_orbit_block_adjusts_to_its_truth(interior):
    sb = clementine_multi_orbit(interior, orbits=3, per_orbit=10, points=700, n_check=30, seed=3)
    assert all(c.interior is interior for c in sb.true_cameras)
    assert np.unique(sb.orbit).size == 3 and np.abs(sb.true_offsets[:, 3:]).max() > 20.0    # metres per orbit
    _, f = adjust_multi_orbit(sb)
    print("Clementine multi-orbit (real UVVIS IK): " + ", ".join(
        f"{k} {np.round(v, 3) if isinstance(v, np.ndarray) else round(v, 3)}" for k, v in f.items()))
    assert 0.85 < f["sigma0"] < 1.15
    assert abs(f["points_z_rms"] - 1) < 0.2 and abs(f["images_z_rms"] - 1) < 0.25
    assert abs(f["offsets_drifts_z_rms"] - 1) < 0.4 and f["offsets_drifts_estimated"] == 36
    assert np.all(f["check_rms_after_m"] < f["check_rms_before_m"])
    assert 0.6 < f["check_z_rms"] < 1.4

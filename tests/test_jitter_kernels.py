"""Adjusted jitter written back (issue 30, item 3/5): an adjusted line-scan camera carrying a jitter spline gives
an ISD resampled at its attitude records and SPICE kernels that reproduce it (oracle: the adjusted camera's
own projection, against the camera rebuilt from the new kernels through the driver)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from lunarmap.camera.factory import camera_from_isd
from lunarmap.orientation.drivers import image_support
from lunarmap.orientation.kernels import write_orientation_kernels
from lunarmap.orientation.update import updated_image_support


def test_jitter_spline_reaches_the_isd_and_the_kernels(sim_mission, tmp_path):
    label = sim_mission.parent / "sim_nac_equator.lbl"
    isd = image_support(label, sim_mission)
    cam = camera_from_isd(isd)
    # knots every 40 lines: records every 5 lines, finer than the ISD's epochs (every 10 lines here)
    corr = cam.corrections(1, jitter_lines=40.0)
    # a NAC-like jitter: 3 urad sinusoids of a 300-line period (0.3 px) in the knot coefficients, with phases per axis
    knots = corr.knot_lines()
    c = 3e-6 * np.sin(2 * np.pi * knots[:, None] / 300.0 + np.array([0.3, 1.9, 4.0])[None, :])
    p = np.zeros(corr.n_params)
    p[corr.n_poly:] = (corr.jitter_projector.T @ c).ravel()
    adjusted = corr.apply(p)
    new = updated_image_support(isd, adjusted.eo)
    assert new.times.size > isd.times.size and new.pointing.times.size == new.times.size
    # the new ISD's attitude is the adjusted camera's at every epoch, the jitter included
    eo_new = new.exterior_orientation(epoch=adjusted.eo.epoch)
    rel = np.swapaxes(eo_new.rotation_at(eo_new.times), 1, 2) @ adjusted.eo.rotation_at(eo_new.times)
    assert np.max(Rotation.from_matrix(rel).magnitude()) < 1e-11
    # without resampling the ISD's own epochs would not hold it: the jitter is between them
    coarse = updated_image_support(isd, adjusted.eo, resample=False)
    assert coarse.times.size == isd.times.size
    # written to kernels and read back through the driver: the same camera as the adjusted one
    mk = write_orientation_kernels([new], tmp_path, sim_mission)
    back = camera_from_isd(image_support(label, mk))
    lines = np.linspace(10.5, cam.n_lines - 10.5, 25)
    samples = np.linspace(0.5, cam.n_samples - 0.5, 7)
    ll, ss = np.meshgrid(lines, samples, indexing="ij")
    ground = adjusted.image_to_ground(ll.ravel(), ss.ravel(), height=0.0)
    lb, sb = back.ground_to_image(ground, within_image=False)
    la, sa = adjusted.ground_to_image(ground, within_image=False)
    d = np.hypot(lb - la, sb - sa)
    print("kernels vs adjusted camera: max", np.max(d), "median", np.median(d), "px")
    assert np.max(d) < 1e-3
    # and the jitter is really there: the original camera sees these points elsewhere by ~0.1 px or more
    lo, so = cam.ground_to_image(ground, within_image=False)
    assert np.max(np.hypot(lo - la, so - sa)) > 0.05

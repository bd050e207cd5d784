"""Adjustment problems of the DLR paper's simulation (lunarmap.simulate.dlr) and scoring of quality control
against the injected truth; shared by tests/test_adjust_qc.py and bench/bench_qc.py."""

from __future__ import annotations

import numpy as np

from lunarmap.adjust import BundleProblem, ImageObservations, NavigationObservations, PointPriors, SensorImageModel

#: a navigation position error and an attitude error of the same image that move the images alike
#: (roll <-> cross-track position, pitch <-> along-track position): [w_x, w_y, w_z, c_x, c_y, c_z]
PARTNER = {0: 5, 5: 0, 1: 4, 4: 1, 2: 3, 3: 2}


def dlr_problem(sim, sigma_factor=1.0) -> BundleProblem:
    """The simulation as a problem: navigation cameras, their corrections observed (zero + blunders) with the
    simulated sigmas, control points, image sigmas; ``sigma_factor`` scales the a-priori sigmas of
    ``[image, position, attitude, control]`` (a scalar scales all)."""
    sb = sim.block
    m = sb.measurements
    f = np.broadcast_to(np.asarray(sigma_factor, float), (4,))
    model = SensorImageModel(sb.nav_cameras)
    p0 = model.initial_params()
    X0 = model.initial_points(p0, m.cam_idx, m.pt_idx, m.xy, sb.true_points.shape[0])
    X0[sb.control] = sb.control_xyz
    nav_sig = sim.nav_sigma.copy()
    nav_sig[:, :3] *= f[2]
    nav_sig[:, 3:] *= f[1]
    nav = NavigationObservations(sim.nav_observed, nav_sig, sb.orbit, sim.along_km, name="navigation")
    pri = PointPriors(sb.control, sb.control_xyz, np.full((sb.control.size, 3), sim.control_sigma * f[3]))
    return BundleProblem(model, p0, X0, ImageObservations(m.cam_idx, m.pt_idx, m.xy, sim.image_sigma * f[0]), pri,
                         [nav])


def score(sim, qc) -> dict:
    """What quality control found of the injected gross errors, and what it took that was good.

    Image errors count as found when their observation is out of the final adjustment; a navigation
    error when the navigation of its image is down-weighted in its parameter (``exact``) or in the one
    the images cannot tell from it (:data:`PARTNER`); the control error when its control point is
    down-weighted. ``false_images``: good image observations removed by a test; ``lost_with_points``:
    good ones that left with their point (a point left with one ray cannot be adjusted: the good ray of
    a 2-ray point with a gross error goes too); ``withdrawn_good``: good ones withdrawn with a point whose
    error the data cannot attribute to one ray; ``false_navigation`` / ``false_control``: other
    down-weighted ones.
    """
    bl = sim.blunders
    out_obs = set(qc.removed_image_observations.tolist())
    found = np.array([i in out_obs for i in bl.image_obs])
    # removed by a test (and not given back) vs gone with a point left with fewer than 2 rays
    # withdrawn with their point (the data could not say which of its rays is wrong): none judged wrong
    withdrawn = {d.index for d in qc.report.decisions if d.kind == "image" and d.action == "withdrawn"}
    tested = {d.index for d in qc.report.decisions if d.kind == "image" and d.action == "removed"}
    tested = (tested & out_obs) - withdrawn
    led = qc.ledger
    nav_rows = led.terms[0].row_table()
    down = led.weights.term_sigma[0] > 1.0
    nav_down = {(int(nav_rows["image"][r]), int(nav_rows["param"][r])) for r in np.flatnonzero(down)
                if nav_rows["kind"][r] == 0}
    ctl_down = set(np.flatnonzero(led.weights.control_sigma > 1.0).tolist())

    def nav_found(b):
        if b is None:
            return None, set()
        j, k = b
        hits = {(j, k), (j, PARTNER[k])} & nav_down
        return ((j, k) in nav_down, bool(hits)), hits

    pos, pos_hits = nav_found(bl.position)
    att, att_hits = nav_found(bl.attitude)
    return {"large": int(found[bl.image_group == 1].sum()), "small": int(found[bl.image_group == 2].sum()),
            "position_exact": pos[0] if pos else None, "position": pos[1] if pos else None,
            "attitude_exact": att[0] if att else None, "attitude": att[1] if att else None,
            "control": (bl.control[0] in ctl_down) if bl.control else None,
            "false_images": len(tested - set(bl.image_obs.tolist())),
            "lost_with_points": len(out_obs - tested - withdrawn - set(bl.image_obs.tolist())),
            "withdrawn_good": len(withdrawn - set(bl.image_obs.tolist())),
            "false_navigation": len(nav_down - pos_hits - att_hits),
            "false_control": len(ctl_down - ({bl.control[0]} if bl.control else set())),
            "found": int(found.sum()) + sum(bool(x) for x in (pos and pos[1], att and att[1],
                                                               bl.control and bl.control[0] in ctl_down)),
            "total": bl.count}

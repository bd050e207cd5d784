"""Random ISIS control networks with every field set somewhere (tests and bench/bench_isis_network.py)."""

from __future__ import annotations

import numpy as np

from lunarmap.io.isis_network import network_dataset


def random_network(n_pt: int, per_point: int = 10, n_img: int = 50, seed: int = 0, rich: bool = True):
    """A control-network Dataset of ``n_pt`` points with about ``per_point`` measures each."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(2, 2 * per_point - 1, n_pt)
    n_m = int(counts.sum())
    m_point = np.repeat(np.arange(n_pt), counts)
    isis_type = rng.choice([2, 3, 4], n_pt, p=[0.8, 0.15, 0.05]).astype(np.int8)
    xyz = rng.normal(0, 1, (n_pt, 3))
    xyz *= 1737400.0 / np.linalg.norm(xyz, axis=1, keepdims=True)
    xyz[(isis_type == 2) & (rng.random(n_pt) < 0.5)] = np.nan
    a = rng.normal(0, 1, (n_pt, 3, 3))
    cov = a @ np.swapaxes(a, 1, 2)
    cov[isis_type == 2] = np.nan
    cov[isis_type == 4] = 0.0
    ptype = np.where(isis_type == 2, 0, 1).astype(np.int8)
    points = dict(point_id=np.array([f"pt_{i:06d}" for i in range(n_pt)]), point_type=ptype, isis_point_type=isis_type,
                  xyz=xyz, xyz_cov=cov)
    measures = dict(measure_point=m_point, measure_image=rng.integers(0, n_img, n_m),
                    line=rng.uniform(0, 52224, n_m), sample=rng.uniform(0, 5064, n_m),
                    sigma_line=np.where(rng.random(n_m) < 0.5, np.nan, 0.3),
                    sigma_sample=np.where(rng.random(n_m) < 0.5, np.nan, 0.3),
                    measure_type=rng.integers(0, 4, n_m).astype(np.int8))
    plogs = mlogs = None
    if rich:
        adj = xyz + rng.normal(0, 1, (n_pt, 3))
        adj[rng.random(n_pt) < 0.3] = np.nan
        maybe = lambda p, text: np.where(rng.random(n_pt) < p, text, "")  # noqa: E731
        points.update(
            adjusted_xyz=adj, adjusted_cov=np.where(np.isnan(adj)[:, :, None], np.nan, cov + np.eye(3)),
            ignore=rng.random(n_pt) < 0.05, edit_lock=rng.random(n_pt) < 0.05, jigsaw_rejected=rng.random(n_pt) < 0.02,
            reference_index=np.where(rng.random(n_pt) < 0.5, 0, -1), chooser_name=maybe(0.5, "pointreg"),
            datetime=maybe(0.5, "2026-11-30T12:00:00"), apriori_surface_source=rng.integers(-1, 8, n_pt),
            apriori_surface_source_file=maybe(0.1, "base.cub"), apriori_radius_source=rng.integers(-1, 6, n_pt),
            apriori_radius_source_file=maybe(0.1, "dem.cub"), latitude_constrained=rng.random(n_pt) < 0.1,
            longitude_constrained=rng.random(n_pt) < 0.1, radius_constrained=rng.random(n_pt) < 0.1)
        ptype[(isis_type == 2) & points["ignore"] & (points["apriori_surface_source"] == 3)] = 2  # check points
        measures.update(
            line_residual=rng.normal(0, 0.3, n_m),
            sample_residual=np.where(rng.random(n_m) < 0.3, np.nan, rng.normal(0, 0.3, n_m)),
            apriori_line=rng.uniform(0, 100, n_m), apriori_sample=np.where(rng.random(n_m) < 0.5, np.nan, 3.25),
            diameter=np.where(rng.random(n_m) < 0.9, np.nan, 12.5), measure_ignore=rng.random(n_m) < 0.05,
            measure_edit_lock=rng.random(n_m) < 0.05, measure_jigsaw_rejected=rng.random(n_m) < 0.05,
            measure_chooser_name=np.where(rng.random(n_m) < 0.5, "autocnet", ""),
            measure_datetime=np.where(rng.random(n_m) < 0.2, "2026-12-01T00:00:00", ""))
        k = max(n_m // 10, 1)
        mlogs = dict(measure=np.sort(rng.choice(n_m, k, replace=False)), type=rng.integers(2, 8, k),
                     value=rng.random(k), bool_type=np.full(k, -1), bool_value=np.full(k, -1))
        kp = max(n_pt // 20, 1)
        plogs = dict(point=np.sort(rng.choice(n_pt, kp, replace=False)), type=rng.integers(1, 5, kp),
                     value=rng.random(kp), bool_type=rng.integers(-1, 3, kp), bool_value=rng.integers(-1, 2, kp))
    images = np.array([f"LRO/NACL/{270649237 + 10 * i}:07208" for i in range(n_img)])
    return network_dataset(points, measures, images, point_logs=plogs, measure_logs=mlogs,
                           attrs=dict(body="Moon", isis_network_id="test", isis_created="2026-12-01",
                                      isis_description="random", isis_user_name="lunarmap", isis_last_modified="",
                                      isis_target_radii=np.array([1737400.0] * 3)))

"""The embedded example of ``lunarmap run --example``: a synthetic mission with rendered images and a config.

:func:`write_example` writes, into one folder, the 12-image synthetic block of
:func:`lunarmap.synthetic.write_block_mission` (TRUTH and NAVIGATION kernels, labels), its images
rendered from a synthetic DTM through the truth cameras (:func:`lunarmap.simulate.render_block`),
control points (coordinates from a reference with ``control_sigma`` metres) and check points measured in
the images (``sigma_px``) as a control network, and ``run.toml``: the run configuration over the
NAVIGATION kernels, so that a run starts where a user with real data starts.

With ``sites=n`` the block has ``12 n`` images over ``n`` sites along each orbit's ground track
(one kernel set); every site gets its own control and check points (its sub-block's datum: images of
different sites do not overlap), the navigation groups stay per (orbit, camera) across the sites (the
navigation errors are per orbit), and the configuration has no ``[dtm]`` (one DTM file cannot hold
sites hundreds of kilometres apart): tie points are predicted at height 0.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["write_example", "EXAMPLE_CONFIG"]

#: The configuration written next to the example data (``{...}`` filled in).
EXAMPLE_CONFIG = """# lunarmap run configuration of the embedded example (lunarmap run --example)
[run]
output = "{output}"
name = "{name}"

[kernels]
metakernel = "mission/navigation.tm"

{images}
{dtm}
[points]
path = "points.nc"

[rpc]
enabled = true
height_range = [-300.0, 300.0]

[tiepoints]
cell = {cell}
search = 128.0
min_overlap = 0.05

[adjust]
degree = 1
estimate_tie_variance = true
ftol = 1e-10

[adjust.navigation]
position_sigma = 0.5
attitude_sigma = 1e-6
position_rate_sigma = 1.0
attitude_rate_sigma = 1e-6
offset = "observed"
drift = "observed"
offset_sigma = [50e-6, 50e-6, 50e-6, 50.0, 50.0, 50.0]
drift_sigma = [1e-6, 1e-6, 1e-6, 1.0, 1.0, 1.0]

[adjust.qc]
steps = ["baarda"]
robust_function = "danish"
robust_scale = "mad"
baarda_limit = 4.0
baarda_per_round = "point"
baarda_sigma0 = "robust"

[report]
html = true
"""


def _points_network(points, kind: str, prefix: str, sigma_m: float = 0.0, rng=None):
    from ..adjust import ControlNetwork

    ids, inverse = np.unique(points["point_id"].values, return_inverse=True)
    xyz = points["xyz"].values[ids]
    cov = None
    if kind == "control":
        xyz = xyz + rng.normal(0.0, sigma_m, xyz.shape)       # a reference DTM / altimetry with sigma_m
        cov = np.repeat((sigma_m ** 2 * np.eye(3))[None], ids.size, axis=0)
    return ControlNetwork([f"{prefix}{i}" for i in ids], [kind] * ids.size, xyz, inverse,
                          points["image_id"].values, np.column_stack([points["line"].values, points["sample"].values]),
                          np.column_stack([points["sigma_line"].values, points["sigma_sample"].values]),
                          np.asarray(points["image"].values).astype(str), xyz_cov=cov)


_DTM_SECTION = """[dtm]
path = "mission/dtm.nc"
"""
_NO_DTM = """# no [dtm]: the sites' DTMs (mission/dtm_s<k>.nc) are hundreds of kilometres apart; tie points
# are predicted at height 0
"""


def write_example(folder: str | os.PathLike[str], seed: int = 0, quick: bool = False, n_control: int = 6,
                  n_check: int | None = None, control_sigma: float = 0.5, sigma_px: float = 0.3,
                  names: list[str] | None = None, output: str = "run", sites: int = 1,
                  site_spacing_deg: float | None = None, site_half_width_s: float | None = None) -> Path:
    """Write the example's data and configuration; returns the path of ``run.toml``.

    Parameters
    ----------
    folder : path-like
        Created if needed.
    seed : int
        Seed of the mission, scene and measurements.
    quick : bool
        Fewer interest points and check points (tests).
    n_control, n_check : int
        Control and check points per site (check default 20, or 12 with ``quick``).
    control_sigma : float
        Sigma of the control coordinates, metres.
    sigma_px : float
        Measurement noise of control and check points, pixels.
    names : list of str, optional
        A subset of the block's images (default all ``12 * sites``).
    output : str
        Run folder, relative to ``folder``.
    sites : int
        Sites of the block (:func:`lunarmap.synthetic.write_block_mission`): ``12 * sites`` images.
    site_spacing_deg, site_half_width_s : float, optional
        Latitude step between sites and pass half-width (defaults of
        :func:`~lunarmap.synthetic.write_block_mission`; e.g. -2.5 and 12 for 40 sites).
    """
    from ..adjust import merge_networks, write_network
    from ..simulate import block_cameras, block_check_points, render_block
    from ..synthetic import write_block_mission

    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    extra = {} if site_spacing_deg is None else {"site_spacing_deg": float(site_spacing_deg)}
    bm = write_block_mission(root / "mission", seed=seed, sites=sites, site_half_width_s=site_half_width_s, **extra)
    use = list(bm.image_names) if names is None else list(names)
    render_block(bm, names=use, supersample=2)
    truth = block_cameras(bm, "truth", use)
    rng = np.random.default_rng(seed + 1)
    n_sites = bm.model.n_sites
    nets = []
    for site in range(1, n_sites + 1):
        here = [n for n in use if bm.model.image(n).site == site]
        if not here:
            continue
        # one site: the networks of the one-site example (seeds, point ids) exactly
        extra = 0 if n_sites == 1 else 1000 * site
        prefix = "" if n_sites == 1 else f"s{site}_"
        control = block_check_points(bm, n_control, sigma_px=sigma_px, seed=seed + 11 + extra, cameras=truth,
                                     names=here)
        check = block_check_points(bm, n_check if n_check is not None else (12 if quick else 20),
                                   sigma_px=sigma_px, seed=seed + 12 + extra, cameras=truth, names=here)
        nets += [_points_network(control, "control", f"{prefix}C", control_sigma, rng),
                 _points_network(check, "check", f"{prefix}K")]
    # control points first, then check points (the one-site example's order)
    net = merge_networks(*nets[0::2], *nets[1::2])
    write_network(net, root / "points.nc")
    man = bm.manifest
    images = "\n".join(
        f'[[images]]\nname = "{n}"\nlabel = "mission/{n}.lbl"\npixels = "mission/{n}.nc"\n'
        f'group = "{man["images"][n]["orbit"]}-{man["images"][n]["kind"]}"\n' for n in use)
    if n_sites == 1:
        name = f"synthetic block: 12 images, 3 orbits, NAC-like / TC-like / frame cameras (seed {seed})"
    else:
        name = (f"synthetic block: {len(use)} images over {n_sites} sites, 3 orbits, NAC-like / TC-like / frame "
                f"cameras (seed {seed})")
    text = EXAMPLE_CONFIG.format(output=output, name=name, images=images, cell=64 if quick else 48,
                                 dtm=_DTM_SECTION if n_sites == 1 else _NO_DTM)
    path = root / "run.toml"
    path.write_text(text)
    return path

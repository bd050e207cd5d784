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

With ``full_size=True`` the mission is the full-size layout (``write_block_mission(layout="full_size")``:
eight LRO-NAC-like images of 52,224 x 5,064 pixels, NAC-L and NAC-R in two along-track strips on two
orbits, staggered), rendered by the compiled renderer into UnsignedByte ISIS cubes (``mission/<image>.cub``,
:func:`lunarmap.simulate.render_block_cubes`); control and check points are drawn per pair of
cross-orbit images of one camera and strip (no point is seen by all eight), navigation groups are per
(orbit, camera).

**Written once.** The example is made of parts (the mission, each image, the DTM, the points, the
configuration); beside ``run.toml``, ``example_state.json`` records for each part a digest of what
generated it (seed, parameters, :data:`EXAMPLE_GENERATION`, the lunarmap version, the digests of the
parts it is made from) and the size and modification time of its files. A part whose digest is
unchanged and whose files are there as written is not written again: a second call rewrites
nothing and takes about a second; a deleted or touched file, or another parameter, rewrites that
part and what depends on it. An interrupted write keeps the parts that were finished.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..atomic import atomic_write

__all__ = ["write_example", "EXAMPLE_CONFIG", "EXAMPLE_GENERATION", "EXAMPLE_STATE", "TERRAIN_EXAMPLE"]

_log = logging.getLogger(__name__)

#: Bumped whenever a generator of the example (mission, renderer, scene, points) changes its output,
#: so that examples written before are written again.
EXAMPLE_GENERATION = 1
#: The record of the example's parts, beside ``run.toml``.
EXAMPLE_STATE = "example_state.json"

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
search = {search}
min_overlap = 0.05

[adjust]
degree = {degree}
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

{terrain}[adjust.qc]
steps = ["baarda"]
robust_function = "danish"
robust_scale = "mad"
baarda_limit = 4.0
baarda_per_round = "point"
baarda_sigma0 = "robust"

[report]
html = true
"""


#: The terrain / jitter example (``write_example(terrain=True)``, ``lunarmap run --example --terrain``): the bus
#: jitter of the TRUTH CK (amplitude rad, frequency Hz), the simulated LOLA-like tracks over the DTM and
#: the a-priori values of ``[[adjust.terrain.altimetry]]`` and ``[adjust.jitter]``.
TERRAIN_EXAMPLE: dict[str, Any] = {
    "jitter_waves": [(3e-6, 8.0)],          # LRO NAC-like: 1-3 urad at 1-10 Hz; 8 Hz is 2.7 periods of a NAC image
    "tracks": 10, "shot_sigma_m": 0.5, "track_offset_sigma_m": 10.0, "heading_deg": 15.0,
    "box_fraction": 0.6,                    # the tracks' box: this central share of the DTM (where the images are)
    "interpolation_sigma_m": 1.0,           # the tie points' surface (~50 m apart) against the cratered terrain
    # knots every 32 NAC lines (21 ms, 6 per period of 8 Hz); the smoothness sigma is the second difference of
    # a 3 urad / 8 Hz sinusoid at that spacing (A (2 - 2 cos(2 pi f dt)) ~ 3 urad)
    "knot_lines": 32.0, "jitter_sigma": 3e-6, "jitter_zero_sigma": 1e-5,
}
#: The simulated shot table of the terrain example, and its truth (per-track offsets), beside ``run.toml``.
ALTIMETRY_TABLE = "altimetry.csv"
ALTIMETRY_TRUTH = "altimetry_truth.json"

_TERRAIN_SECTION = """[adjust.terrain]
[[adjust.terrain.altimetry]]
# simulated LOLA-like tracks over the DTM (lunarmap.simulate.altimetry_tracks), a radial offset per track
path = "{table}"
sigma = {shot_sigma_m}
interpolation_sigma = {interpolation_sigma_m}
offset_sigma = {track_offset_sigma_m}
name = "lola"

[adjust.jitter]
# the TRUTH CK carries bus jitter (mission/jitter_truth.json); the NAVIGATION CK is smooth
knot_lines = {knot_lines}
sigma = {jitter_sigma}
zero_sigma = {jitter_zero_sigma}

"""


def _points_network(points, kind: str, prefix: str, sigma_m: float = 0.0, rng=None):
    from ..adjust import ControlNetwork

    ids, inverse = np.unique(points["point_id"].values, return_inverse=True)
    xyz = points["xyz"].values[ids]
    cov = None
    if kind == "control":
        xyz = xyz + rng.normal(0.0, sigma_m, xyz.shape)       # a reference DTM / altimetry with sigma_m
        cov = np.repeat((sigma_m ** 2 * np.eye(3))[None], ids.size, axis=0)
    return ControlNetwork(np.array([f"{prefix}{i}" for i in ids]), np.array([kind] * ids.size), xyz, inverse,
                          points["image_id"].values, np.column_stack([points["line"].values, points["sample"].values]),
                          np.column_stack([points["sigma_line"].values, points["sigma_sample"].values]),
                          np.asarray(points["image"].values).astype(str), xyz_cov=cov)


_DTM_SECTION = """[dtm]
path = "mission/dtm.nc"
"""
_NO_DTM = """# no [dtm]: the sites' DTMs (mission/dtm_s<k>.nc) are hundreds of kilometres apart; tie points
# are predicted at height 0
"""


class _Parts:
    """The example's parts on disk: which are there as their digest says (see the module docstring)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.path = root / EXAMPLE_STATE
        try:
            state = json.loads(self.path.read_text())
            self.parts: dict[str, Any] = dict(state["parts"]) if state.get("format") == 1 else {}
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            self.parts = {}
        self.written: list[str] = []
        self.reused: list[str] = []

    @staticmethod
    def digest(doc: Any) -> str:
        import lunarmap

        text = json.dumps({"doc": doc, "generation": EXAMPLE_GENERATION, "lunarmap": lunarmap.__version__},
                          sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:32]

    def _stamp(self, rel: str) -> list[int]:
        st = (self.root / rel).stat()
        return [st.st_size, st.st_mtime_ns]

    def fresh(self, name: str, digest: str) -> bool:
        """Whether part ``name`` is on disk as written with ``digest`` (every file there, untouched)."""
        rec = self.parts.get(name)
        if not isinstance(rec, dict) or rec.get("digest") != digest:
            return False
        try:
            return all(self._stamp(rel) == list(v) for rel, v in rec["files"].items())
        except (OSError, TypeError, ValueError):
            return False

    def reuse(self, name: str) -> None:
        self.reused.append(name)

    def stale(self, digests: dict[str, str]) -> list[str]:
        """The parts (name -> digest) not fresh; the others are counted as reused."""
        out = [name for name, d in digests.items() if not self.fresh(name, d)]
        for name in digests:
            if name not in out:
                self.reuse(name)
        return out

    def done(self, name: str, digest: str, files: Iterable[str | Path]) -> None:
        """Record part ``name`` as written (its files relative to the example's folder)."""
        rels = [str(Path(f).resolve().relative_to(self.root.resolve())) for f in files]
        self.parts[name] = {"digest": digest, "files": {rel: self._stamp(rel) for rel in rels}}
        self.written.append(name)
        doc = json.dumps({"format": 1, "parts": self.parts}, indent=1, sort_keys=True) + "\n"
        atomic_write(self.path, lambda tmp: tmp.write_text(doc))

    def forget(self, name: str) -> None:
        self.parts.pop(name, None)


def write_example(folder: str | os.PathLike[str], seed: int = 0, quick: bool = False, n_control: int | None = None,
                  n_check: int | None = None, control_sigma: float = 0.5, sigma_px: float = 0.3,
                  names: list[str] | None = None, output: str = "run", sites: int = 1,
                  site_spacing_deg: float | None = None, site_half_width_s: float | None = None,
                  full_size: bool = False, threads: int = 2, terrain: bool = False) -> Path:
    """Write the example's data and configuration (only the parts not already there); returns ``run.toml``.

    Parameters
    ----------
    folder : path-like
        Created if needed.
    seed : int
        Seed of the mission, scene and measurements.
    quick : bool
        Fewer interest points and check points (tests).
    n_control, n_check : int
        Control and check points per site (defaults 6 and 20, or 12 check points with ``quick``); with
        ``full_size``, in all (defaults 8 and 40), shared out over the four cross-orbit image pairs.
    control_sigma : float
        Sigma of the control coordinates, metres.
    sigma_px : float
        Measurement noise of control and check points, pixels.
    names : list of str, optional
        A subset of the block's images (default all ``12 * sites``, or the 8 full-size ones).
    output : str
        Run folder, relative to ``folder``.
    sites : int
        Sites of the block (:func:`lunarmap.synthetic.write_block_mission`): ``12 * sites`` images.
    site_spacing_deg, site_half_width_s : float, optional
        Latitude step between sites and pass half-width (defaults of
        :func:`~lunarmap.synthetic.write_block_mission`; e.g. -2.5 and 12 for 40 sites).
    full_size : bool
        The full-size mission (see the module docstring): 8 images of 52,224 x 5,064 pixels as ISIS
        cubes, 2.2 GB; 104 s of CPU per image (about 7 minutes on two free cores).
    threads : int
        Threads of the full-size renderer.
    terrain : bool
        The terrain / jitter example (:data:`TERRAIN_EXAMPLE`): the TRUTH CK carries bus attitude jitter
        (:func:`lunarmap.simulate.block_jitter.add_block_jitter`, its truth in ``mission/jitter_truth.json``),
        LOLA-like altimetry tracks over the DTM are written as ``altimetry.csv`` (their true per-track
        offsets in ``altimetry_truth.json``), there are no control points (default ``n_control=0``: the
        datum is the navigation's and the altimetry's), and ``run.toml`` has ``[[adjust.terrain.altimetry]]``
        and ``[adjust.jitter]``. One site, not with ``full_size``.
    """
    from ..synthetic import write_block_mission

    t0 = time.perf_counter()
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    parts = _Parts(root)
    if full_size and sites != 1:
        from ..errors import InvalidInputError

        raise InvalidInputError(f"the full-size example has one site, got sites={sites!r}")
    if terrain and (full_size or sites != 1):
        from ..errors import InvalidInputError

        raise InvalidInputError("the terrain / jitter example is the one-site block (not full_size, sites=1)")
    layout = "full_size" if full_size else "block"
    extra: dict[str, Any] = {} if site_spacing_deg is None else {"site_spacing_deg": float(site_spacing_deg)}
    # the digest holds only the parameters given, so that the examples written before stay fresh
    mission_doc = {"seed": int(seed), "sites": int(sites), "layout": layout, **extra,
                   **({} if site_half_width_s is None else {"site_half_width_s": float(site_half_width_s)}),
                   **({"jitter": TERRAIN_EXAMPLE["jitter_waves"]} if terrain else {})}
    mission_digest = parts.digest(mission_doc)
    mdir = root / "mission"
    if parts.fresh("mission", mission_digest):
        from ..synthetic import open_block_mission

        bm = open_block_mission(mdir)
        parts.reuse("mission")
    else:
        _log.info("example: writing the mission's SPICE kernels (truth and navigation) and labels in %s", mdir)
        bm = write_block_mission(mdir, seed=seed, sites=sites, site_half_width_s=site_half_width_s, layout=layout,
                                 **extra)
        files = [mdir / f for f in _mission_files(bm)]
        from ..simulate.block_jitter import JITTER_TRUTH, add_block_jitter

        # the truth of a jitter the new TRUTH CK does not have would mislead a comparison
        (mdir / JITTER_TRUTH).unlink(missing_ok=True)
        if terrain:

            _log.info("example: bus attitude jitter (%s) in the TRUTH CK", ", ".join(
                f"{a * 1e6:g} urad at {f:g} Hz" for a, f in TERRAIN_EXAMPLE["jitter_waves"]))
            add_block_jitter(bm, TERRAIN_EXAMPLE["jitter_waves"], seed=seed)
            files.append(mdir / JITTER_TRUTH)
        parts.done("mission", mission_digest, files)
    use = list(bm.image_names) if names is None else list(names)
    if full_size:
        points_doc = _write_full_size_images(bm, use, parts, mission_digest, threads)
        n_control = 8 if n_control is None else n_control
        n_check = 40 if n_check is None else n_check
    else:
        points_doc = _write_block_images(bm, use, parts, mission_digest)
        n_control = (0 if terrain else 6) if n_control is None else n_control
        n_check = n_check if n_check is not None else (12 if quick else 20)
    points_digest = parts.digest({"mission": mission_digest, "images": points_doc, "names": use,
                                  "n_control": n_control, "n_check": n_check, "control_sigma": control_sigma,
                                  "sigma_px": sigma_px, "seed": seed})
    if parts.fresh("points", points_digest):
        parts.reuse("points")
    else:
        _log.info("example: measuring %d control and %d check points in the images", n_control, n_check)
        net = (_full_size_points(bm, use, n_control, n_check, control_sigma, sigma_px, seed) if full_size
               else _block_points(bm, use, n_control, n_check, control_sigma, sigma_px, seed))
        from ..adjust import write_network

        write_network(net, root / "points.nc")
        parts.done("points", points_digest, [root / "points.nc"])
    if terrain:
        _write_altimetry(bm, root, parts, points_doc["dtm"], seed)
    text = _config_text(bm, use, seed, quick, output, full_size, terrain)
    path = root / "run.toml"
    config_digest = parts.digest({"text": text})
    if parts.fresh("config", config_digest):
        parts.reuse("config")
    else:
        path.write_text(text)
        parts.done("config", config_digest, [path])
    _log.info("example %s: %d part(s) written (%s), %d reused, %.1f s", root, len(parts.written),
              ", ".join(parts.written) or "none", len(parts.reused), time.perf_counter() - t0)
    return path


def _write_altimetry(bm: Any, root: Path, parts: _Parts, dtm_digest: str, seed: int) -> None:
    """The terrain example's LOLA-like shot table over the true DTM, and its truth (per-track offsets)."""
    p = TERRAIN_EXAMPLE
    digest = parts.digest({"dtm": dtm_digest, "altimetry": {k: p[k] for k in (
        "tracks", "shot_sigma_m", "track_offset_sigma_m", "heading_deg", "box_fraction")}, "seed": seed})
    if parts.fresh("altimetry", digest):
        parts.reuse("altimetry")
        return
    import xarray as xr
    from scipy.interpolate import RegularGridInterpolator

    from ..io.altimetry import write_altimetry
    from ..simulate import altimetry_tracks
    from ..simulate.mission import block_dtm_file

    with xr.open_dataarray(bm.folder / block_dtm_file(bm)) as d:
        dtm = d.load()
    lat, lon = np.asarray(dtm["lat"].values, float), np.asarray(dtm["lon"].values, float)
    interp = RegularGridInterpolator((lat, lon), np.asarray(dtm.values, float))

    def height(lo: Any, la: Any) -> Any:        # metres above the DTM's sphere (the Moon's radius)
        return interp(np.column_stack([np.ravel(la), np.ravel(lo)])).reshape(np.shape(lo))

    f = 0.5 * p["box_fraction"]
    c_lon, c_lat, h_lon, h_lat = 0.5 * (lon[0] + lon[-1]), 0.5 * (lat[0] + lat[-1]), lon[-1] - lon[0], lat[-1] - lat[0]
    sim = altimetry_tracks(height, (c_lon - f * h_lon, c_lon + f * h_lon), (c_lat - f * h_lat, c_lat + f * h_lat),
                           int(p["tracks"]), sigma=float(p["shot_sigma_m"]),
                           offset_sigma=float(p["track_offset_sigma_m"]), heading_deg=float(p["heading_deg"]),
                           seed=seed + 30)
    _log.info("example: %d LOLA-like altimetry tracks (%d shots, %.2g m radial noise, per-track offsets of %.3g m "
              "RMS) over the DTM", sim.track_names.size, sim.shots.lon.size,
              sim.sigma, float(np.sqrt(np.mean(sim.offsets ** 2))))
    write_altimetry(root / ALTIMETRY_TABLE, sim.shots)
    truth = {"tracks": {str(n): {"offset_m": float(o), "drift_m_per_s": float(dr)}
                        for n, o, dr in zip(sim.track_names, sim.offsets, sim.drifts)},
             "shot_sigma_m": sim.sigma, "offset_sigma_m": float(p["track_offset_sigma_m"])}
    doc = json.dumps(truth, indent=1)
    atomic_write(root / ALTIMETRY_TRUTH, lambda tmp: tmp.write_text(doc))
    parts.done("altimetry", digest, [root / ALTIMETRY_TABLE, root / ALTIMETRY_TRUTH])


def _mission_files(bm: Any) -> list[str]:
    man = bm.manifest
    return [*man["kernels"]["shared"], *man["kernels"]["truth"], *man["kernels"]["navigation"],
            *(im["label"] for im in man["images"].values()), "block_mission.json", *man["metakernels"].values()]


def _write_block_images(bm: Any, use: list[str], parts: _Parts, mission_digest: str) -> dict[str, str]:
    """The 1 m-pixel block's netCDF images and DTM(s) (render_block, 2 x 2 rays); returns the parts' digests."""
    from ..simulate import render_block
    from ..simulate.mission import block_dtm_file

    digests = {n: parts.digest({"mission": mission_digest, "image": n, "render": "render_block", "supersample": 2})
               for n in use}
    sites = sorted({bm.model.image(n).site for n in use})
    dtm_files = {block_dtm_file(bm, k) for k in sites}
    dtm_digest = parts.digest({"mission": mission_digest, "dtm": sorted(dtm_files)})
    stale = parts.stale({f"image:{n}": d for n, d in digests.items()})
    stale = [n for n in use if f"image:{n}" in stale]
    dtm_stale = not parts.fresh("dtm", dtm_digest)
    if stale or dtm_stale:
        # the DTMs come with any rendering; a stale DTM alone re-renders the first image of its site
        _log.info("example: rendering %d image(s) and the DTM through the truth cameras",
                  len(stale) or 1)
        render_block(bm, names=stale or [next(n for n in use if bm.model.image(n).site == sites[0])], supersample=2)
        for n in stale:
            parts.done(f"image:{n}", digests[n], [bm.folder / f"{n}.nc"])
        parts.done("dtm", dtm_digest, [bm.folder / f for f in sorted(dtm_files)])
    else:
        parts.reuse("dtm")
    return {**digests, "dtm": dtm_digest}


def _write_full_size_images(bm: Any, use: list[str], parts: _Parts, mission_digest: str,
                            threads: int) -> dict[str, str]:
    """The full-size cubes and DTM (render_block_cubes, 1 ray per pixel); returns the parts' digests."""
    from ..simulate.mission import block_dtm_file, block_scene, render_block_cubes

    render = {"render": "render_block_cubes", "supersample": 1, "noise_sigma": 2.0, "gain": 160.0,
              "pixel_type": "UnsignedByte"}
    digests = {n: parts.digest({"mission": mission_digest, "image": n, **render}) for n in use}
    dtm_digest = parts.digest({"mission": mission_digest, "dtm": block_dtm_file(bm)})
    stale = parts.stale({f"image:{n}": d for n, d in digests.items()})
    stale = [n for n in use if f"image:{n}" in stale]
    dtm_stale = not parts.fresh("dtm", dtm_digest)
    if not (stale or dtm_stale):
        parts.reuse("dtm")
        return {**digests, "dtm": dtm_digest}
    t = time.perf_counter()
    scene = block_scene(bm)
    _log.info("full-size scene (DTM %d x %d at 4 m, tiled albedo) in %.1f s", *scene[0].shape, time.perf_counter() - t)
    if dtm_stale:
        path = atomic_write(bm.folder / block_dtm_file(bm), lambda tmp: scene[0].to_netcdf(tmp, engine="netcdf4"))
        parts.done("dtm", dtm_digest, [path])
    else:
        parts.reuse("dtm")
    for n in stale:
        # one image at a time, each recorded as soon as it is there: an interrupted write keeps them
        parts.forget(f"image:{n}")
        render_block_cubes(bm, names=[n], scene=scene, write_dtm=False, threads=threads, log=_log.info)
        parts.done(f"image:{n}", digests[n], [bm.folder / f"{n}.cub"])
    return {**digests, "dtm": dtm_digest}


def _block_points(bm: Any, use: list[str], n_control: int, n_check: int, control_sigma: float, sigma_px: float,
                  seed: int) -> Any:
    """Control and check points of every site of the 1 m-pixel block (the one-site example's exactly)."""
    from ..adjust import merge_networks
    from ..simulate import block_cameras, block_check_points

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
        _log.info("example: %d control points of site %d (visible in its %d images, on the true DTM)", n_control,
                  site, len(here))
        control = (block_check_points(bm, n_control, sigma_px=sigma_px, seed=seed + 11 + extra, cameras=truth,
                                      names=here) if n_control else None)
        _log.info("example: %d check points of site %d", n_check, site)
        check = block_check_points(bm, n_check, sigma_px=sigma_px, seed=seed + 12 + extra, cameras=truth, names=here)
        nets += [_points_network(control, "control", f"{prefix}C", control_sigma, rng) if n_control else None,
                 _points_network(check, "check", f"{prefix}K")]
    # control points first, then check points (the one-site example's order)
    return merge_networks(*(n for n in nets[0::2] if n is not None), *nets[1::2])


def _full_size_points(bm: Any, use: list[str], n_control: int, n_check: int, control_sigma: float,
                      sigma_px: float, seed: int) -> Any:
    """Control and check points of the full-size block, per cross-orbit pair of one camera and strip."""
    import xarray as xr

    from ..adjust import merge_networks
    from ..camera.intersect import DtmSampler
    from ..simulate import block_cameras, block_check_points
    from ..simulate.mission import block_dtm_file

    truth = block_cameras(bm, "truth", use)
    with xr.open_dataarray(bm.folder / block_dtm_file(bm)) as d:
        dtm = d.load()
    DtmSampler(dtm)  # validates once
    groups: dict[str, list[str]] = {}
    for n in use:
        groups.setdefault(bm.model.image(n).kind, []).append(n)
    groups = {k: v for k, v in groups.items() if len({bm.model.image(n).orbit for n in v}) > 1}
    if not groups:
        from ..errors import InvalidInputError

        raise InvalidInputError(f"the full-size example's points need images of one camera and strip on two orbits; "
                                f"{use} has none")
    rng = np.random.default_rng(seed + 1)

    def share(total):  # untyped as the lambda it replaces (typed, mypy misreads the loop below)
        return [total // len(groups) + (1 if i < total % len(groups) else 0) for i in range(len(groups))]

    nets_c: list[Any] = []          # ControlNetwork
    nets_k: list[Any] = []
    for i, ((kind, here), nc, nk) in enumerate(zip(groups.items(), share(n_control), share(n_check))):
        for n, what, out, s in ((nc, "control", nets_c, 11), (nk, "check", nets_k, 12)):
            if n:
                pts = block_check_points(bm, n, sigma_px=sigma_px, seed=seed + s + 1000 * i, cameras=truth,
                                         names=here, dtm=dtm, margin_px=40.0)
                out.append(_points_network(pts, what, f"{kind}_{'C' if what == 'control' else 'K'}",
                                           control_sigma if what == "control" else 0.0,
                                           rng if what == "control" else None))
    return merge_networks(*nets_c, *nets_k)


def _config_text(bm: Any, use: list[str], seed: int, quick: bool, output: str, full_size: bool,
                 terrain: bool = False) -> str:
    man = bm.manifest
    n_sites = bm.model.n_sites
    ext = "cub" if full_size else "nc"

    def group(n: str) -> str:
        kind = str(man["images"][n]["kind"])
        return f'{man["images"][n]["orbit"]}-{kind.split("_")[0] if full_size else kind}'

    images = "\n".join(
        f'[[images]]\nname = "{n}"\nlabel = "mission/{n}.lbl"\npixels = "mission/{n}.{ext}"\n'
        f'group = "{group(n)}"\n' for n in use)
    if full_size:
        name = (f"synthetic full-size block: {len(use)} LRO-NAC-like images of 52,224 x 5,064 pixels, NAC-L / NAC-R, "
                f"{bm.model.orbits} orbits (seed {seed})")
    elif n_sites == 1:
        name = f"synthetic block: 12 images, 3 orbits, NAC-like / TC-like / frame cameras (seed {seed})"
    else:
        name = (f"synthetic block: {len(use)} images over {n_sites} sites, 3 orbits, NAC-like / TC-like / frame "
                f"cameras (seed {seed})")
    # full size: one interest point per 512-pixel cell (~1,000 per image) and a search as wide as the
    # navigation errors are in 0.5 m pixels
    cell = 512 if full_size else (64 if quick else 48)
    # full size: a 16-s image spans enough of the orbit that its navigation errors curve (their smooth random
    # part, periods from 20 s): quadratic corrections in time (measured on the full-size example: check points
    # 4.2 m -> 3.1 m 3-D RMS, errors / posterior sigma RMS 1.84 -> 0.73)
    if terrain:
        name = (f"synthetic block with altimetry and jitter: 12 images, 3 orbits, NAC-like / TC-like / frame cameras, "
                f"LOLA-like tracks, bus jitter in the true CK (seed {seed})")
    return EXAMPLE_CONFIG.format(output=output, name=name, images=images, cell=cell, degree=2 if full_size else 1,
                                 search="256.0" if full_size else "128.0",
                                 dtm=_DTM_SECTION if n_sites == 1 else _NO_DTM,
                                 terrain=_TERRAIN_SECTION.format(table=ALTIMETRY_TABLE, **TERRAIN_EXAMPLE)
                                 if terrain else "")

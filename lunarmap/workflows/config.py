"""Run configuration: a TOML file, read without executing anything, validated before any work starts.

Layout (every relative path is taken relative to the configuration file's folder)::

    [run]
    output = "run_output"            # run folder: store, outputs, report, log
    name = "my block"                # free text, for the report

    [kernels]
    metakernel = "mission/navigation.tm"

    [[images]]
    name = "orbit1_nac"              # unique; letters, digits, _ . -
    label = "mission/orbit1_nac.lbl" # ISIS or PDS3 label
    pixels = "mission/orbit1_nac.nc" # netCDF (xarray DataArray, dims line x sample), ISIS cube, PDS3 .IMG or GeoTIFF
    group = "1-nac"                  # navigation group (orbit, camera): offsets/drifts are per group

    [dtm]                            # optional: heights for the tie-point prediction
    path = "mission/dtm.nc"          # netCDF DataArray on lat x lon, metres above the reference radius

    [points]                         # optional: control and check points measured in the images
    path = "points.nc"               # a lunarmap control network (lunarmap.adjust.write_network)
    other_images = "error"           # measures of images not in [[images]]: "error" (checked before any
                                     # work) or "ignore" (dropped; a point left with too few rays too)

    [rpc]
    enabled = true
    height_range = [-300.0, 300.0]   # metres

    [tiepoints]
    cell = 48                        # interest-point grid cell, pixels
    search = 128.0                   # NCC search radius, pixels
    min_overlap = 0.05               # pairs whose footprints overlap less than this fraction are skipped
    max_points = 1000                # most interest points matched per pair, uniform over the overlap
                                     # (0: all of them)

    [adjust]
    degree = 1                       # line-scan correction polynomial degree
    estimate_tie_variance = true     # variance factor of the matcher's sigmas
    ftol = 1e-10

    [adjust.navigation]              # optional: navigation observations
    position_sigma = 0.5             # m per image
    attitude_sigma = 1e-6            # rad per image
    position_rate_sigma = 1.0        # m/s (line-scan higher coefficients)
    attitude_rate_sigma = 1e-6       # rad/s
    offset = "observed"              # "fixed" | "free" | "observed" (per group)
    drift = "observed"
    offset_sigma = [50e-6, 50e-6, 50e-6, 50.0, 50.0, 50.0]     # rad, rad, rad, m, m, m
    drift_sigma = [1e-6, 1e-6, 1e-6, 1.0, 1.0, 1.0]           # rad/s, m/s

    [adjust.terrain]                 # optional: reference DTM heights observe the tie points (lunarmap.adjust.terrain)
    [[adjust.terrain.dtm]]           # one table per DTM: its own observation group and variance component
    path = "lola_dtm.tif"            # GeoTIFF with a Moon CRS (or an ISIS cube with a Mapping group)
    sigma = 2.0                      # a-priori sigma of one interpolated height, m
    name = "lola"                    # optional (default the file's stem); letters, digits, _ . -
    slope_baseline = 48.0            # optional: slope of the partials from heights this far apart, m
                                     # (a noisy DTM's cell slopes are its noise; see lunarmap.adjust.terrain)
    [[adjust.terrain.altimetry]]     # optional, one table per altimeter (lunarmap.adjust.altimetry): its shots
                                     # observe the tie points' triangulated surface, an offset per track
    path = "lola_shots.csv"          # shot table: track, time [s], lon, lat [deg], radius [m], optional sigma [m]
                                     # (CSV or netCDF; lunarmap.io.altimetry)
    sigma = 0.5                      # a-priori radial sigma of one shot, m
    interpolation_sigma = 1.0        # optional: the tie points' surface against the terrain, m (default 0)
    offset_sigma = 30.0              # optional: a-priori sigma of every track's offset, m (default: free offsets,
                                     # the block's radius then comes from the navigation)
    drift = false                    # optional: also a radial drift per track (m/s)
    name = "lola"                    # optional (default the file's stem)

    [adjust.jitter]                  # optional: line-scan attitude jitter splines (lunarmap.adjust.jitter)
    knot_lines = 100.0               # knot spacing of the cubic B-spline, image lines (>= 1)
    sigma = 2e-6                     # smoothness prior: sigma of a second difference of knot coefficients, rad
    zero_sigma = 1e-5                # optional: weak zero prior of the spline parameters, rad
    images = ["orbit1_nac"]          # optional: the images that get a spline (default every line-scan image)

    [adjust.qc]                      # optional: quality control of the adjustment (lunarmap.adjust.quality_control)
    steps = ["baarda"]               # in this order; any of "sequent", "robust", "baarda", "variance", "offsets"
                                     # (["robust", "baarda"] for tie points with many mismatches)
    sequent_limit_km = 0.05          # Sequent: rays whose intersections disagree by more are removed
    robust_function = "danish"       # "danish" | "huber" | "cauchy"
    robust_scale = "mad"             # residuals normalised by the a-priori sigmas ("apriori") or their robust spread
    baarda_limit = 4.0               # w-test limit of the data snooping
    baarda_per_round = "point"       # "one" (largest w-test per round) | "point" (largest per point per round)
    baarda_sigma0 = "robust"         # w-tests against sigma0 = 1 ("apriori"), the adjustment's ("aposteriori") or
                                     # the median standardised residual's ("robust": gross errors do not inflate it)
    baarda_separable = true          # a point whose failing ray no test can single out is withdrawn whole
    downweight_factor = 5.0          # failing navigation / control observations: weight divided by this
    # max_rounds = 200               # budget: adjustments after the first one (default: no limit)
    # max_seconds = 600.0            # budget: wall-clock seconds; a run that spends it is flagged in the report

    [report]
    html = true

An unknown section or key, a value of the wrong type and a file that does not exist are
:class:`~lunarmap.errors.ConfigError`\\ s naming the key and the configuration file; what needs the
files' content (the points file's images, the datum, variance estimation) is checked by
:func:`lunarmap.workflows.checks.check_before_work` before any step runs.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..errors import ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["ImageSpec", "NavigationConfig", "QCConfig", "TerrainDtmConfig", "TerrainAltimetryConfig", "RunConfig", "load_config",
           "config_from_dict"]

_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")

#: Default ``[tiepoints] max_points``: most interest points matched per pair (see the README's curve).
DEFAULT_MAX_POINTS = 1000


@dataclass(frozen=True)
class ImageSpec:
    """One image of a run: its name, label, pixels and navigation group (paths absolute)."""

    name: str
    label: Path
    pixels: Path
    group: str = ""


@dataclass(frozen=True)
class NavigationConfig:
    """Navigation observations (see :class:`lunarmap.adjust.NavigationSpec`); SI units."""

    position_sigma: float
    attitude_sigma: float
    position_rate_sigma: float | None = None
    attitude_rate_sigma: float | None = None
    offset: str = "fixed"
    drift: str = "fixed"
    offset_sigma: tuple[float, ...] | None = None
    drift_sigma: tuple[float, ...] | None = None


@dataclass(frozen=True)
class QCConfig:
    """Quality control of the adjustment (see :func:`lunarmap.adjust.quality_control`); lengths in km as the
    DLR paper gives the Sequent limit."""

    steps: tuple[str, ...] = ("baarda",)
    sequent_limit_km: float = 0.05
    robust_function: str = "danish"
    robust_scale: str = "mad"
    baarda_limit: float = 4.0
    baarda_per_round: str = "point"
    baarda_sigma0: str = "robust"
    downweight_factor: float = 5.0
    baarda_separable: bool = True
    max_rounds: int | None = None
    max_seconds: float | None = None


@dataclass(frozen=True)
class TerrainDtmConfig:
    """One reference DTM of ``[[adjust.terrain.dtm]]`` (see :class:`lunarmap.adjust.ReferenceDtm`).

    Attributes
    ----------
    name : str
        Its observation group is ``"terrain <name>"``.
    path : Path
        The DTM file (absolute).
    sigma : float
        A-priori sigma of one interpolated height, metres.
    slope_baseline : float or None
        Baseline of the partials' slope, metres (None: the cell's gradient).
    """

    name: str
    path: Path
    sigma: float
    slope_baseline: float | None = None

    @property
    def group(self) -> str:
        """The observation group's name (variance component, QC decisions)."""
        return f"terrain {self.name}"


@dataclass(frozen=True)
class JitterConfig:
    """``[adjust.jitter]`` (see :class:`lunarmap.adjust.JitterSpec`).

    Attributes
    ----------
    knot_lines : float
        Knot spacing, image lines (>= 1).
    sigma : float
        Sigma of a second difference of knot coefficients, radians.
    zero_sigma : float or None
        Weak zero prior of the spline parameters, radians.
    images : tuple of str or None
        The images with a spline (None: every line-scan image).
    """

    knot_lines: float
    sigma: float
    zero_sigma: float | None = None
    images: tuple[str, ...] | None = None


@dataclass(frozen=True)
class TerrainAltimetryConfig:
    """One altimeter of ``[[adjust.terrain.altimetry]]`` (see :class:`lunarmap.adjust.LaserAltimetry`).

    Attributes
    ----------
    name : str
        Its observation group is ``"altimetry <name>"``.
    path : Path
        The shot table (absolute; CSV or netCDF, :mod:`lunarmap.io.altimetry`).
    sigma : float
        A-priori radial sigma of one shot, metres.
    interpolation_sigma : float
        Sigma of the tie points' triangulated surface against the terrain, metres.
    offset_sigma : float or None
        A-priori sigma of every track's offset, metres (None: free).
    drift : bool
        A radial drift per track too.
    """

    name: str
    path: Path
    sigma: float
    interpolation_sigma: float = 0.0
    offset_sigma: float | None = None
    drift: bool = False

    @property
    def group(self) -> str:
        """The observation group's name (variance component, QC decisions)."""
        return f"altimetry {self.name}"


@dataclass(frozen=True)
class RunConfig:
    """A validated run configuration (see the module docstring)."""

    source: Path
    output: Path
    metakernel: Path
    images: tuple[ImageSpec, ...]
    name: str = ""
    dtm: Path | None = None
    points: Path | None = None
    points_other_images: str = "error"
    rpc_enabled: bool = True
    rpc_height_range: tuple[float, float] = (-300.0, 300.0)
    cell: int = 48
    search: float = 128.0
    min_overlap: float = 0.05
    max_points: int | None = None
    degree: int = 1
    estimate_tie_variance: bool = True
    ftol: float = 1e-10
    navigation: NavigationConfig | None = None
    qc: QCConfig | None = None
    terrain: tuple[TerrainDtmConfig, ...] = ()
    jitter: JitterConfig | None = None
    html: bool = True
    altimetry: tuple[TerrainAltimetryConfig, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)

    def digest(self) -> str:
        """SHA-256 of the configuration's content (paths and values), for provenance."""
        d = asdict(self)
        d.pop("source")
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()


_MODES = ("fixed", "free", "observed")
_SCHEMA: dict[str, dict[str, tuple[type | tuple[type, ...], bool]]] = {
    # section -> key -> (types, required)
    "run": {"output": (str, True), "name": (str, False)},
    "kernels": {"metakernel": (str, True)},
    "dtm": {"path": (str, True)},
    "points": {"path": (str, True), "other_images": (str, False)},
    "rpc": {"enabled": (bool, False), "height_range": (list, False)},
    "tiepoints": {"cell": (int, False), "search": ((int, float), False), "min_overlap": ((int, float), False),
                  "max_points": (int, False)},
    "adjust": {"degree": (int, False), "estimate_tie_variance": (bool, False), "ftol": ((int, float), False),
               "navigation": (dict, False), "qc": (dict, False), "terrain": (dict, False), "jitter": (dict, False)},
    "report": {"html": (bool, False)},
}
_NAV = {"position_sigma": ((int, float), True), "attitude_sigma": ((int, float), True),
        "position_rate_sigma": ((int, float), False), "attitude_rate_sigma": ((int, float), False),
        "offset": (str, False), "drift": (str, False), "offset_sigma": (list, False), "drift_sigma": (list, False)}
_QC = {"steps": (list, False), "sequent_limit_km": ((int, float), False), "robust_function": (str, False),
       "robust_scale": (str, False), "baarda_limit": ((int, float), False), "baarda_per_round": (str, False),
       "baarda_sigma0": (str, False), "baarda_separable": (bool, False),
       "downweight_factor": ((int, float), False), "max_rounds": (int, False), "max_seconds": ((int, float), False)}
_TERRAIN = {"dtm": (list, False), "altimetry": (list, False)}
_TERRAIN_ALT = {"path": (str, True), "sigma": ((int, float), True), "name": (str, False),
                "interpolation_sigma": ((int, float), False), "offset_sigma": ((int, float), False),
                "drift": (bool, False)}
_JITTER = {"knot_lines": ((int, float), True), "sigma": ((int, float), True), "zero_sigma": ((int, float), False),
           "images": (list, False)}
_TERRAIN_DTM = {"path": (str, True), "sigma": ((int, float), True), "name": (str, False),
                "slope_baseline": ((int, float), False)}
_IMAGE = {"name": (str, True), "label": (str, True), "pixels": (str, True), "group": ((str, int), False)}


def _type_name(t: type | tuple[type, ...]) -> str:
    ts = t if isinstance(t, tuple) else (t,)
    return " or ".join({"str": "a string", "int": "an integer", "float": "a number", "bool": "true/false",
                        "list": "an array", "dict": "a table"}[x.__name__] for x in ts)


def _check_table(table: Mapping[str, Any], schema: Mapping[str, tuple[Any, bool]], where: str, src: str) -> None:
    for key in table:
        if key not in schema:
            raise ConfigError(f"{src}: unknown key {where}.{key} (known: {', '.join(sorted(schema))})")
    for key, (types, required) in schema.items():
        if key not in table:
            if required:
                raise ConfigError(f"{src}: missing required key {where}.{key}")
            continue
        v = table[key]
        ok = isinstance(v, types) and not (isinstance(v, bool) and bool not in (types if isinstance(types, tuple)
                                                                                  else (types,)))
        if not ok:
            raise ConfigError(f"{src}: {where}.{key} must be {_type_name(types)}, got {v!r}")


def _path(base: Path, value: str, key: str, src: str, must_exist: bool = True, folder: bool = False) -> Path:
    if not str(value).strip() or "\0" in str(value):
        # Path("") is ".": an empty value would silently name the configuration's folder
        raise ConfigError(f"{src}: {key} = {value!r} is not a path")
    p = Path(value)
    p = p if p.is_absolute() else (base / p)
    if must_exist and not p.exists():
        raise ConfigError(f"{src}: {key} = {value!r}: file {p} does not exist")
    if must_exist and not folder and p.is_dir():
        raise ConfigError(f"{src}: {key} = {value!r}: {p} is a folder, not a file")
    return p


def _numbers(v: list, n: int, key: str, src: str) -> tuple[float, ...]:
    if len(v) != n or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        raise ConfigError(f"{src}: {key} must be an array of {n} numbers, got {v!r}")
    return tuple(float(x) for x in v)


def _qc_config(q: Mapping[str, Any], navigation: bool, largest_group: int, src: str) -> QCConfig:
    from ..adjust.qc import STEPS, WEIGHT_FUNCTIONS

    _check_table(q, _QC, "adjust.qc", src)
    d = QCConfig()
    steps = tuple(q.get("steps", d.steps))
    if any(not isinstance(s, str) or s not in STEPS for s in steps) or len(set(steps)) != len(steps):
        raise ConfigError(f"{src}: adjust.qc.steps must be distinct names of {list(STEPS)}, got {list(steps)}")
    if "offsets" in steps and not navigation:
        raise ConfigError(f"{src}: adjust.qc.steps has 'offsets' but there are no navigation observations "
                          "([adjust.navigation])")
    if "offsets" in steps and largest_group < 2:
        raise ConfigError(f"{src}: adjust.qc.steps has 'offsets' but no navigation group has 2 or more images: an "
                          "offset of a group of one image cannot be told from that image's own navigation error")
    for key in ("sequent_limit_km", "baarda_limit"):
        if key in q and not q[key] > 0:
            raise ConfigError(f"{src}: adjust.qc.{key} must be > 0, got {q[key]!r}")
    if "max_rounds" in q and not q["max_rounds"] >= 0:
        raise ConfigError(f"{src}: adjust.qc.max_rounds must be >= 0, got {q['max_rounds']!r}")
    if "max_seconds" in q and not q["max_seconds"] >= 0:
        raise ConfigError(f"{src}: adjust.qc.max_seconds must be >= 0, got {q['max_seconds']!r}")
    if "downweight_factor" in q and not q["downweight_factor"] > 1:
        raise ConfigError(f"{src}: adjust.qc.downweight_factor must be > 1, got {q['downweight_factor']!r}")
    fn = q.get("robust_function", d.robust_function)
    if fn not in WEIGHT_FUNCTIONS:
        raise ConfigError(f"{src}: adjust.qc.robust_function must be one of {sorted(WEIGHT_FUNCTIONS)}, got {fn!r}")
    per_round = q.get("baarda_per_round", d.baarda_per_round)
    if per_round not in ("one", "point"):
        raise ConfigError(f"{src}: adjust.qc.baarda_per_round must be 'one' or 'point', got {per_round!r}")
    for key, allowed in (("robust_scale", ("apriori", "mad")), ("baarda_sigma0", ("apriori", "aposteriori", "robust"))):
        if key in q and q[key] not in allowed:
            raise ConfigError(f"{src}: adjust.qc.{key} must be one of {list(allowed)}, got {q[key]!r}")
    return QCConfig(steps, float(q.get("sequent_limit_km", d.sequent_limit_km)), fn,
                    q.get("robust_scale", d.robust_scale), float(q.get("baarda_limit", d.baarda_limit)), per_round,
                    q.get("baarda_sigma0", d.baarda_sigma0), float(q.get("downweight_factor", d.downweight_factor)),
                    bool(q.get("baarda_separable", d.baarda_separable)),
                    int(q["max_rounds"]) if "max_rounds" in q else None,
                    float(q["max_seconds"]) if "max_seconds" in q else None)


def _bounded(t: Mapping[str, Any], key: str, where: str, unit: str, src: str, low: float = 0.0,
             inclusive: bool = False) -> float:
    """``t[key]`` as a finite float above ``low`` (or at it, ``inclusive``), else a ConfigError naming it."""
    v = float(t[key])
    if not ((v >= low if inclusive else v > low) and v < float("inf")):
        raise ConfigError(f"{src}: {where}.{key} must be {'>=' if inclusive else '>'} {low:g} {unit}, got {t[key]!r}")
    return v


def _group_name(e: Mapping[str, Any], path: Path, where: str, taken: Sequence[Any], what: str, src: str) -> str:
    """The observation group's name of a terrain table (default its file's stem), checked and unique."""
    name = e.get("name", path.stem)
    if not _NAME.match(name):
        raise ConfigError(f"{src}: {where}.name {name!r} may hold only letters, digits, '_', '.', '-'")
    if any(d.name == name for d in taken):
        raise ConfigError(f"{src}: {where}.name {name!r} repeats (each {what} is its own observation group)")
    return name


def _jitter_config(t: Any, names: Sequence[str], src: str) -> JitterConfig:
    if not isinstance(t, dict):
        raise ConfigError(f"{src}: [adjust.jitter] must be a table")
    _check_table(t, _JITTER, "adjust.jitter", src)
    knots = _bounded(t, "knot_lines", "adjust.jitter", "line", src, low=1.0, inclusive=True)
    sigma = _bounded(t, "sigma", "adjust.jitter", "radians", src)
    zero = _bounded(t, "zero_sigma", "adjust.jitter", "radians", src) if "zero_sigma" in t else None
    images = None
    if "images" in t:
        images = tuple(t["images"])
        unknown = [str(i) for i in images if not isinstance(i, str) or i not in names]
        if unknown or not images:
            raise ConfigError(f"{src}: adjust.jitter.images must name images of [[images]]"
                              f"{': unknown ' + ', '.join(unknown[:5]) if unknown else ' (got none)'}")
    return JitterConfig(knots, sigma, zero, images)


def _terrain_config(t: Any, base: Path, src: str) -> tuple[TerrainDtmConfig, ...]:
    if not isinstance(t, dict):
        raise ConfigError(f"{src}: [adjust.terrain] must be a table")
    _check_table(t, _TERRAIN, "adjust.terrain", src)
    if not t.get("dtm") and not t.get("altimetry"):
        raise ConfigError(f"{src}: [adjust.terrain] must list at least one [[adjust.terrain.dtm]] or "
                          "[[adjust.terrain.altimetry]] table")
    out: list[TerrainDtmConfig] = []
    for k, e in enumerate(t.get("dtm", [])):
        where = f"adjust.terrain.dtm[{k}]"
        if not isinstance(e, dict):
            raise ConfigError(f"{src}: {where} must be a table")
        _check_table(e, _TERRAIN_DTM, where, src)
        path = _path(base, e["path"], f"{where}.path", src)
        name = _group_name(e, path, where, out, "DTM", src)
        sigma = _bounded(e, "sigma", where, "metres", src)
        baseline = _bounded(e, "slope_baseline", where, "metres", src) if "slope_baseline" in e else None
        out.append(TerrainDtmConfig(name, path, sigma, baseline))
    return tuple(out)


def _altimetry_config(t: Any, base: Path, src: str) -> tuple[TerrainAltimetryConfig, ...]:
    out: list[TerrainAltimetryConfig] = []
    for k, e in enumerate(t.get("altimetry", []) if isinstance(t, dict) else []):
        where = f"adjust.terrain.altimetry[{k}]"
        if not isinstance(e, dict):
            raise ConfigError(f"{src}: {where} must be a table")
        _check_table(e, _TERRAIN_ALT, where, src)
        path = _path(base, e["path"], f"{where}.path", src)
        name = _group_name(e, path, where, out, "altimeter", src)
        out.append(TerrainAltimetryConfig(
            name, path, _bounded(e, "sigma", where, "metres", src),
            _bounded(e, "interpolation_sigma", where, "metres", src, inclusive=True) if "interpolation_sigma" in e
            else 0.0,
            _bounded(e, "offset_sigma", where, "metres", src) if "offset_sigma" in e else None,
            bool(e.get("drift", False))))
    return tuple(out)


def config_from_dict(d: Mapping[str, Any], base: str | os.PathLike[str] = ".",
                     source: str = "<dict>") -> RunConfig:
    """Validate a configuration already parsed into a dict (``base``: folder for relative paths)."""
    src = source
    base_p = Path(base)
    for section in d:
        if section != "images" and section not in _SCHEMA:
            raise ConfigError(f"{src}: unknown section [{section}] (known: images, {', '.join(sorted(_SCHEMA))})")
    for section, schema in _SCHEMA.items():
        if section in d:
            if not isinstance(d[section], dict):
                raise ConfigError(f"{src}: [{section}] must be a table")
            _check_table(d[section], schema, section, src)
    for required in ("run", "kernels"):
        if required not in d:
            raise ConfigError(f"{src}: missing section [{required}]")
    images_raw = d.get("images")
    if not isinstance(images_raw, list) or not images_raw:
        raise ConfigError(f"{src}: [[images]] must list at least 2 images")
    images = []
    seen: set[str] = set()
    for k, im in enumerate(images_raw):
        where = f"images[{k}]"
        if not isinstance(im, dict):
            raise ConfigError(f"{src}: {where} must be a table")
        _check_table(im, _IMAGE, where, src)
        name = im["name"]
        if not _NAME.match(name):
            raise ConfigError(f"{src}: {where}.name {name!r} may hold only letters, digits, '_', '.', '-'")
        if name in seen:
            raise ConfigError(f"{src}: {where}.name {name!r} repeats")
        seen.add(name)
        images.append(ImageSpec(name, _path(base_p, im["label"], f"{where}.label", src),
                                _path(base_p, im["pixels"], f"{where}.pixels", src), str(im.get("group", ""))))
    if len(images) < 2:
        raise ConfigError(f"{src}: [[images]] must list at least 2 images")
    run, rpc, tp = d["run"], d.get("rpc", {}), d.get("tiepoints", {})
    adj, rep = d.get("adjust", {}), d.get("report", {})
    nav = None
    if "navigation" in adj:
        n = adj["navigation"]
        _check_table(n, _NAV, "adjust.navigation", src)
        for key in ("offset", "drift"):
            if key in n and n[key] not in _MODES:
                raise ConfigError(f"{src}: adjust.navigation.{key} must be one of {_MODES}, got {n[key]!r}")
        for key in ("position_sigma", "attitude_sigma", "position_rate_sigma", "attitude_rate_sigma"):
            if key in n and not n[key] > 0:
                raise ConfigError(f"{src}: adjust.navigation.{key} must be > 0, got {n[key]!r}")
        nav = NavigationConfig(
            float(n["position_sigma"]), float(n["attitude_sigma"]),
            float(n["position_rate_sigma"]) if "position_rate_sigma" in n else None,
            float(n["attitude_rate_sigma"]) if "attitude_rate_sigma" in n else None,
            n.get("offset", "fixed"), n.get("drift", "fixed"),
            _numbers(n["offset_sigma"], 6, "adjust.navigation.offset_sigma", src) if "offset_sigma" in n else None,
            _numbers(n["drift_sigma"], 6, "adjust.navigation.drift_sigma", src) if "drift_sigma" in n else None)
        for key, mode in (("offset", nav.offset), ("drift", nav.drift)):
            if mode == "observed" and getattr(nav, f"{key}_sigma") is None:
                raise ConfigError(f"{src}: adjust.navigation.{key} = 'observed' needs adjust.navigation.{key}_sigma")
    qc = None
    if "qc" in adj:
        per_group: dict[str, int] = {}
        for im in images:
            per_group[im.group or im.name] = per_group.get(im.group or im.name, 0) + 1
        qc = _qc_config(adj["qc"], nav is not None, max(per_group.values()), src)
    terrain = _terrain_config(adj["terrain"], base_p, src) if "terrain" in adj else ()
    jitter = _jitter_config(adj["jitter"], [im.name for im in images], src) if "jitter" in adj else None
    altimetry = _altimetry_config(adj["terrain"], base_p, src) if "terrain" in adj else ()
    if (terrain or altimetry) and qc is not None and "variance" in qc.steps and "baarda" in qc.steps \
            and qc.steps.index("variance") > qc.steps.index("baarda"):
        # the w-tests of the DTM heights rest on their sigma: tested at a wrong a-priori sigma (the DTM's
        # error is what the run estimates), good heights go or bad ones stay
        raise ConfigError(f"{src}: adjust.qc.steps {list(qc.steps)}: with [adjust.terrain], 'variance' must come "
                          "before 'baarda' (the DTM heights are tested at their estimated sigma)")
    other_images = d.get("points", {}).get("other_images", "error")
    if other_images not in ("error", "ignore"):
        raise ConfigError(f"{src}: points.other_images must be 'error' or 'ignore', got {other_images!r}")
    lo, hi = _numbers(rpc["height_range"], 2, "rpc.height_range", src) if "height_range" in rpc \
        else (-300.0, 300.0)
    height_range = (lo, hi)
    if not height_range[1] > height_range[0]:
        raise ConfigError(f"{src}: rpc.height_range must increase, got {list(height_range)}")
    degree = int(adj.get("degree", 1))
    if degree not in (0, 1, 2):
        raise ConfigError(f"{src}: adjust.degree must be 0, 1 or 2, got {degree}")
    cell = int(tp.get("cell", 48))
    if cell < 8:
        raise ConfigError(f"{src}: tiepoints.cell must be >= 8 pixels, got {cell}")
    search = float(tp.get("search", 128.0))
    if not search > 0:
        raise ConfigError(f"{src}: tiepoints.search must be > 0 pixels, got {search}")
    min_overlap = float(tp.get("min_overlap", 0.05))
    if not 0.0 <= min_overlap < 1.0:
        raise ConfigError(f"{src}: tiepoints.min_overlap must be in [0, 1), got {min_overlap}")
    max_points = int(tp.get("max_points", DEFAULT_MAX_POINTS))
    if max_points < 0 or 0 < max_points < 16:
        raise ConfigError(f"{src}: tiepoints.max_points must be 0 (all points) or >= 16, got {max_points}")
    return RunConfig(
        source=Path(source).resolve() if source != "<dict>" else Path(source),
        output=_path(base_p, run["output"], "run.output", src, must_exist=False),
        metakernel=_path(base_p, d["kernels"]["metakernel"], "kernels.metakernel", src),
        images=tuple(images), name=str(run.get("name", "")),
        dtm=_path(base_p, d["dtm"]["path"], "dtm.path", src) if "dtm" in d else None,
        points=_path(base_p, d["points"]["path"], "points.path", src) if "points" in d else None,
        points_other_images=other_images,
        rpc_enabled=bool(rpc.get("enabled", True)), rpc_height_range=height_range, cell=cell, search=search,
        min_overlap=min_overlap, max_points=max_points or None, degree=degree, estimate_tie_variance=bool(adj.get("estimate_tie_variance", True)),
        ftol=float(adj.get("ftol", 1e-10)), navigation=nav, qc=qc, terrain=terrain, jitter=jitter,
        html=bool(rep.get("html", True)), altimetry=altimetry)


def load_config(path: str | os.PathLike[str]) -> RunConfig:
    """Read and validate a TOML run configuration (no code is executed; see the module docstring).

    Raises
    ------
    ConfigError
        Unreadable TOML, unknown section or key, wrong type, missing file (each names key and file).
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"run configuration {p} does not exist")
    try:
        d = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"{p}: not valid TOML: {err}") from None
    return config_from_dict(d, base=p.resolve().parent, source=str(p))

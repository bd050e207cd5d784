"""The tie-point chain for a set of images, and the tie-point table.

Per image, interest points are detected tile by tile; per image pair
``(i, j)``, the points of image ``i`` are predicted into ``j`` through the
sensor models, matched by pyramid NCC and least-squares matching, and
screened by RANSAC; matches of all pairs are joined into multi-image tracks.
The result is an ``xarray.Dataset`` with one row per observation:

=================  =======================================================
``point_id``       track id (one per ground feature), int64
``image_id``       index into the ``image`` coordinate (image names)
``line, sample``   image coordinates, pixels (CSM: first pixel centre 0.5)
``sigma_line``     standard deviation, pixels (LSM's, split equally
``sigma_sample``   between the two images of a match: ``sigma / sqrt 2``)
``correlation``    LSM correlation coefficient
=================  =======================================================

:func:`~lunarmap.matching.parallel.find_tiepoints` runs these steps as a dask graph with any
scheduler (``"sync"`` for serial, a ``distributed.Client``...).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ..atomic import atomic_write
from ..camera.intersect import DtmSampler
from ..errors import InvalidInputError, TiePointFormatError
from ..ncread import load_netcdf
from .interest import InterestPoints, foerstner
from .pairs import STATUS, MatchParams, PairMatches, match_points
from .ransac import RansacParams, ransac_local_affine
from .thinning import thin_points
from .tracks import Observations, build_tracks

__all__ = ["DetectParams", "TiePointParams", "detect_tile", "tile_windows", "match_pair", "assemble_tiepoints", "TrackRows",
           "write_tiepoints", "read_tiepoints", "check_tiepoint_table", "TIEPOINT_VARIABLES"]


@dataclass
class DetectParams:
    """Interest-point detection per tile (pixels); see :func:`~lunarmap.matching.interest.foerstner`."""

    tile: int = 256
    window: int = 5
    nms: int = 7
    cell: int = 32
    per_cell: int = 2
    q_min: float = 0.5
    min_contrast: float = 1.0
    border: int = 10


@dataclass
class TiePointParams:
    """All tuning of the chain.

    Attributes
    ----------
    detect, match, ransac
        Detection, matching and RANSAC settings.
    track_tol : float
        Positions of one image closer than this (pixels) are one feature of a track.
    max_points : int, optional
        Most interest points of image 1 matched per pair, spatially uniform over the overlap
        (:func:`~lunarmap.matching.thinning.thin_points`); ``None`` matches every point.
    """

    detect: DetectParams = field(default_factory=DetectParams)
    match: MatchParams = field(default_factory=MatchParams)
    ransac: RansacParams = field(default_factory=RansacParams)
    track_tol: float = 0.5
    max_points: int | None = None


def tile_windows(shape: tuple[int, int], tile: int, halo: int) -> list[tuple[tuple[int, int, int, int],
                                                                           tuple[int, int, int, int]]]:
    """``(core, padded)`` array-index windows ``(l0, l1, s0, s1)`` tiling an image."""
    h, w = shape
    out = []
    for a in range(0, h, tile):
        for c in range(0, w, tile):
            core = (a, min(a + tile, h), c, min(c + tile, w))
            pad = (max(a - halo, 0), min(a + tile + halo, h), max(c - halo, 0), min(c + tile + halo, w))
            out.append((core, pad))
    return out


def detect_tile(pixels: NDArray, core: tuple[int, int, int, int], padded: tuple[int, int, int, int],
                params: DetectParams, saturation: float | None, label: str) -> InterestPoints:
    """Interest points of one tile (``pixels`` = the padded window); CSM coordinates of the full image."""
    lab = f"{label} tile lines [{core[0]}, {core[1]}) samples [{core[2]}, {core[3]})"
    return foerstner(np.asarray(pixels, dtype=float), window=params.window, nms=params.nms, cell=params.cell,
                     per_cell=params.per_cell, q_min=params.q_min, min_contrast=params.min_contrast,
                     border=params.border, saturation=saturation, origin=(padded[0], padded[2]), core=core,
                     label=lab)


def merge_points(parts: Sequence[InterestPoints]) -> InterestPoints:
    """Concatenate the interest points of all tiles of an image."""
    if not parts:
        return InterestPoints(np.empty(0), np.empty(0), np.empty(0))
    return InterestPoints(*(np.concatenate([p[k] for p in parts]) for k in range(3)))


def _typical_height(height: Any) -> float:
    """The median prediction height (metres) of one height, per-point heights or a DTM.

    A DTM's median is taken on every 4th node in each direction: ``np.nanmedian`` copies its input, and a
    full-size example's DTM is 177 MB (the thinning only needs a typical height).
    """
    if isinstance(height, DtmSampler):
        return float(np.nanmedian(height.z[::4, ::4]))
    if isinstance(height, xr.DataArray):
        return float(np.nanmedian(np.asarray(height.values)[..., ::4, ::4]))
    return float(np.nanmedian(np.asarray(height, dtype=float)))


def match_pair(image1: NDArray, image2: NDArray, sensor1: Any, sensor2: Any, points: InterestPoints,
               height: Any, params: TiePointParams, label: str) -> PairMatches:
    """Match one image pair and screen the matches with RANSAC (outliers get status ``outlier``).

    With ``params.max_points`` the points are first thinned to that many, uniformly over the overlap
    (the others get status ``thinned``). ``image1``, ``image2``: arrays or windowed images
    (:class:`~lunarmap.matching.windowed.WindowedImage`).
    """
    n = points.line.size
    keep = None
    if params.max_points is not None and n > params.max_points:
        h = _typical_height(height)
        keep = thin_points(points.line, points.sample, points.strength, params.max_points, sensor1, sensor2,
                           tuple(image1.shape), tuple(image2.shape), h, cell=float(params.detect.cell))
    if keep is None:
        m = match_points(image1, image2, sensor1, sensor2, points.line, points.sample, height=height,
                         params=params.match, label=label)
    else:
        # per-point heights follow their points; a DTM or one height serves all
        h_keep = height if isinstance(height, (xr.DataArray, DtmSampler)) or np.ndim(height) == 0 else np.asarray(height)[keep]
        m = _expand(match_points(image1, image2, sensor1, sensor2, points.line[keep], points.sample[keep],
                                 height=h_keep, params=params.match, label=label), keep, n, points)
    ok = m.ok
    if np.count_nonzero(ok) >= 3:
        p = m.prediction
        inl = ransac_local_affine(m.line1[ok], m.sample1[ok], m.line2[ok] - p.line[ok],
                                  m.sample2[ok] - p.sample[ok], p.epipolar[ok], params.ransac)
        idx = np.flatnonzero(ok)
        m.status[idx[~inl]] = STATUS["outlier"]
    m.meta["n_points"] = int(m.line1.size)
    m.meta["n_ok"] = int(np.count_nonzero(m.ok))
    return m


def _expand(m: PairMatches, keep: NDArray[np.intp], n: int, points: InterestPoints) -> PairMatches:
    """Matches of the kept points as rows of all ``n`` points (the others ``thinned``)."""
    from .predict import Prediction

    def full(a: NDArray, fill: float = np.nan) -> NDArray:
        out = np.full((n,) + a.shape[1:], fill, dtype=a.dtype)
        out[keep] = a
        return out

    status = np.full(n, STATUS["thinned"], dtype=np.int8)
    status[keep] = m.status
    p = m.prediction
    pred = Prediction(full(p.line), full(p.sample), full(p.affine), full(p.epipolar), full(p.height))
    line1, sample1 = points.line.astype(float), points.sample.astype(float)
    return PairMatches(line1, sample1, full(m.line2), full(m.sample2), full(m.sigma_line), full(m.sigma_sample),
                       full(m.correlation), status, pred, dict(m.meta, thinned=int(n - keep.size)))


class TrackRows:
    """Matched rows of image pairs, gathered pair by pair and joined into tracks at the end.

    Only what the tie-point table needs is kept per pair (its matched rows, not the attempted points'
    predictions), so a run's memory grows with its matches, not with its interest points.
    """

    def __init__(self) -> None:
        self.parts: dict[str, list[NDArray]] = {k: [] for k in ("img", "node", "line", "sample", "sl", "ss", "corr",
                                                                  "ea", "eb")}
        self.n_rows = 0
        self.next_node = 0
        self.anchor_base: dict[int, int] = {}
        self.stats: dict[tuple[int, int], str] = {}

    @property
    def n_pairs(self) -> int:
        return len(self.stats)

    def add(self, i: int, j: int, index: NDArray, line1: NDArray, sample1: NDArray, line2: NDArray, sample2: NDArray,
            sigma_line: NDArray, sigma_sample: NDArray, correlation: NDArray, n_points: int) -> None:
        """The matched rows of pair ``(i, j)``: ``index`` of the matched interest points of image ``i``."""
        k = int(np.size(index))
        self.stats[(i, j)] = f"{k}/{n_points}"
        if k == 0:
            return
        if i not in self.anchor_base:  # anchors of image i: one node per interest point, shared by its pairs
            self.anchor_base[i] = self.next_node
            self.next_node += 10 ** 9
        anchors = self.anchor_base[i] + np.asarray(index, dtype=np.int64)
        matched = self.next_node + np.arange(k)
        self.next_node += k
        s_l = np.asarray(sigma_line, float) / np.sqrt(2.0)
        s_s = np.asarray(sigma_sample, float) / np.sqrt(2.0)
        p = self.parts
        p["img"] += [np.full(k, i), np.full(k, j)]
        p["node"] += [anchors, matched]
        p["line"] += [np.asarray(line1, float), np.asarray(line2, float)]
        p["sample"] += [np.asarray(sample1, float), np.asarray(sample2, float)]
        p["sl"] += [s_l, s_l]
        p["ss"] += [s_s, s_s]
        p["corr"] += [np.asarray(correlation, float)] * 2
        p["ea"].append(self.n_rows + np.arange(k))
        p["eb"].append(self.n_rows + k + np.arange(k))
        self.n_rows += 2 * k

    def table(self, names: Sequence[str], track_tol: float = 0.5) -> xr.Dataset:
        """The tie-point table (see the module docstring)."""
        def cat(key: str, dtype: type) -> NDArray:
            parts = self.parts[key]
            return np.concatenate(parts).astype(dtype) if parts else np.empty(0, dtype=dtype)

        obs = Observations(cat("img", np.int64), cat("node", np.int64), cat("line", float), cat("sample", float),
                           cat("sl", float), cat("ss", float), cat("corr", float), cat("ea", np.int64),
                           cat("eb", np.int64))
        table, n_conflicts = build_tracks(obs, tol=track_tol)
        pair_stats = {f"{names[i]}|{names[j]}": v for (i, j), v in self.stats.items()}
        return xr.Dataset(
            {
                "point_id": ("observation", table["point_id"].to_numpy(np.int64),
                             {"long_name": "tie-point (track) id"}),
                "image_id": ("observation", table["image_id"].to_numpy(np.int32),
                             {"long_name": "index into the image coordinate"}),
                "line": ("observation", table["line"].to_numpy(float), {"units": "pixel"}),
                "sample": ("observation", table["sample"].to_numpy(float), {"units": "pixel"}),
                "sigma_line": ("observation", table["sigma_line"].to_numpy(float), {"units": "pixel"}),
                "sigma_sample": ("observation", table["sigma_sample"].to_numpy(float), {"units": "pixel"}),
                "correlation": ("observation", table["correlation"].to_numpy(float), {"units": "1"}),
            },
            coords={"image": ("image", np.asarray(list(names), dtype=str))},
            attrs={"pixel_convention": "CSM: centre of the first pixel at (0.5, 0.5)",
                   "sigma_convention": "LSM standard deviation of the match split equally: sigma / sqrt(2) per image",
                   "n_conflicting_tracks_dropped": n_conflicts,
                   "matches_per_pair": "; ".join(f"{k}: {v}" for k, v in pair_stats.items()),
                   "source": "lunarmap.matching"},
        )


def assemble_tiepoints(results: Sequence[tuple[int, int, PairMatches]], names: Sequence[str],
                       track_tol: float = 0.5) -> xr.Dataset:
    """Join pair matches into tracks and return the tie-point table (see the module docstring)."""
    rows = TrackRows()
    for i, j, m in results:
        ok = np.flatnonzero(m.ok)
        rows.add(i, j, ok, m.line1[ok], m.sample1[ok], m.line2[ok], m.sample2[ok], m.sigma_line[ok],
                 m.sigma_sample[ok], m.correlation[ok], n_points=0)
        rows.stats[(i, j)] = f"{m.meta.get('n_ok', 0)}/{m.meta.get('n_points', 0)}"
    return rows.table(names, track_tol)


def write_tiepoints(ds: xr.Dataset, path: str | os.PathLike) -> Path:
    """Write a tie-point table to netCDF atomically (temporary file in the same folder, then rename)."""
    path = Path(path)
    if not isinstance(ds, xr.Dataset) or "point_id" not in ds:
        raise InvalidInputError("write_tiepoints expects the Dataset returned by find_tiepoints")
    return atomic_write(path, lambda tmp: ds.to_netcdf(tmp, engine="netcdf4"))


#: Variables of a tie-point table, all along one dimension (one row per observation).
TIEPOINT_VARIABLES = ("point_id", "image_id", "line", "sample", "sigma_line", "sigma_sample")


def check_tiepoint_table(ds: object, error: type[Exception] = TiePointFormatError, source: str = "") -> None:
    """Raise ``error`` unless ``ds`` is a usable tie-point table (see the module docstring).

    Checked: an ``xarray.Dataset`` with the variables of :data:`TIEPOINT_VARIABLES`, all 1-D along
    one dimension, an ``image`` coordinate; integer point and image ids, image ids indexing
    ``image``; finite coordinates and finite positive sigmas.
    """
    where = f"tie-point table {source}".rstrip()
    if not isinstance(ds, xr.Dataset):
        raise error(f"expected the tie-point Dataset of find_tiepoints, got {type(ds).__name__}")
    missing = [v for v in TIEPOINT_VARIABLES if v not in ds] + (["image"] if "image" not in ds.coords else [])
    if missing:
        raise error(f"not a tie-point table{' ' + source if source else ''}: missing {', '.join(missing)}")
    dims = {ds[v].dims for v in TIEPOINT_VARIABLES}
    if len(dims) != 1 or len(next(iter(dims))) != 1:
        raise error(f"{where}: {', '.join(TIEPOINT_VARIABLES)} must share one dimension, got {sorted(dims)}")
    if ds["image"].ndim != 1:
        raise error(f"{where}: the image coordinate must be 1-D")
    for v in TIEPOINT_VARIABLES:
        a = ds[v].values
        if a.dtype.kind not in "iuf":
            raise error(f"{where}: {v} must be numeric, got {a.dtype}")
        if not np.all(np.isfinite(a)):
            raise error(f"{where}: {v} holds NaN or infinite values")
    for v in ("point_id", "image_id"):
        a = ds[v].values
        if not np.all(a == np.round(a)):
            raise error(f"{where}: {v} holds non-integer values")
    img = ds["image_id"].values
    if img.size and (img.min() < 0 or img.max() >= ds["image"].size):
        raise error(f"{where}: image_id out of range [0, {ds['image'].size})")
    for v in ("sigma_line", "sigma_sample"):
        if np.any(ds[v].values <= 0):
            raise error(f"{where}: {v} must be positive")


def read_tiepoints(path: str | os.PathLike) -> xr.Dataset:
    """Read a tie-point table written by :func:`write_tiepoints` (loaded into memory, file closed).

    Raises
    ------
    FileNotFoundError
        No such file.
    TiePointFormatError
        The file is not a readable netCDF file or not a tie-point table (:func:`check_tiepoint_table`).
    """
    ds = load_netcdf(path, TiePointFormatError, "tie-point table")
    check_tiepoint_table(ds, TiePointFormatError, str(path))
    return ds

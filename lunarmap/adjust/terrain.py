"""Reference DTM heights as observations of the tie points (issue 30, item 1).

For every tie point ``j`` inside a reference DTM, its height is observed:

    v_j = (|X_j| - R) - h_DTM(lon(X_j), lat(X_j)),        sigma_j = sigma of the DTM

with ``R`` the radius of the DTM's CRS (a Moon sphere: the height is the ellipsoidal height of that
CRS) and ``h_DTM`` the DTM bilinearly interpolated at the point's planetocentric longitude and
latitude (for a sphere, planetocentric = planetographic). The partials w.r.t. the point are
analytic: ``d|X|/dX = X / |X|`` minus the DTM's slope term ``dh/dlon dlon/dX + dh/dlat dlat/dX``
(the bilinear gradient in pixels, chained with the map projection's partials: exact for a
geographic CRS; PROJ's projection differentiated centrally, 1e-9 relative, for a projected one).
On sloping terrain a horizontal shift of the point changes its residual: the DTM observes the
horizontal position too, the more the steeper the terrain.

The slope of a noisy DTM's cell is mostly its noise (white node noise ``s`` on spacing ``d`` gives
slopes of ``~s / d``: 3 m on 10 m, 0.3, against a terrain's few percent): taken as terrain, it makes the
DTM observe horizontal positions it does not know (errors in the variables). With ``slope_baseline_m``
the partials take the slope from DTM heights that far apart (a central difference over the baseline),
the terrain's slope at that scale; the residual is still the interpolated height. Measured on the run
test's synthetic block (white noise 3 m on 10 m nodes, variance components then data snooping):
check points 20.3 m 3-D, errors / posterior sigma 27 with the cell slopes; 0.73 m and 0.95 with a 48 m
baseline.

Each :class:`ReferenceDtm` is one observation group (its own variance component) and its rows
are w-tested by data snooping like the others: a point on steep or changed terrain (a fresh
crater, a DTM artefact) gets a large w and is down-weighted and named in the QC report.

Reading: the DTM (GeoTIFF through GDAL, or an ISIS cube with an Equirectangular/SimpleCylindrical
``Mapping`` group) is opened lazily through :func:`lunarmap.io.open_image`, and only the window of
pixels around the block's points (plus a margin for their moves during the adjustment) is read.

Skipping, documented and counted (``DtmHeights.skipped``): points outside the grid or on a cell
with a NaN node (hole, nodata) get no observation. A point that moves into such a cell during the
adjustment keeps its row with a zero residual and zero partials (``DtmHeights.lost`` counts them at
the last linearisation), so that every index keeps its meaning. Nothing here calls SPICE.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pyproj
import scipy.sparse as sp
from numpy.typing import NDArray

from ..errors import DtmCoverageError, DtmCrsError, LunarmapError, TerrainInputError

__all__ = ["ReferenceDtm", "DtmGrid", "DtmHeights", "dtm_heights", "point_height"]

#: Moon radii a CRS may have (metres): the IAU sphere 1737.4 km, LOLA's 1737.151 km, and margin for others.
_MOON_RADIUS_RANGE = (1.70e6, 1.78e6)
#: Pixels read around the block's points, beyond their bounding box: room for their moves in the adjustment.
_MARGIN_PX = 16
#: Step of the central difference of a projected CRS's map coordinates, degrees.
_PROJ_STEP_DEG = 1e-6


@dataclass
class ReferenceDtm:
    """A reference DTM whose heights observe the block's tie points.

    Parameters
    ----------
    path : path-like
        GeoTIFF (any GDAL raster with a CRS and a north-up geotransform) or ISIS cube with a
        ``Mapping`` group (Equirectangular or SimpleCylindrical), one band of heights.
    sigma_m : float
        A-priori standard deviation of one interpolated DTM height, metres (> 0).
    name : str, optional
        Observation-group name in reports (default ``"dtm <file name>"``).
    band : int
        Band of the heights (1-based).
    values : {"height", "radius"}
        What the pixels hold: heights above the CRS's sphere (metres), or radii (metres; the CRS
        radius is subtracted).
    point_types : sequence of str
        Point types that get an observation (default tie points only; check points keep their
        independence, control points their own observation).
    slope_baseline_m : float, optional
        Ground distance (metres, > 0) between the DTM heights whose difference gives the slope in the
        partials (module docstring); default the interpolating cell's own gradient.
    """

    path: str | os.PathLike[str]
    sigma_m: float
    name: str | None = None
    band: int = 1
    values: str = "height"
    point_types: Sequence[str] = ("tie",)
    slope_baseline_m: float | None = None

    def __post_init__(self) -> None:
        if self.slope_baseline_m is not None:
            b = float(self.slope_baseline_m)
            if not (np.isfinite(b) and b > 0):
                raise TerrainInputError(f"reference DTM {self.path}: slope_baseline_m must be finite and > 0, "
                                        f"got {self.slope_baseline_m!r}")
            self.slope_baseline_m = b
        s = float(self.sigma_m)
        if not (np.isfinite(s) and s > 0):
            raise TerrainInputError(f"reference DTM {self.path}: sigma_m must be finite and > 0, got {self.sigma_m!r}")
        self.sigma_m = s
        if self.values not in ("height", "radius"):
            raise TerrainInputError(f"reference DTM {self.path}: values must be 'height' or 'radius', got {self.values!r}")
        if self.name is None:
            self.name = f"dtm {os.path.basename(os.fspath(self.path))}"

    def open(self) -> "DtmGrid":
        """The DTM's grid (label, CRS and geotransform read; no pixels yet)."""
        return DtmGrid.open(self.path, self.band, self.values)


def _isis_mapping_crs(path: str) -> tuple[str, list[float]]:
    """PROJ string and geotransform ``[a, b, c, d, e, f]`` of an ISIS cube's ``Mapping`` group."""
    from ..io import IsisCube

    cube = IsisCube(path)
    m = cube.group("Mapping")
    if m is None:
        raise DtmCrsError(f"reference DTM {path}: the ISIS cube has no Mapping group (no CRS): a DTM must be map-projected")

    def num(key: str, default: float | None = None) -> float:
        v = m.get(key, default)
        if v is None:
            raise DtmCrsError(f"reference DTM {path}: Mapping group without {key}")
        try:
            return float(v.value if hasattr(v, "value") else v)
        except (TypeError, ValueError):
            raise DtmCrsError(f"reference DTM {path}: Mapping {key} = {v!r} is not a number") from None

    proj = str(m.get("ProjectionName", "")).strip()
    a, b = num("EquatorialRadius"), num("PolarRadius")
    if abs(a - b) > 1e-6 * a:
        raise DtmCrsError(f"reference DTM {path}: Mapping is on an ellipsoid ({a} / {b} m): only Moon spheres")
    if str(m.get("LatitudeType", "Planetocentric")).lower() != "planetocentric" and abs(a - b) > 0:
        raise DtmCrsError(f"reference DTM {path}: planetographic latitudes on an ellipsoid are not supported")
    if str(m.get("LongitudeDirection", "PositiveEast")).lower() != "positiveeast":
        raise DtmCrsError(f"reference DTM {path}: LongitudeDirection must be PositiveEast")
    clon = num("CenterLongitude", 0.0)
    if proj.lower() == "equirectangular":
        clat = num("CenterLatitude", 0.0)
        crs = f"+proj=eqc +lat_ts={clat!r} +lon_0={clon!r} +R={a!r} +units=m +no_defs +type=crs"
    elif proj.lower() == "simplecylindrical":
        crs = f"+proj=eqc +lat_ts=0 +lon_0={clon!r} +R={a!r} +units=m +no_defs +type=crs"
    else:
        raise DtmCrsError(f"reference DTM {path}: ISIS projection {proj!r} is not supported "
                          "(Equirectangular, SimpleCylindrical; convert others with GDAL to a GeoTIFF)")
    res = num("PixelResolution")
    x0, y0 = num("UpperLeftCornerX"), num("UpperLeftCornerY")
    return crs, [res, 0.0, x0, 0.0, -res, y0]


class DtmGrid:
    """A reference DTM's grid: CRS, north-up geotransform, lazily read pixels (see :meth:`open`).

    Attributes
    ----------
    crs : pyproj.CRS
    radius : float
        Radius of the CRS's sphere, metres (heights are above it).
    transform : (6,) float
        ``x = c + a (col)``, ``y = f + e (row)`` of the pixel corners (GDAL / rasterio order ``a, b, c, d, e, f``).
    shape : (lines, samples)
    """

    def __init__(self, path: str, pixels, crs: pyproj.CRS, transform: Sequence[float], band: int, values: str):
        self.path = path
        self.crs = crs
        self.values = values
        self.transform = np.asarray(transform, float)
        a, b, _, d, e, _ = self.transform
        if b != 0.0 or d != 0.0 or a == 0.0 or e == 0.0:
            raise TerrainInputError(f"reference DTM {path}: a rotated or degenerate geotransform {list(transform)} "
                                    "(only north-up grids)")
        ell = crs.ellipsoid
        if ell is None:
            raise DtmCrsError(f"reference DTM {path}: its CRS has no ellipsoid")
        R, Rb = float(ell.semi_major_metre), float(ell.semi_minor_metre)
        if not (_MOON_RADIUS_RANGE[0] <= R <= _MOON_RADIUS_RANGE[1]):
            raise DtmCrsError(f"reference DTM {path}: its CRS's radius {R:.0f} m is not the Moon's "
                              f"({crs.name!r})")
        if abs(R - Rb) > 1e-6 * R:
            raise DtmCrsError(f"reference DTM {path}: its CRS is on an ellipsoid ({R} / {Rb} m): only Moon spheres")
        self.radius = R
        if pixels.ndim == 3:
            if not 1 <= band <= pixels.shape[0]:
                raise TerrainInputError(f"reference DTM {path}: band {band} of {pixels.shape[0]}")
            pixels = pixels[band - 1]
        self.pixels = pixels
        self.shape = tuple(int(v) for v in pixels.shape[-2:])
        self.geographic = bool(crs.is_geographic)
        self._to_map = None if self.geographic else pyproj.Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True)

    @classmethod
    def open(cls, path: str | os.PathLike[str], band: int = 1, values: str = "height") -> "DtmGrid":
        """Open a GeoTIFF / GDAL raster or ISIS cube DTM (label only).

        Raises
        ------
        DtmCrsError
            No CRS (a plain TIFF, a cube without ``Mapping``), or not a Moon sphere.
        TerrainInputError
            Unreadable file, rotated grid, bad band.
        """
        from ..io import open_image
        from ..io.raster import image_kind

        p = os.fspath(path)
        if not os.path.isfile(p):
            raise TerrainInputError(f"reference DTM {p} does not exist")
        try:
            pixels = open_image(p)
            kind = image_kind(p)
        except LunarmapError as err:
            raise TerrainInputError(f"reference DTM {p}: {err}") from None
        if kind == "isis":
            crs_text, transform = _isis_mapping_crs(p)
        elif kind == "gdal":
            crs_text, transform = str(pixels.attrs.get("crs", "")), list(pixels.attrs.get("transform", []))
        else:
            raise DtmCrsError(f"reference DTM {p}: a PDS3 image has no map CRS here (convert it to a GeoTIFF)")
        if not crs_text:
            raise DtmCrsError(f"reference DTM {p} has no coordinate reference system: its heights' datum and its "
                              "grid's coordinates are unknown (write it with a Moon CRS, e.g. IAU_2015:30100)")
        try:
            crs = pyproj.CRS(crs_text)
        except pyproj.exceptions.CRSError as err:
            raise DtmCrsError(f"reference DTM {p}: its CRS is not readable: {err}") from None
        return cls(p, pixels.data, crs, transform, band, values)

    # -- map coordinates ----------------------------------------------------
    def _map(self, lon: NDArray, lat: NDArray) -> tuple[NDArray, NDArray]:
        if self._to_map is None:
            return lon.copy(), lat.copy()
        x, y = self._to_map.transform(lon, lat)
        return np.asarray(x, float), np.asarray(y, float)

    def to_pixel(self, lon: NDArray, lat: NDArray) -> tuple[NDArray, NDArray]:
        """Fractional (col, row) of pixel centres (centre of pixel 0 at 0.0) at ``lon, lat`` degrees."""
        x, y = self._map(lon, lat)
        a, _, c, _, e, f = self.transform
        return (x - c) / a - 0.5, (y - f) / e - 0.5

    def map_partials(self, lon: NDArray, lat: NDArray) -> NDArray:
        """``d(col, row) / d(lon, lat)`` per radian, ``(n, 2, 2)``."""
        a, e = self.transform[0], self.transform[4]
        J = np.zeros((lon.size, 2, 2))
        if self._to_map is None:
            deg = 180.0 / np.pi
            J[:, 0, 0] = deg / a
            J[:, 1, 1] = deg / e
            return J
        h = _PROJ_STEP_DEG
        for k, (dl, dp) in enumerate(((h, 0.0), (0.0, h))):
            xp, yp = self._map(lon + dl, lat + dp)
            xm, ym = self._map(lon - dl, lat - dp)
            scale = 180.0 / np.pi / (2.0 * h)
            J[:, 0, k] = (xp - xm) * scale / a
            J[:, 1, k] = (yp - ym) * scale / e
        return J

    def read_window(self, col: NDArray, row: NDArray, margin: int = _MARGIN_PX) -> "DtmWindow":
        """The pixels around fractional pixel positions (their bounding box plus ``margin``), read once."""
        ok = np.isfinite(col) & np.isfinite(row)
        nl, ns = self.shape
        if not ok.any():
            return DtmWindow(self, 0, 0, np.full((0, 0), np.nan))
        c0 = int(np.clip(np.floor(col[ok].min()) - margin, 0, ns))
        c1 = int(np.clip(np.ceil(col[ok].max()) + margin + 1, 0, ns))
        r0 = int(np.clip(np.floor(row[ok].min()) - margin, 0, nl))
        r1 = int(np.clip(np.ceil(row[ok].max()) + margin + 1, 0, nl))
        if c1 <= c0 or r1 <= r0:
            return DtmWindow(self, 0, 0, np.full((0, 0), np.nan))
        z = np.asarray(self.pixels[r0:r1, c0:c1], dtype=float)
        if self.values == "radius":
            z = z - self.radius
        return DtmWindow(self, r0, c0, z)


class DtmWindow:
    """Heights of a window of a :class:`DtmGrid`, bilinear with analytic gradient."""

    def slope(self, lon: NDArray, lat: NDArray, baseline_m: float) -> NDArray:
        """``dh/d(lon, lat)`` per radian ``(n, 2)`` from the heights ``baseline_m`` metres apart (central
        differences east-west and north-south on the CRS's sphere; NaN where one of them is)."""
        lon = np.atleast_1d(np.asarray(lon, float))
        lat = np.atleast_1d(np.asarray(lat, float))
        dlat = 0.5 * baseline_m / self.grid.radius                           # radians
        dlon = dlat / np.maximum(np.cos(np.radians(lat)), 1e-6)
        he, _ = self.sample(lon + np.degrees(dlon), lat)
        hw, _ = self.sample(lon - np.degrees(dlon), lat)
        hn, _ = self.sample(lon, lat + np.degrees(dlat))
        hs, _ = self.sample(lon, lat - np.degrees(dlat))
        return np.column_stack([(he - hw) / (2.0 * dlon), (hn - hs) / (2.0 * dlat)])

    def __init__(self, grid: DtmGrid, r0: int, c0: int, z: NDArray):
        self.grid, self.r0, self.c0 = grid, r0, c0
        self.z = np.ascontiguousarray(z, float)

    def sample(self, lon: NDArray, lat: NDArray) -> tuple[NDArray, NDArray]:
        """Heights (metres; NaN outside the window or next to a NaN node) and ``dh/d(lon, lat)`` per radian ``(n, 2)``."""
        lon = np.atleast_1d(np.asarray(lon, float))
        lat = np.atleast_1d(np.asarray(lat, float))
        col, row = self.grid.to_pixel(lon, lat)
        col, row = col - self.c0, row - self.r0
        nr, nc = self.z.shape
        h = np.full(lon.size, np.nan)
        g = np.full((lon.size, 2), np.nan)
        if nr < 2 or nc < 2:
            return h, g
        inside = (col >= 0) & (col <= nc - 1) & (row >= 0) & (row <= nr - 1)
        j = np.clip(np.floor(np.where(inside, col, 0)).astype(np.int64), 0, nc - 2)
        i = np.clip(np.floor(np.where(inside, row, 0)).astype(np.int64), 0, nr - 2)
        v, u = col - j, row - i
        z = self.z
        z00, z01, z10, z11 = z[i, j], z[i, j + 1], z[i + 1, j], z[i + 1, j + 1]
        hh = (1 - u) * ((1 - v) * z00 + v * z01) + u * ((1 - v) * z10 + v * z11)
        dcol = (1 - u) * (z01 - z00) + u * (z11 - z10)
        drow = (1 - v) * (z10 - z00) + v * (z11 - z01)
        J = self.grid.map_partials(lon, lat)
        grad = np.column_stack([dcol * J[:, 0, 0] + drow * J[:, 1, 0], dcol * J[:, 0, 1] + drow * J[:, 1, 1]])
        good = inside & np.isfinite(hh)
        h[good] = hh[good]
        g[good] = grad[good]
        return h, g


def point_height(X: NDArray, radius: float) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Planetocentric ``lon, lat`` (degrees), height ``|X| - radius`` and the partials ``(n, 3, 3)`` of
    ``(lon, lat, |X|)`` (radians, metres) w.r.t. ``X`` (metres)."""
    X = np.asarray(X, float).reshape(-1, 3)
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    r2 = rho2 + z * z
    r = np.sqrt(r2)
    lon = np.degrees(np.arctan2(y, x))
    lat = np.degrees(np.arctan2(z, rho))
    D = np.zeros((X.shape[0], 3, 3))
    D[:, 0, 0], D[:, 0, 1] = -y / rho2, x / rho2
    D[:, 1, 0], D[:, 1, 1], D[:, 1, 2] = -x * z / (r2 * rho), -y * z / (r2 * rho), rho / r2
    D[:, 2] = X / r[:, None]
    return lon, lat, r - radius, D


class DtmHeights:
    """The observation term of one reference DTM: one scalar row per observed point.

    A term of :class:`~lunarmap.adjust.problem.BundleProblem` that observes points only
    (``uses_points``): :meth:`linearize` takes the points and returns the whitened residuals, a
    zero Jacobian on the reduced unknowns and the whitened partials ``(m, 3)`` w.r.t. the points
    :attr:`point_index`. Build it with :func:`dtm_heights`.

    Attributes
    ----------
    name : str
        Observation-group name (its own variance component, :attr:`variance_group`).
    point_index : (m,) int
        The observed points.
    sigma : float
        A-priori sigma of every row, metres.
    skipped : int
        Candidate points that got no observation (outside the grid or on NaN nodes).
    lost : int
        Rows whose point was outside the window / on a NaN cell at the last linearisation (zero row).
    slope_baseline : float or None
        Baseline of the partials' slope, metres (:class:`ReferenceDtm`); None: the cell's gradient.
    """

    uses_points = True
    variance_group = True
    n_extra = 0

    def __init__(self, window: DtmWindow, point_index: NDArray, sigma: float, n_cam_red: int, name: str,
                 skipped: int = 0, point_ids: NDArray | None = None, slope_baseline: float | None = None):
        self.window = window
        self.point_index = np.asarray(point_index, np.int64)
        self.sigma = float(sigma)
        self.n_cam_red = int(n_cam_red)
        self.name = name
        self.skipped = int(skipped)
        self.lost = 0
        self.point_ids = point_ids
        self.slope_baseline = None if slope_baseline is None else float(slope_baseline)
        self._n_img = 0

    @property
    def n_obs_scalar(self) -> int:
        return int(self.point_index.size)

    @property
    def radius(self) -> float:
        return self.window.grid.radius

    def initial_extra(self) -> NDArray:
        return np.zeros(0)

    def extra_free(self) -> NDArray[np.bool_]:
        return np.zeros(0, bool)

    def observed_images(self) -> NDArray[np.bool_]:
        return np.zeros(self._n_img, bool)

    def residuals_m(self, points: NDArray) -> NDArray:
        """Point height minus DTM height, metres (NaN where the point left the DTM)."""
        X = np.asarray(points, float)[self.point_index]
        lon, lat, h, _ = point_height(X, self.radius)
        hd, _ = self.window.sample(lon, lat)
        return h - hd

    def linearize(self, cam_params: NDArray, extra: NDArray, points: NDArray):
        """Whitened residuals ``(m,)``, their (zero) Jacobian on the reduced unknowns and partials ``(m, 3)`` on the points."""
        X = np.asarray(points, float)[self.point_index]
        lon, lat, h, D = point_height(X, self.radius)
        hd, g = self.window.sample(lon, lat)
        ok = np.isfinite(hd)
        self.lost = int(np.sum(~ok))
        if self.slope_baseline is not None:
            gb = self.window.slope(lon, lat, self.slope_baseline)
            # near the window's edge the baseline leaves the grid: the cell's gradient there
            g = np.where(np.isfinite(gb), gb, g)
        r = np.where(ok, (h - np.where(ok, hd, 0.0)) / self.sigma, 0.0)
        # d v / d X = d|X|/dX - dh/dlon dlon/dX - dh/dlat dlat/dX
        a = D[:, 2] - np.where(ok[:, None], g, 0.0)[:, 0:1] * D[:, 0] - np.where(ok[:, None], g, 0.0)[:, 1:2] * D[:, 1]
        Jp = np.where(ok[:, None], a / self.sigma, 0.0)
        J = sp.csr_matrix((self.point_index.size, self.n_cam_red + self.n_extra))
        return r, J, Jp


def dtm_heights(dtm: ReferenceDtm, points: NDArray, n_cam_red: int, n_images: int,
                candidates: NDArray | None = None, point_ids: NDArray | None = None) -> DtmHeights:
    """The :class:`DtmHeights` term of ``dtm`` for the block's points.

    Parameters
    ----------
    dtm : ReferenceDtm
    points : (n_pt, 3)
        Start values of the points, body-fixed metres.
    n_cam_red : int
        Image parameters of the block (``n_images * n_params``).
    n_images : int
    candidates : (n_pt,) bool, optional
        Points that may get an observation (default all).
    point_ids : (n_pt,) optional
        Point names, for reports.

    Raises
    ------
    DtmCrsError, TerrainInputError
        See :meth:`DtmGrid.open`.
    DtmCoverageError
        No candidate point lies inside the DTM on finite heights.
    """
    grid = dtm.open()
    X = np.asarray(points, float)
    cand = np.ones(X.shape[0], bool) if candidates is None else np.asarray(candidates, bool)
    idx = np.flatnonzero(cand & np.all(np.isfinite(X), axis=1))
    lon, lat, _, _ = point_height(X[idx], grid.radius)
    col, row = grid.to_pixel(lon, lat)
    nl, ns = grid.shape
    inside = (col >= 0) & (col <= ns - 1) & (row >= 0) & (row <= nl - 1)
    window = grid.read_window(col[inside], row[inside])
    hd, _ = window.sample(lon, lat)
    ok = np.isfinite(hd)
    if not ok.any():
        where = "outside its grid" if not inside.any() else "on NaN heights (holes / nodata)"
        raise DtmCoverageError(f"reference DTM {grid.path} covers none of the block's {idx.size} candidate point(s): "
                               f"they are all {where}")
    term = DtmHeights(window, idx[ok], dtm.sigma_m, n_cam_red, str(dtm.name), skipped=int(idx.size - ok.sum()),
                      point_ids=None if point_ids is None else np.asarray(point_ids)[idx[ok]],
                      slope_baseline=dtm.slope_baseline_m)
    term._n_img = int(n_images)
    return term

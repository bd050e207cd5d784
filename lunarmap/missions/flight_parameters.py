"""Ranger flight-parameter tables: one row per photo, as JPL listed them (``seeds/000``, "Flight parameters").

Table format (CSV with a header row, or netCDF with a ``photo`` dimension)
--------------------------------------------------------------------------
=========  ======  =========================================================================
column     unit    meaning
=========  ======  =========================================================================
photo      --      photo (frame) identifier, unique
LATs       deg     planetocentric latitude (north positive) of the sub-spacecraft point
LONs       deg     longitude (east positive) of the sub-spacecraft point
LATp       deg     latitude of the lunar principal point (camera axis meets the sphere)
LONp       deg     longitude of the lunar principal point
R          m       lunar centre to camera
Range      m       camera to lunar principal point along the camera axis
Alt        m       camera to sub-spacecraft point
AZN        deg     clockwise angle in the photo from +y to lunar north
AZSC       deg     counterclockwise angle in the photo from +y to the nadir end of the principal line
et         s       optional: exposure time, TDB seconds past J2000
utc        --      optional: exposure time, UTC (ISO 8601)
=========  ======  =========================================================================

Column names are matched case-insensitively; ``AZS/C`` is accepted for ``AZSC``. Lines starting
with ``#`` in a CSV file are comments; a comment ``# radius_m = <value>`` sets the sphere radius
(default 1736.6 km, the historical lunar radius the paper used). Latitudes and longitudes are in
lunarmap's body-fixed frame (north, east); listings in south latitude or west longitude must be
negated (:func:`lunarmap.missions.ranger.paper_to_body_fixed` converts the paper's ``X'Y'Z'``).

On reading, every row is checked; an unusable table raises
:class:`~lunarmap.errors.FlightParameterError` naming the file, photo and column: missing columns,
non-numbers, ``|LAT| > 90``, a camera at or below the sphere, ``Range < Alt`` (the nearest surface
point is straight below) or ``Range`` beyond the horizon. :meth:`FlightParameters.check_consistency`
compares the redundant columns (``LATp``, ``LONp``, ``Alt``) with the orientation of the others.
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..atomic import atomic_write
from ..errors import FlightParameterError, GeometryError
from .five_rotations import orientation_angles, sensor_to_body, tilt_from_ranges

__all__ = ["COLUMNS", "DEFAULT_RADIUS", "FlightParameters", "read_flight_parameters",
           "flight_parameters_from_orientation"]

#: Required numeric columns, in file order.
COLUMNS = ("LATs", "LONs", "LATp", "LONp", "R", "Range", "Alt", "AZN", "AZSC")
UNITS = {"LATs": "degrees_north", "LONs": "degrees_east", "LATp": "degrees_north", "LONp": "degrees_east",
         "R": "m", "Range": "m", "Alt": "m", "AZN": "degrees", "AZSC": "degrees", "et": "s"}
#: The lunar radius of the Ranger reductions, metres.
DEFAULT_RADIUS = 1736600.0
_ALIASES = {"azs/c": "AZSC", "azs_c": "AZSC"}


def _canonical(name: str) -> str:
    key = name.strip().lower()
    if key in _ALIASES:
        return _ALIASES[key]
    for c in COLUMNS + ("photo", "et", "utc"):
        if c.lower() == key:
            return c
    return name.strip()


@dataclass(frozen=True, eq=False)
class FlightParameters:
    """A flight-parameter table (module docstring); arrays of one value per photo.

    Build it with :func:`read_flight_parameters`, :meth:`from_columns` or
    :func:`flight_parameters_from_orientation`; the constructor checks every row.
    """

    photo: tuple[str, ...]
    LATs: NDArray[np.float64]
    LONs: NDArray[np.float64]
    LATp: NDArray[np.float64]
    LONp: NDArray[np.float64]
    R: NDArray[np.float64]
    Range: NDArray[np.float64]
    Alt: NDArray[np.float64]
    AZN: NDArray[np.float64]
    AZSC: NDArray[np.float64]
    et: NDArray[np.float64] | None = None
    utc: tuple[str, ...] | None = None
    radius: float = DEFAULT_RADIUS
    source: str = ""
    attrs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = f"flight parameters {self.source}".rstrip()
        photo = tuple(str(p) for p in self.photo)
        object.__setattr__(self, "photo", photo)
        n = len(photo)
        if n == 0:
            raise FlightParameterError(f"{where}: no photos")
        if len(set(photo)) != n:
            dup = sorted({p for p in photo if photo.count(p) > 1})
            raise FlightParameterError(f"{where}: photo ids repeat: {', '.join(dup[:5])}")
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise FlightParameterError(f"{where}: radius must be a positive number of metres, got {self.radius!r}")
        for c in COLUMNS + ("et",):
            v = getattr(self, c)
            if v is None:
                continue
            arr = np.asarray(v, dtype=float).reshape(-1)
            if arr.size != n:
                raise FlightParameterError(f"{where}: column {c} has {arr.size} values for {n} photos")
            bad = ~np.isfinite(arr)
            if bad.any():
                raise FlightParameterError(f"{where}: photo {photo[int(np.argmax(bad))]}: column {c} is not a finite "
                                           "number")
            object.__setattr__(self, c, arr)
        if self.utc is not None:
            object.__setattr__(self, "utc", tuple(str(u) for u in self.utc))
            if len(self.utc) != n:
                raise FlightParameterError(f"{where}: column utc has {len(self.utc)} values for {n} photos")
        self._check_geometry(where)

    def _first(self, mask: NDArray[np.bool_]) -> int | None:
        return int(np.argmax(mask)) if np.any(mask) else None

    def _check_geometry(self, where: str) -> None:
        r0 = self.radius
        horizon = np.sqrt(np.maximum(self.R ** 2 - r0 ** 2, 0.0))
        checks = [
            (np.abs(self.LATs) > 90.0, lambda i: f"|LATs| = {abs(self.LATs[i]):.6g} deg exceeds 90"),
            (np.abs(self.LATp) > 90.0, lambda i: f"|LATp| = {abs(self.LATp[i]):.6g} deg exceeds 90"),
            (self.R <= r0, lambda i: f"R = {self.R[i]:.1f} m puts the camera at or below the {r0:.1f} m sphere"),
            (self.Range <= 0, lambda i: f"Range = {self.Range[i]:.1f} m is not positive"),
            (self.Alt <= 0, lambda i: f"Alt = {self.Alt[i]:.1f} m is not positive"),
            (self.Range < self.Alt, lambda i: f"Range {self.Range[i]:.1f} m is shorter than the altitude Alt "
                                              f"{self.Alt[i]:.1f} m: impossible (the nearest surface point is the "
                                              "sub-spacecraft point)"),
            (self.Range < (self.R - r0) * (1 - 1e-12),
             lambda i: f"Range {self.Range[i]:.1f} m is shorter than the altitude R - radius = "
                       f"{self.R[i] - r0:.1f} m above the {r0:.1f} m sphere: impossible"),
            (self.Range > horizon * (1 + 1e-12),
             lambda i: f"Range {self.Range[i]:.1f} m exceeds the distance to the horizon of the {r0:.1f} m "
                       f"sphere ({horizon[i]:.1f} m): the camera axis would meet the far side"),
        ]
        for mask, message in checks:
            i = self._first(mask)
            if i is not None:
                raise FlightParameterError(f"{where}: photo {self.photo[i]}: {message(i)}")

    # -- construction ----------------------------------------------------------------------------
    @classmethod
    def from_columns(cls, columns: Mapping[str, Any], radius: float = DEFAULT_RADIUS, source: str = "",
                     attrs: Mapping[str, Any] | None = None) -> "FlightParameters":
        """Build from a mapping of column name -> values (names as in the module docstring).

        Raises
        ------
        FlightParameterError
            Missing columns (all are named), non-numbers, impossible geometry.
        """
        cols = {_canonical(str(k)): v for k, v in columns.items()}
        missing = [c for c in ("photo",) + COLUMNS if c not in cols]
        where = f"flight parameters {source}".rstrip()
        if missing:
            raise FlightParameterError(f"{where}: missing column(s) {', '.join(missing)}; a table needs "
                                       f"{', '.join(('photo',) + COLUMNS)}")
        values: dict[str, Any] = {}
        photos = [str(p) for p in np.atleast_1d(np.asarray(cols["photo"], dtype=object))]
        for c in COLUMNS + ("et",):
            if c not in cols:
                continue
            raw = np.atleast_1d(np.asarray(cols[c], dtype=object))
            out = np.empty(raw.size)
            for i, v in enumerate(raw):
                try:
                    out[i] = float(v)
                except (TypeError, ValueError):
                    who = photos[i] if i < len(photos) else f"row {i + 1}"
                    raise FlightParameterError(f"{where}: photo {who}: column {c} = {v!r} is not a number") from None
            values[c] = out
        utc = tuple(str(u) for u in np.atleast_1d(np.asarray(cols["utc"], dtype=object))) if "utc" in cols else None
        return cls(photo=tuple(photos), utc=utc, radius=float(radius), source=source, attrs=dict(attrs or {}), **values)

    @classmethod
    def from_orientation(cls, photo: Sequence[str], position: ArrayLike, sensor_rotation: ArrayLike,
                         radius: float = DEFAULT_RADIUS, et: ArrayLike | None = None) -> "FlightParameters":
        """The flight parameters of known orientations (exact inverse of :meth:`sensor_rotations`).

        Parameters
        ----------
        photo : sequence of str
            Photo ids.
        position : array_like (n, 3)
            Camera positions, body-fixed, metres.
        sensor_rotation : array_like (n, 3, 3)
            Sensor frame (boresight +z, lunarmap convention) to body-fixed.
        radius : float
            Sphere of the principal points, metres.
        et : array_like (n,), optional
            Exposure times, TDB seconds past J2000.
        """
        ang = orientation_angles(position, sensor_rotation, radius)
        cols: dict[str, Any] = {"photo": list(photo), **{c: ang[c] for c in COLUMNS}}
        if et is not None:
            cols["et"] = np.asarray(et, float)
        return cls.from_columns(cols, radius=radius, source="(from orientation)")

    # -- derived ---------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.photo)

    def index(self, photo: str) -> int:
        """Row of a photo id; :class:`FlightParameterError` when absent."""
        try:
            return self.photo.index(str(photo))
        except ValueError:
            raise FlightParameterError(f"flight parameters {self.source}: no photo {photo!r}") from None

    @property
    def tilt(self) -> NDArray[np.float64]:
        """Tilt ``t`` of each camera axis from the vertical, degrees (from ``R``, ``Range`` and the radius)."""
        try:
            return tilt_from_ranges(self.R, self.Range, self.radius)
        except GeometryError as err:
            raise FlightParameterError(f"flight parameters {self.source}: {err}") from None

    @property
    def positions(self) -> NDArray[np.float64]:
        """Camera positions ``(n, 3)``, body-fixed metres, from ``LATs``, ``LONs`` and ``R``."""
        lat, lon = np.radians(self.LATs), np.radians(self.LONs)
        return self.R[:, None] * np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])

    def sensor_rotations(self) -> NDArray[np.float64]:
        """Sensor frame (boresight +z) to body-fixed rotations ``(n, 3, 3)`` by the five rotations."""
        return sensor_to_body(self.AZN, self.AZSC, self.tilt, self.LATs, self.LONs)

    def check_consistency(self, tolerance_deg: float = 0.01, altitude_tolerance: float | None = None) -> xr.Dataset:
        """Compare the redundant columns with the orientation the others give.

        ``LATp``/``LONp`` are compared with the principal point of the five-rotation orientation, and
        (when ``altitude_tolerance`` is given, metres) ``Alt`` with ``R - radius``.

        Returns
        -------
        xarray.Dataset
            ``principal_point_error`` (photo) degrees of arc, ``altitude_error`` (photo) metres.

        Raises
        ------
        FlightParameterError
            A difference beyond its tolerance; the photo and the size are named.
        """
        ang = orientation_angles(self.positions, self.sensor_rotations(), self.radius)
        def unit(lat: NDArray[np.float64], lon: NDArray[np.float64]) -> NDArray[np.float64]:
            la, lo = np.radians(lat), np.radians(lon)
            return np.column_stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])

        u, v = unit(self.LATp, self.LONp), unit(ang["LATp"], ang["LONp"])
        pp = np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.einsum("ni,ni->n", u, v)))
        alt = self.Alt - (self.R - self.radius)
        where = f"flight parameters {self.source}".rstrip()
        i = self._first(pp > tolerance_deg)
        if i is not None:
            raise FlightParameterError(f"{where}: photo {self.photo[i]}: LATp/LONp lie {pp[i]:.4g} deg from the "
                                       "principal point of the orientation that LATs, LONs, R, Range, AZN and AZSC "
                                       f"give (tolerance {tolerance_deg} deg)")
        i = self._first(np.abs(alt) > altitude_tolerance) if altitude_tolerance is not None else None
        if i is not None:
            raise FlightParameterError(f"{where}: photo {self.photo[i]}: Alt differs from R - radius by "
                                       f"{alt[i]:.1f} m (tolerance {altitude_tolerance} m)")
        return xr.Dataset({"principal_point_error": ("photo", pp, {"units": "degrees"}),
                           "altitude_error": ("photo", alt, {"units": "m"})}, coords={"photo": list(self.photo)})

    # -- files -----------------------------------------------------------------------------------
    def to_dataset(self) -> xr.Dataset:
        """The table as an :class:`xarray.Dataset` (dimension ``photo``; units attributes)."""
        data: dict[str, tuple] = {c: ("photo", getattr(self, c), {"units": UNITS[c]}) for c in COLUMNS}
        if self.et is not None:
            data["et"] = ("photo", self.et, {"units": UNITS["et"], "long_name": "TDB seconds past J2000"})
        if self.utc is not None:
            data["utc"] = ("photo", np.array(self.utc, dtype=object))
        return xr.Dataset(data, coords={"photo": np.array(self.photo, dtype=object)},
                          attrs={"Conventions": "lunarmap_flight_parameters", "version": 1,
                                 "radius_m": float(self.radius), **{k: v for k, v in self.attrs.items()
                                                                     if isinstance(v, (str, int, float))}})

    def to_csv(self, path: str | os.PathLike[str]) -> Path:
        """Write the table as CSV (full float precision), atomically."""
        buf = io.StringIO()
        buf.write("# lunarmap flight parameters (Ranger paper, seeds/000); degrees and metres\n")
        buf.write(f"# radius_m = {self.radius!r}\n")
        w = csv.writer(buf, lineterminator="\n")
        extra = (["et"] if self.et is not None else []) + (["utc"] if self.utc is not None else [])
        w.writerow(["photo", *COLUMNS, *extra])
        for i, p in enumerate(self.photo):
            row = [p, *(repr(float(getattr(self, c)[i])) for c in COLUMNS)]
            if self.et is not None:
                row.append(repr(float(self.et[i])))
            if self.utc is not None:
                row.append(self.utc[i])
            w.writerow(row)
        text = buf.getvalue()
        return atomic_write(path, lambda tmp: Path(tmp).write_text(text))

    def to_netcdf(self, path: str | os.PathLike[str]) -> Path:
        """Write the table as netCDF, atomically."""
        ds = self.to_dataset()
        return atomic_write(path, lambda tmp: ds.to_netcdf(tmp))

    @classmethod
    def from_dataset(cls, ds: xr.Dataset, source: str = "") -> "FlightParameters":
        """Read a table from an :class:`xarray.Dataset` laid out as :meth:`to_dataset` writes it."""
        dim = "photo"
        cols: dict[str, Any] = {}
        if dim in ds.coords or dim in ds:
            cols["photo"] = [str(v) for v in ds[dim].values]
        for name in ds.data_vars:
            cols[str(name)] = ds[name].values
        return cls.from_columns(cols, radius=float(ds.attrs.get("radius_m", DEFAULT_RADIUS)), source=source)


def _read_csv(path: Path) -> tuple[dict[str, Any], float]:
    radius = DEFAULT_RADIUS
    lines = []
    for raw in path.read_text().splitlines():
        if raw.lstrip().startswith("#"):
            body = raw.lstrip()[1:].strip()
            if body.replace(" ", "").lower().startswith("radius_m="):
                try:
                    radius = float(body.split("=", 1)[1])
                except ValueError:
                    raise FlightParameterError(f"flight parameters {path}: malformed comment {raw!r}") from None
            continue
        if raw.strip():
            lines.append(raw)
    rows = list(csv.reader(lines))
    if not rows:
        raise FlightParameterError(f"flight parameters {path}: no header row")
    header = [h.strip() for h in rows[0]]
    cols: dict[str, list[str]] = {h: [] for h in header}
    for k, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise FlightParameterError(f"flight parameters {path}: data row {k - 1} has {len(row)} fields, the "
                                       f"header {len(header)}")
        for h, v in zip(header, row):
            cols[h].append(v.strip())
    return cols, radius


def read_flight_parameters(path: str | os.PathLike[str], radius: float | None = None) -> FlightParameters:
    """Read a flight-parameter table from CSV (``.csv``, ``.txt``) or netCDF (``.nc``).

    Parameters
    ----------
    path : path-like
        The file.
    radius : float, optional
        Sphere radius, metres; overrides the file's (default 1736.6 km).

    Raises
    ------
    FileNotFoundError
        No such file.
    FlightParameterError
        Missing columns, non-numbers, impossible geometry (the file, photo and column are named).
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"flight-parameter table {p} does not exist")
    if p.suffix.lower() in (".nc", ".nc4", ".cdf"):
        try:
            with xr.open_dataset(p) as ds:
                table = FlightParameters.from_dataset(ds.load(), source=str(p))
        except (OSError, ValueError) as err:
            raise FlightParameterError(f"flight parameters {p}: not a readable netCDF table ({err})") from None
        if radius is not None:
            table = FlightParameters.from_columns(_columns(table), radius=radius, source=str(p))
        return table
    cols, file_radius = _read_csv(p)
    return FlightParameters.from_columns(cols, radius=file_radius if radius is None else radius, source=str(p))


def _columns(t: FlightParameters) -> dict[str, Any]:
    cols: dict[str, Any] = {"photo": list(t.photo), **{c: getattr(t, c) for c in COLUMNS}}
    if t.et is not None:
        cols["et"] = t.et
    if t.utc is not None:
        cols["utc"] = list(t.utc)
    return cols


def flight_parameters_from_orientation(photo: Sequence[str], position: ArrayLike, sensor_rotation: ArrayLike,
                                       radius: float = DEFAULT_RADIUS, et: ArrayLike | None = None) -> FlightParameters:
    """:meth:`FlightParameters.from_orientation` as a function."""
    return FlightParameters.from_orientation(photo, position, sensor_rotation, radius=radius, et=et)

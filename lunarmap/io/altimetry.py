"""Laser-altimetry shot tables (LOLA RDR-like): read and write a plain CSV or netCDF table of shots.

The table has one row per shot and these columns (names exact, lower case):

==========  ==========================================================================================
column      meaning
==========  ==========================================================================================
``track``   track (orbit) identifier, any text or integer; the shots of one track share an offset and
            an optional drift (:mod:`lunarmap.adjust.altimetry`)
``time``    shot time, seconds (ephemeris time or relative to any epoch: only differences within a
            track are used)
``lon``     planetocentric longitude, degrees east (any range; -180..180 or 0..360)
``lat``     planetocentric latitude, degrees (-90..90)
``radius``  distance of the surface point from the Moon's centre, metres (LOLA RDR ``RADIUS`` is in
            kilometres: multiply by 1000)
``sigma``   optional: a-priori radial standard deviation of the shot, metres (> 0)
==========  ==========================================================================================

* CSV (``.csv``, ``.txt``): a header line with the column names, comma separated; lines starting with
  ``#`` are comments.
* netCDF (``.nc``): one dimension (any name) and the columns as variables on it (``track`` may be
  text or integer).

Bad input raises :class:`~lunarmap.errors.AltimetryInputError` naming the file and the column or the
track: a missing column, a NaN / non-finite value (with its first row), a latitude outside
[-90, 90], a radius that is not the Moon's (kilometres given as metres), a sigma <= 0, a track with
one shot (its offset would absorb the shot: no observation left). Nothing here calls SPICE.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import AltimetryInputError

__all__ = ["AltimetryShots", "read_altimetry", "write_altimetry", "ALTIMETRY_COLUMNS"]

#: required columns of a shot table, in order
ALTIMETRY_COLUMNS = ("track", "time", "lon", "lat", "radius")
#: radii a Moon shot may have, metres (the deepest basin to the highest peak, with margin)
_MOON_RADIUS_RANGE = (1.70e6, 1.78e6)


@dataclass
class AltimetryShots:
    """Laser-altimetry shots (see the module docstring for the columns).

    Attributes
    ----------
    track : (n,) str
        Track identifier of every shot.
    time : (n,) float
        Seconds.
    lon, lat : (n,) float
        Planetocentric degrees east / north.
    radius : (n,) float
        Metres from the Moon's centre.
    sigma : (n,) float or None
        Per-shot radial sigma, metres (None: the instrument's sigma is used).
    source : str
        The file read, for messages.
    """

    track: NDArray
    time: NDArray[np.float64]
    lon: NDArray[np.float64]
    lat: NDArray[np.float64]
    radius: NDArray[np.float64]
    sigma: NDArray[np.float64] | None = None
    source: str = "<memory>"

    def __post_init__(self) -> None:
        self.track = np.asarray(self.track).astype(str)
        n = self.track.size
        for name in ("time", "lon", "lat", "radius") + (("sigma",) if self.sigma is not None else ()):
            a = np.asarray(getattr(self, name), float).reshape(-1)
            if a.size != n:
                raise AltimetryInputError(f"altimetry {self.source}: column {name!r} has {a.size} values, "
                                          f"'track' has {n}")
            bad = ~np.isfinite(a)
            if bad.any():
                raise AltimetryInputError(f"altimetry {self.source}: column {name!r} has {int(bad.sum())} "
                                          f"NaN / non-finite value(s), first at row {int(np.argmax(bad))}")
            setattr(self, name, a)
        if n == 0:
            raise AltimetryInputError(f"altimetry {self.source}: no shots")
        if np.any(np.abs(self.lat) > 90.0):
            raise AltimetryInputError(f"altimetry {self.source}: latitude outside [-90, 90] degrees at row "
                                      f"{int(np.argmax(np.abs(self.lat) > 90.0))}")
        out = (self.radius < _MOON_RADIUS_RANGE[0]) | (self.radius > _MOON_RADIUS_RANGE[1])
        if out.any():
            k = int(np.argmax(out))
            raise AltimetryInputError(f"altimetry {self.source}: radius {self.radius[k]!r} at row {k} is not a Moon "
                                      "radius in metres (LOLA RDR radii are kilometres: multiply by 1000)")
        if self.sigma is not None and np.any(self.sigma <= 0):
            raise AltimetryInputError(f"altimetry {self.source}: column 'sigma' must be > 0 metres, row "
                                      f"{int(np.argmax(self.sigma <= 0))} is {self.sigma[np.argmax(self.sigma <= 0)]!r}")
        names, counts = np.unique(self.track, return_counts=True)
        if np.any(counts < 2):
            lonely = names[counts < 2]
            raise AltimetryInputError(f"altimetry {self.source}: {lonely.size} track(s) with one shot, first "
                                      f"{lonely[0]!r}: a track's offset would absorb it (drop it or merge tracks)")

    @property
    def n(self) -> int:
        return int(self.track.size)

    def tracks(self) -> NDArray:
        """The distinct track identifiers, sorted."""
        return np.unique(self.track)

    def select(self, keep: NDArray[np.bool_]) -> "AltimetryShots":
        """The shots where ``keep`` is True (validated again: a track left with one shot is an error)."""
        k = np.asarray(keep, bool)
        return AltimetryShots(self.track[k], self.time[k], self.lon[k], self.lat[k], self.radius[k],
                              None if self.sigma is None else self.sigma[k], self.source)


def _columns_from_csv(p: str) -> dict:
    import pandas as pd

    try:
        df = pd.read_csv(p, comment="#", skipinitialspace=True, dtype={"track": str})
    except (OSError, ValueError, pd.errors.ParserError) as err:
        raise AltimetryInputError(f"altimetry {p}: not a readable CSV table: {err}") from None
    df.columns = [str(c).strip() for c in df.columns]
    return {c: df[c].to_numpy() for c in df.columns}


def _columns_from_netcdf(p: str) -> dict:
    import xarray as xr

    try:
        with xr.open_dataset(p) as ds:
            out = {}
            for name in ds.variables:
                v = ds[name]
                if v.ndim != 1:
                    continue
                out[str(name)] = v.values.astype(str) if name == "track" else np.asarray(v.values)
            return out
    except (OSError, ValueError) as err:
        raise AltimetryInputError(f"altimetry {p}: not a readable netCDF table: {err}") from None


def read_altimetry(path: str | os.PathLike[str]) -> AltimetryShots:
    """Read a shot table (CSV or netCDF, by extension; see the module docstring).

    Parameters
    ----------
    path : path-like
        ``.csv`` / ``.txt`` (comma-separated with a header) or ``.nc``.

    Returns
    -------
    AltimetryShots

    Raises
    ------
    AltimetryInputError
        Missing file or column, NaN values, a track with one shot, bad latitudes, radii or sigmas.
    """
    p = os.fspath(path)
    if not os.path.isfile(p):
        raise AltimetryInputError(f"altimetry table {p} does not exist")
    ext = os.path.splitext(p)[1].lower()
    if ext in (".csv", ".txt"):
        cols = _columns_from_csv(p)
    elif ext in (".nc", ".nc4", ".cdf"):
        cols = _columns_from_netcdf(p)
    else:
        raise AltimetryInputError(f"altimetry table {p}: unknown extension {ext!r} (.csv, .txt or .nc)")
    missing = [c for c in ALTIMETRY_COLUMNS if c not in cols]
    if missing:
        raise AltimetryInputError(f"altimetry {p}: missing column(s) {', '.join(missing)} (has: "
                                  f"{', '.join(sorted(cols)) or 'none'}; needs {', '.join(ALTIMETRY_COLUMNS)})")
    try:
        num = {c: np.asarray(cols[c], float) for c in ALTIMETRY_COLUMNS[1:]}
        sigma = np.asarray(cols["sigma"], float) if "sigma" in cols else None
    except (TypeError, ValueError) as err:
        raise AltimetryInputError(f"altimetry {p}: a numeric column holds text: {err}") from None
    track = np.asarray(cols["track"]).astype(str)
    if np.any(np.char.strip(track) == "") or np.any(track == "nan"):
        raise AltimetryInputError(f"altimetry {p}: column 'track' has an empty value at row "
                                  f"{int(np.argmax((np.char.strip(track) == '') | (track == 'nan')))}")
    return AltimetryShots(track, num["time"], num["lon"], num["lat"], num["radius"], sigma, p)


def write_altimetry(path: str | os.PathLike[str], shots: AltimetryShots) -> str:
    """Write ``shots`` as a CSV (``.csv``) or netCDF (``.nc``) table that :func:`read_altimetry` reads
    (atomically: a temporary file renamed over ``path``). Returns the path."""
    import pandas as pd

    from ..atomic import atomic_write

    p = os.fspath(path)
    cols = {"track": shots.track, "time": shots.time, "lon": shots.lon, "lat": shots.lat, "radius": shots.radius}
    if shots.sigma is not None:
        cols["sigma"] = shots.sigma
    ext = os.path.splitext(p)[1].lower()
    if ext in (".csv", ".txt"):
        df = pd.DataFrame(cols)
        atomic_write(p, lambda tmp: df.to_csv(tmp, index=False, float_format="%.10g"))
    elif ext in (".nc", ".nc4", ".cdf"):
        import xarray as xr

        ds = xr.Dataset({k: ("shot", np.asarray(v)) for k, v in cols.items()},
                        attrs={"title": "laser altimetry shots", "lon_units": "degrees_east planetocentric",
                               "lat_units": "degrees_north planetocentric", "radius_units": "m", "time_units": "s"})
        atomic_write(p, lambda tmp: ds.to_netcdf(tmp, engine="netcdf4"))
    else:
        raise AltimetryInputError(f"altimetry table {p}: unknown extension {ext!r} (.csv or .nc)")
    return p

"""Laser-altimetry shots (LOLA RDR-like tracks) as observations of the terrain the tie points span (issue 30,
item 2).

The terrain surface is the triangulated surface of the tie points: a Delaunay triangulation
(:class:`scipy.spatial.Delaunay`) of their *initial* planetocentric longitudes and latitudes (local
coordinates ``(lon cos(lat_0), lat)`` about the block's centre, so that the triangles are not stretched);
its topology is fixed for the whole adjustment (a re-triangulation would make the objective jump). A shot
``k`` of track ``T`` inside triangle ``(1, 2, 3)`` observes

    v_k = sum_i b_i |X_i| + o_T + d_T (t_k - t_T) - r_k,        sigma_k^2 = sigma_shot^2 + sigma_interp^2

with ``r_k`` the shot's radius, ``o_T`` and ``d_T`` the track's radial offset (m) and optional drift (m/s,
about the mean shot time ``t_T`` of the track: they absorb the track's orbit error) and ``b_i`` the
barycentric coordinates of the shot's longitude/latitude in its triangle.

Two choices of ``b_i`` (:attr:`LaserAltimetry.slopes`):

* ``slopes=False`` (the default): ``b_i`` fixed at the points' start longitudes/latitudes; the shots observe the
  points' radii only, ``dv / dX_i = b_i d|X_i|/dX_i``. The surface is then misplaced horizontally by the
  points' horizontal corrections times its slope, which on gentle terrain is far below the interpolation error.
* ``slopes=True``: ``b_i(X)`` recomputed at every linearisation from the points' *current* longitudes /
  latitudes, so that the observed surface is the one through the points where they are and the shots observe
  horizontal moves on sloping terrain (as a reference DTM does, :mod:`lunarmap.adjust.terrain`). Moving vertex
  ``i`` horizontally with its radius moves the plane at the shot by ``-b_i g`` (``g`` the plane's gradient), so
  ``dv / dX_i = b_i (d|X_i|/dX_i - g_lon dlon_i/dX_i - g_lat dlat_i/dX_i)``. That horizontal information is only
  the terrain's where the slope times the horizontal error exceeds the interpolation error; below that it is
  the interpolation error's, and pulls the points off (measured on the test block, 50 m relief, ~8 km between
  tie points: tie points 73 m 3-D with fixed weights, 205 m with recomputed ones, errors / sigma 0.7 and 5.4).
  A shot whose triangle's vertices have moved so that it left the triangle keeps the plane's (extrapolated,
  continuous) value.

Both: ``dv / do_T = 1``, ``dv / dd_T = t_k - t_T``; all partials analytic. Each row couples three points and one track: the rows are not of the one-point kind of a
reference DTM, and a problem with them is solved on its full sparse normal equations (:mod:`.normal`); its
precision is the dense inverse of them (blocks of a few thousand unknowns; at most
``lunarmap.adjust.precision.COUPLED_DENSE_LIMIT``, else :class:`~lunarmap.errors.AdjustmentInputError`).

The interpolation error: the triangulated surface is the terrain's linear interpolant between tie points,
off by up to ``kappa h^2 / 8`` on a triangle of edge ``h`` for a terrain of curvature ``kappa`` (metres^-1);
``interpolation_sigma_m`` is added to every shot's sigma in quadrature, and the instrument's group has its
own variance component that scales both.

Datum: the offsets shift every track's radii; with every offset free (no ``offset_sigma_m``) the altimetry
observes the terrain's shape only, and the block's radius comes from the navigation observations (or control
points). Free offsets and a block without navigation or control is a datum defect
(:class:`~lunarmap.errors.DatumDefectError`). With ``offset_sigma_m`` the offsets are observed as 0 with that
sigma (LOLA's radial orbit error after the crossover adjustment, ~1 m; raw tracks: tens of metres): those
pseudo-observation rows are in no variance-component group and not w-tested.

What the shots fix, measured (``bench/altimetry_datum.py``; the test's fore/aft frame block, 2 orbits x 8 images,
no control points, per-orbit navigation errors, 24 tracks, shots 0.5 m, interpolation sigma 1 m, offsets 30 m;
a-priori covariances, as the simulation's noise is the a-priori's: the posterior ones are scaled by sigma0^2,
which the altimeter's pessimistic interpolation sigma pulls to 0.66 and would make the image-driven sigmas 1.5 x
too small; estimate the variance components instead):

* gentle terrain (50 m relief, slope 0.05 deg at the tie points' 4.6 km spacing), 24 seeds, ``slopes=False``:
  tie points' radial RMS 225 -> 12.0 m (18.8 x; predicted sigma 16.3 m), the block's orientation error at the
  check points free of their own noise (noise-free rays through the adjusted images) radial 176 -> 27.6 m
  (predicted 25.4), horizontal 111.5 -> 108.5 m (predicted 117: the navigation's), 3-D 208 -> 112 m (1.9 x).
  The check points' own 3-D RMS 268 -> 197 m (predicted 198) is their intersection's (0.3 px of a 102 m pixel,
  base/height 0.54: radial sigma 60-400 m per point), so no check point of this block can show 10 x.
* errors / sigma pooled over the 24 seeds: 0.92-1.09 for every part (check, tie, orientation; radial,
  horizontal, 3-D); per seed 0.2-2.2, with effective degrees of freedom k_eff = 2 m^2 / var of the per-seed
  mean z^2 of 1.5-1.8 (horizontal) and 3-4 (3-D): the navigation's few per-orbit draws. A per-block
  "within 1 +- 0.2" then holds with probability 0.25-0.45 (sqrt(chi2_k / k)), as measured (17-54 % of seeds).
* the track offsets' errors share the block's radius error (their common part, sigma 30 / sqrt(24) = 6.1 m,
  measured 6.6 m RMS): per block all tracks are within 2 sigma or none (23 of 24 seeds all, one none: its
  common error 2.3 sigma); pooled 95.8 %.
* steeper terrain (the sines at 2000 m relief: slope 1.8 deg; the true surface's interpolation error 39 m at
  4.6 km, 26 m at 2.3 km between tie points, given as the interpolation sigma), orientation error at the check
  points, navigation alone -> with shots (3-D / horizontal, errors / sigma horizontal):
  300 points, 4 seeds: ``slopes=False`` 123 -> 66 / 63 m (0.53); ``slopes=True`` 331 / 330 m (6.5);
  ``slopes=False`` then ``slopes=True`` from the settled points, re-triangulated: 279 / 279 m (5.5).
  1200 points, 3 seeds: ``slopes=False`` 102 -> 56 / 55 m (0.52), radial 63 -> 7.5 m (8.4 x);
  ``slopes=True`` 707 / 707 m (25); fixed then recomputed: 184 / 184 m (6.9).
  On cratered terrain (craters 2-20 km over rolling terrain: slope 28 deg RMS, interpolation error 350 m at
  2.3 km; 2 seeds) the shots fix neither radius (tie points 160 -> 148 m) nor position, and ``slopes=True``
  makes the horizontal worse (57 -> 90 m, errors / sigma 5). The horizontal datum is the navigation's in every
  regime tried: the interpolant's error is not white (it follows the terrain's curvature over whole features
  and correlates with the plane's slope), so each shot's slope row carries it as information with a sigma
  that treats it as noise. ``slopes=True`` is not recommended until the interpolation error is modelled (a
  denser surface than the tie points, e.g. a DTM, :mod:`lunarmap.adjust.terrain`).

Skipping: shots outside every triangle of the tie points get no observation and are counted
(:attr:`AltimetryObservations.skipped`); if all shots are outside,
:class:`~lunarmap.errors.AltimetryCoverageError`. A track left with fewer than two shots inside is dropped
(its offset would absorb its shot) and counted in :attr:`AltimetryObservations.dropped_tracks`. Nothing here
calls SPICE.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from ..errors import AltimetryCoverageError, AltimetryInputError
from ..io.altimetry import AltimetryShots, read_altimetry
from .terrain import point_height

__all__ = ["LaserAltimetry", "AltimetryObservations", "altimetry_observations"]


@dataclass
class LaserAltimetry:
    """Laser-altimetry shots of one instrument observing the block's terrain.

    Parameters
    ----------
    shots : AltimetryShots or path-like
        The shots, or a CSV / netCDF table of them (:func:`lunarmap.io.read_altimetry`).
    sigma_m : float
        A-priori radial standard deviation of one shot, metres (> 0); a per-shot ``sigma`` column
        replaces it.
    interpolation_sigma_m : float
        Standard deviation of the tie points' triangulated surface against the terrain at a shot, metres
        (>= 0; module docstring), added in quadrature.
    drift : bool
        Also estimate a radial drift per track (m/s).
    offset_sigma_m : float, optional
        A-priori sigma of every track's offset (observed as 0), metres; None: free offsets.
    name : str, optional
        Observation-group name (default ``"altimetry <file name>"``).
    point_types : sequence of str
        Point types spanning the surface (default tie points; check points keep their independence).
    slopes : bool
        Barycentric weights recomputed from the points' current positions, with the plane's slope in the
        partials (module docstring); default False: fixed at the start, radii only.
    """

    shots: AltimetryShots | str | os.PathLike[str]
    sigma_m: float
    interpolation_sigma_m: float = 0.0
    drift: bool = False
    offset_sigma_m: float | None = None
    name: str | None = None
    point_types: Sequence[str] = ("tie",)
    slopes: bool = False

    def __post_init__(self) -> None:
        label = self.shots.source if isinstance(self.shots, AltimetryShots) else os.fspath(self.shots)
        for key in ("sigma_m", "interpolation_sigma_m") + (("offset_sigma_m",) if self.offset_sigma_m is not None else ()):
            v = float(getattr(self, key))
            ok = v > 0 if key != "interpolation_sigma_m" else v >= 0
            if not (np.isfinite(v) and ok):
                raise AltimetryInputError(f"altimetry {label}: {key} must be finite and "
                                          f"{'>= 0' if key == 'interpolation_sigma_m' else '> 0'}, got {v!r}")
            setattr(self, key, v)
        if self.name is None:
            self.name = f"altimetry {os.path.basename(label)}"

    def load(self) -> AltimetryShots:
        """The shots (read from the table on the first call)."""
        if not isinstance(self.shots, AltimetryShots):
            self.shots = read_altimetry(self.shots)
        return self.shots


def _local(lon_deg: NDArray, lat_deg: NDArray, lon0: float, coslat0: float) -> NDArray:
    """Local planar coordinates ``((lon - lon0) cos(lat0), lat)`` in radians, ``(n, 2)``; longitudes unwrapped
    about ``lon0``."""
    dl = (np.asarray(lon_deg, float) - lon0 + 180.0) % 360.0 - 180.0
    return np.column_stack([np.radians(dl) * coslat0, np.radians(np.asarray(lat_deg, float))])


class AltimetryObservations:
    """The observation term of one altimeter's shots (rows: shots inside the triangulation, then the offset
    pseudo-observations when ``offset_sigma_m`` is given). Build it with :func:`altimetry_observations`.

    A term of :class:`~lunarmap.adjust.problem.BundleProblem` that observes points (``uses_points``) and
    couples three of them per row (``couples_points``): :meth:`linearize` returns the whitened residuals,
    the Jacobian on the reduced unknowns (the track offsets / drifts, this term's extra parameters) and the
    whitened partials ``(m, 3, 3)`` w.r.t. the points :attr:`point_index` ``(m, 3)`` of every row.

    Attributes
    ----------
    name : str
    point_index : (m, 3) int
        The triangle's points of every row (largest barycentric weight first; prior rows repeat the first
        shot's, with zero partials).
    track_names : (n_tr,) str
    track_of : (m_shots,) int
        Track of every shot row.
    dt : (m_shots,) float
        Shot time minus its track's mean shot time, seconds.
    radius : (m_shots,) float
        Observed radii, metres.
    sigma : (m,) float
        A-priori sigma of every row (shots: shot and interpolation in quadrature), metres.
    skipped : int
        Shots outside every triangle (no observation).
    dropped_tracks : int
        Tracks with fewer than two shots inside (no observation).
    shot_index : (m_shots,) int
        Row of every observed shot in the shot table.
    """

    uses_points = True
    couples_points = True
    variance_group = True

    def __init__(self, name: str, point_index: NDArray, lonlat_local: NDArray, radius: NDArray, track_of: NDArray,
                 dt: NDArray, sigma: NDArray, track_names: NDArray, drift: bool, offset_sigma: float | None,
                 n_cam_red: int, n_images: int, frame: tuple[float, float], skipped: int = 0, dropped_tracks: int = 0,
                 shot_index: NDArray | None = None):
        self.name = name
        self.shot_point_index = np.asarray(point_index, np.int64)
        self.s = np.asarray(lonlat_local, float)
        self.radius = np.asarray(radius, float)
        self.track_of = np.asarray(track_of, np.int64)
        self.dt = np.asarray(dt, float)
        self.track_names = np.asarray(track_names).astype(str)
        self.n_tracks = int(self.track_names.size)
        self.drift = bool(drift)
        self.offset_sigma = None if offset_sigma is None else float(offset_sigma)
        self.n_cam_red = int(n_cam_red)
        self._n_img = int(n_images)
        self.frame = frame
        self.skipped = int(skipped)
        self.dropped_tracks = int(dropped_tracks)
        self.shot_index = np.arange(self.radius.size) if shot_index is None else np.asarray(shot_index, np.int64)
        self.n_shots = int(self.radius.size)
        n_prior = self.n_tracks if self.offset_sigma is not None else 0
        self.sigma = np.concatenate([np.asarray(sigma, float), np.full(n_prior, self.offset_sigma or 1.0)])
        self.point_index = np.concatenate([self.shot_point_index,
                                           np.repeat(self.shot_point_index[:1], n_prior, axis=0)])
        self.n_extra = self.n_tracks * (2 if self.drift else 1)
        self.b_fixed: NDArray | None = None

    # -- the term protocol ----------------------------------------------------------------------
    @property
    def n_obs_scalar(self) -> int:
        return int(self.sigma.size)

    def initial_extra(self) -> NDArray:
        return np.zeros(self.n_extra)

    def extra_free(self) -> NDArray[np.bool_]:
        return np.ones(self.n_extra, bool)

    def observed_images(self) -> NDArray[np.bool_]:
        return np.zeros(self._n_img, bool)

    def group_rows(self) -> NDArray[np.bool_]:
        """Rows in the instrument's variance-component group and w-tested: the shots (not the offset priors)."""
        return np.arange(self.n_obs_scalar) < self.n_shots

    def rows_out(self, dropped: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Rows out of the adjustment with their points (quality control dropped them: held where they were
        left, without their rays): a shot with any dropped vertex; never an offset's pseudo-observation."""
        out = np.zeros(self.n_obs_scalar, bool)
        out[:self.n_shots] = np.any(np.asarray(dropped, bool)[self.shot_point_index], axis=1)
        return out

    def row_table(self) -> dict:
        """``kind`` of every row: 0 a shot, 1 a track offset's pseudo-observation; ``track`` its track; ``image``
        -1 (no image's row)."""
        n_prior = self.n_obs_scalar - self.n_shots
        return {"kind": np.concatenate([np.zeros(self.n_shots, np.int64), np.ones(n_prior, np.int64)]),
                "track": np.concatenate([self.track_of, np.arange(n_prior)]),
                "image": np.full(self.n_obs_scalar, -1, np.int64)}

    def row_label(self, row: int) -> str:
        """A row's name in reports: the track and the shot's row in the shot table."""
        if row >= self.n_shots:
            return f"{self.name} track {self.track_names[row - self.n_shots]} offset prior"
        return f"{self.name} track {self.track_names[self.track_of[row]]} shot {int(self.shot_index[row])}"

    def offsets(self, extra: NDArray) -> NDArray:
        """Per-track offsets (m) from this term's extra parameters."""
        return np.asarray(extra, float)[:self.n_tracks]

    def drifts(self, extra: NDArray) -> NDArray:
        """Per-track drifts (m/s); zeros without ``drift``."""
        e = np.asarray(extra, float)
        return e[self.n_tracks:2 * self.n_tracks] if self.drift else np.zeros(self.n_tracks)

    # -- model ------------------------------------------------------------------------------------
    def _surface(self, points: NDArray):
        """Interpolated radius ``f`` (m_shots,), barycentric ``b`` (m_shots, 3), plane gradient ``(g_lon, g_lat)``
        per radian (m_shots, 2) and the ``(lon, lat, r)`` partials ``D`` (m_shots, 3, 3, 3) of the vertices."""
        lon0, coslat0 = self.frame
        X = np.asarray(points, float)[self.shot_point_index]                    # (m, 3 vertices, 3)
        lon, lat, r, D = point_height(X.reshape(-1, 3), 0.0)
        P = _local(lon, lat, lon0, coslat0).reshape(-1, 3, 2)
        r = r.reshape(-1, 3)
        D = D.reshape(-1, 3, 3, 3)
        E = np.stack([P[:, 0] - P[:, 2], P[:, 1] - P[:, 2]], axis=1)           # (m, 2 edges, 2)
        det = E[:, 0, 0] * E[:, 1, 1] - E[:, 0, 1] * E[:, 1, 0]
        inv = np.empty_like(E)                                                   # inverse of E^T (columns = edges)
        inv[:, 0, 0], inv[:, 0, 1] = E[:, 1, 1] / det, -E[:, 1, 0] / det
        inv[:, 1, 0], inv[:, 1, 1] = -E[:, 0, 1] / det, E[:, 0, 0] / det
        ds = self.s - P[:, 2]
        b12 = np.einsum("mij,mj->mi", inv, ds)
        b = np.column_stack([b12, 1.0 - b12.sum(axis=1)])
        if self.b_fixed is not None:
            # radii only: the barycentric weights of the start, no slope (module docstring)
            return np.sum(self.b_fixed * r, axis=1), self.b_fixed, np.zeros((r.shape[0], 2)), D
        f = np.sum(b * r, axis=1)
        # plane gradient in local coordinates: E g = (r1 - r3, r2 - r3)
        dr = np.column_stack([r[:, 0] - r[:, 2], r[:, 1] - r[:, 2]])
        Einv = np.empty_like(E)
        Einv[:, 0, 0], Einv[:, 0, 1] = E[:, 1, 1] / det, -E[:, 0, 1] / det
        Einv[:, 1, 0], Einv[:, 1, 1] = -E[:, 1, 0] / det, E[:, 0, 0] / det
        gl = np.einsum("mij,mj->mi", Einv, dr)
        g = np.column_stack([gl[:, 0] * coslat0, gl[:, 1]])                   # per radian of lon, lat
        return f, b, g, D

    def residuals_m(self, points: NDArray, extra: NDArray) -> NDArray:
        """Shot residuals ``surface + offset + drift dt - radius``, metres (shot rows only)."""
        f, _, _, _ = self._surface(points)
        return f + self.offsets(extra)[self.track_of] + self.drifts(extra)[self.track_of] * self.dt - self.radius

    def linearize(self, cam_params: NDArray, extra: NDArray, points: NDArray):
        """Whitened residuals ``(m,)``, Jacobian on ``[images | this term's extras]`` and point partials ``(m, 3, 3)``."""
        m_s, m = self.n_shots, self.n_obs_scalar
        f, b, g, D = self._surface(points)
        e = np.asarray(extra, float)
        v = f + self.offsets(e)[self.track_of] + self.drifts(e)[self.track_of] * self.dt - self.radius
        # dv/dX_i = b_i (D_r - g_lon D_lon - g_lat D_lat)
        a = D[:, :, 2] - g[:, None, 0:1] * D[:, :, 0] - g[:, None, 1:2] * D[:, :, 1]
        Jp = np.zeros((m, 3, 3))
        Jp[:m_s] = b[:, :, None] * a / self.sigma[:m_s, None, None]
        r = np.concatenate([v, self.offsets(e)]) if m > m_s else v
        r = r / self.sigma
        rows = [np.arange(m_s)]
        cols = [self.n_cam_red + self.track_of]
        vals = [1.0 / self.sigma[:m_s]]
        if self.drift:
            rows.append(np.arange(m_s))
            cols.append(self.n_cam_red + self.n_tracks + self.track_of)
            vals.append(self.dt / self.sigma[:m_s])
        if m > m_s:
            rows.append(m_s + np.arange(self.n_tracks))
            cols.append(self.n_cam_red + np.arange(self.n_tracks))
            vals.append(1.0 / self.sigma[m_s:])
        J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(m, self.n_cam_red + self.n_extra))
        return r, J, Jp


def altimetry_observations(alt: LaserAltimetry, points: NDArray, n_cam_red: int, n_images: int,
                           candidates: NDArray | None = None) -> AltimetryObservations:
    """The :class:`AltimetryObservations` term of ``alt`` for the block's points.

    Parameters
    ----------
    alt : LaserAltimetry
    points : (n_pt, 3)
        Start values of the points, body-fixed metres (their longitudes / latitudes are triangulated).
    n_cam_red : int
        Image parameters of the block (``n_images * n_params``).
    n_images : int
    candidates : (n_pt,) bool, optional
        Points spanning the surface (default all).

    Raises
    ------
    AltimetryInputError
        Bad shot table (:func:`lunarmap.io.read_altimetry`), fewer than three spanning points.
    AltimetryCoverageError
        No shot inside the tie points' triangulation (or no track with two shots inside).
    """
    from scipy.spatial import Delaunay, QhullError

    shots = alt.load()
    X = np.asarray(points, float)
    cand = np.ones(X.shape[0], bool) if candidates is None else np.asarray(candidates, bool)
    idx = np.flatnonzero(cand & np.all(np.isfinite(X), axis=1))
    if idx.size < 3:
        raise AltimetryInputError(f"{alt.name}: {idx.size} point(s) of types {tuple(alt.point_types)} span no surface "
                                  "(needs >= 3)")
    lon, lat, _, _ = point_height(X[idx], 0.0)
    # the block's centre: mean direction (no wrap at +-180)
    c = X[idx].mean(axis=0)
    lon0 = float(np.degrees(np.arctan2(c[1], c[0])))
    lat0 = float(np.degrees(np.arctan2(c[2], np.hypot(c[0], c[1]))))
    frame = (lon0, float(np.cos(np.radians(lat0))))
    P = _local(lon, lat, *frame)
    try:
        tri = Delaunay(P)
    except QhullError as err:
        raise AltimetryInputError(f"{alt.name}: the points cannot be triangulated (collinear?): {err}") from None
    S = _local(shots.lon, shots.lat, *frame)
    simplex = tri.find_simplex(S)
    inside = simplex >= 0
    if not inside.any():
        raise AltimetryCoverageError(f"{alt.name}: none of the {shots.n} shots lies inside the triangulation of the "
                                     f"block's {idx.size} points (the tracks miss the block)")
    # tracks with fewer than two shots inside: no observation (the offset would absorb the shot)
    tr_names, tr_of = np.unique(shots.track, return_inverse=True)
    n_in = np.bincount(tr_of[inside], minlength=tr_names.size)
    keep_tr = n_in >= 2
    use = inside & keep_tr[tr_of]
    if not use.any():
        raise AltimetryCoverageError(f"{alt.name}: no track has two shots inside the block's triangulation")
    k = np.flatnonzero(use)
    verts = tri.simplices[simplex[k]]                                          # (m, 3) into idx
    T = tri.transform[simplex[k]]
    b12 = np.einsum("mij,mj->mi", T[:, :2], S[k] - T[:, 2])
    b = np.column_stack([b12, 1.0 - b12.sum(axis=1)])
    order = np.argsort(-b, axis=1)                                              # largest weight first
    verts = np.take_along_axis(verts, order, axis=1)
    remap = -np.ones(tr_names.size, np.int64)
    remap[keep_tr] = np.arange(int(keep_tr.sum()))
    track = remap[tr_of[k]]
    t = shots.time[k]
    t0 = np.bincount(track, weights=t) / np.bincount(track)
    sig_shot = np.full(k.size, alt.sigma_m) if shots.sigma is None else shots.sigma[k]
    sigma = np.sqrt(sig_shot ** 2 + float(alt.interpolation_sigma_m) ** 2)
    term = AltimetryObservations(str(alt.name), idx[verts], S[k], shots.radius[k], track, t - t0[track], sigma,
                                 tr_names[keep_tr], alt.drift, alt.offset_sigma_m, n_cam_red, n_images, frame,
                                 skipped=int(np.sum(~inside)), dropped_tracks=int(np.sum(~keep_tr & (n_in > 0))),
                                 shot_index=k)
    if not alt.slopes:
        term.b_fixed = np.take_along_axis(b, order, axis=1)
    return term

"""Push-frame camera model (LRO WAC): an image stacked from short framelets, each a frame exposure.

Layout and timing (usgscsm ``UsgsAstroPushFrameSensorModel``)
-------------------------------------------------------------
A framelet is ``h = (framelet_height - num_lines_overlap) // line_summing`` image lines. Image line
``L`` (CSM convention) lies in framelet ``k = floor(L / h)`` (clipped to the image's framelets, so
the bottom edge ``L = n_lines`` belongs to the last one) at framelet line ``l = L - k h``, mirrored
to ``h - l`` when the framelets are flipped; ``num_lines_overlap // 2`` image lines are added before
it meets the detector, as usgscsm does. Framelet ``k`` is exposed at the mid-exposure time
``t_first + j * interframe_delay`` with ``j = k``, or ``j = n - 1 - k`` when the framelet order is
reversed. Within a framelet the geometry is a frame camera's: the framelet line is a detector
position (``image_to_focal`` with the starting detector line of the filter), not a time.

Ground to image
---------------
Neighbouring framelets may see the same ground point (the WAC's framelets overlap). The point is given to
the framelet whose projection falls closest to the framelet's centre line (usgscsm's rule), and the
projection in that framelet gives the pixel. For all points at once: the signed distance of the
undistorted projection to the centre line at a coarse subset of framelets (a few dozen) brackets
the point, linear interpolation in the bracket gives a first framelet, its neighbours are compared
until the closest one is found (usgscsm's choice). Where the exact, distorted projection falls outside
that framelet (strong distortion near a framelet edge), the neighbour that contains it is taken instead:
usgscsm keeps its choice there and returns a pixel of another ground point. Unlike usgscsm's ``groundToImage``,
flipped framelets are mirrored back (usgscsm leaves them mirrored, which its image-to-ground
direction does not).

Points not seen: behind the camera, hidden by the body, outside the image when ``within_image``,
and (when ``within_image``) points whose closest framelet still has them beyond its edges, i.e. in
a gap between framelets that do not overlap.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidInputError
from ..orientation.exterior import ExteriorOrientation
from ..orientation.isd_kinds import PushFrameTiming
from .corrections import PushFrameCorrections, _pixel_affine
from .frame import _CameraModel, _check_ground_on_miss, _finite_pixels, _finite_xyz
from .interior import InteriorOrientation
from .intersect import OnMiss
from .shape import Shape

__all__ = ["FrameletTiming", "PushFrameCamera"]

Array = NDArray[np.float64]
#: ``vectors(points (n, 3), exposure indices (n,)) -> sensor-frame vectors (n, 3)``
VectorFn = Callable[[NDArray[np.float64], NDArray[np.intp]], NDArray[np.float64]]

_COARSE = 33        # framelets sampled to bracket a ground point
_MAX_SHIFT = 8      # neighbour comparisons before a point is given up (never reached on smooth orbits)
_EDGE = 1e-9        # lines: a projection this close to a framelet's edge is on it


@dataclass(frozen=True)
class FrameletTiming:
    """When and where each framelet is, relative to the camera's exterior orientation.

    Parameters
    ----------
    t_first : float
        Mid-exposure time of the first exposed framelet, s after ``eo.epoch`` (usgscsm:
        ``starting_ephemeris_time + exposure_duration / 2``).
    interframe_delay : float
        Seconds between framelet exposures.
    framelet_height : int
        Detector lines per framelet, before summing.
    framelets_flipped, framelet_order_reversed : bool
        See :class:`~lunarmap.orientation.isd_kinds.PushFrameTiming`.
    num_lines_overlap : int
        Detector lines shared by neighbouring framelets.
    exposure_duration : float
        Framelet exposure, s (kept for writing the ISD back).
    """

    t_first: float
    interframe_delay: float
    framelet_height: int
    framelets_flipped: bool = False
    framelet_order_reversed: bool = False
    num_lines_overlap: int = 0
    exposure_duration: float = 0.0

    @classmethod
    def from_isd(cls, timing: PushFrameTiming, start: float) -> "FrameletTiming":
        """From an ISD's framelet keys; ``start`` is ``starting_ephemeris_time`` relative to ``eo.epoch``."""
        return cls(t_first=float(start) + 0.5 * timing.exposure_duration,
                   interframe_delay=float(timing.interframe_delay), framelet_height=int(timing.framelet_height),
                   framelets_flipped=bool(timing.framelets_flipped),
                   framelet_order_reversed=bool(timing.framelet_order_reversed),
                   num_lines_overlap=int(timing.num_lines_overlap),
                   exposure_duration=float(timing.exposure_duration))


class PushFrameCamera(_CameraModel):
    """A push-frame camera: framelets of a few lines, each exposed at once, stacked into one image.

    Parameters
    ----------
    interior : InteriorOrientation
        Camera constants of the filter (focal length, focal plane, starting detector line of the filter,
        summing, distortion).
    eo : ExteriorOrientation
        Trajectory and attitude covering the framelet times.
    shape : Shape, optional
        Body shape; the Moon sphere by default.
    timing : FrameletTiming
        Framelet layout and times.

    Raises
    ------
    InvalidInputError
        The image is not a whole number of framelets, or the framelet layout is impossible.
    """

    def __init__(self, interior: InteriorOrientation, eo: ExteriorOrientation, shape: Shape | None = None,
                 timing: FrameletTiming | None = None) -> None:
        super().__init__(interior, eo, shape)
        if not isinstance(timing, FrameletTiming):
            raise InvalidInputError("a push-frame camera needs its FrameletTiming")
        reduced = timing.framelet_height - timing.num_lines_overlap
        if timing.framelet_height < 1 or reduced < 1 or reduced % interior.line_summing:
            raise InvalidInputError(f"framelets of {timing.framelet_height} detector lines with "
                                    f"{timing.num_lines_overlap} overlapping are not whole image lines at "
                                    f"line summing {interior.line_summing}")
        self.timing = timing
        self.framelet_lines = reduced // interior.line_summing
        if interior.n_lines % self.framelet_lines:
            raise InvalidInputError(f"{interior.n_lines} image lines are not a whole number of framelets of "
                                    f"{self.framelet_lines} lines")
        self.n_framelets = interior.n_lines // self.framelet_lines
        if not (np.isfinite(timing.interframe_delay) and timing.interframe_delay > 0.0):
            raise InvalidInputError(f"interframe delay must be positive, got {timing.interframe_delay!r}")
        self._offset = float(timing.num_lines_overlap // 2)  # usgscsm: int / 2, in image lines
        self._A, self._b = _pixel_affine(interior)
        j = np.arange(self.n_framelets)
        self.framelet_times = timing.t_first + j * timing.interframe_delay   # by exposure index j
        self._positions = eo.position_at(self.framelet_times)
        self._rotations = eo.rotation_at(self.framelet_times)                # sensor -> body per exposure
        for a in (self.framelet_times, self._positions, self._rotations):
            a.setflags(write=False)

    def __repr__(self) -> str:
        return (f"PushFrameCamera({self.interior.name or 'unnamed'}, {self.n_framelets} framelets of "
                f"{self.framelet_lines} lines, {self.distortion!r})")

    @property
    def center_time(self) -> float:
        """Mid-exposure time of the middle framelet, ephemeris seconds (TDB past J2000)."""
        return float(self.eo.epoch + 0.5 * (self.framelet_times[0] + self.framelet_times[-1]))

    def corrections(self, degree: int | None = 1) -> "Any":
        """Position/attitude correction polynomials of ``degree`` (0-2) in framelet time.

        See :class:`~lunarmap.camera.corrections.PushFrameCorrections`; ``None`` means degree 1.
        """
        return PushFrameCorrections(self, 1 if degree is None else degree)

    # -- layout ------------------------------------------------------------
    def framelet_of_line(self, line: ArrayLike) -> tuple[NDArray[np.intp], NDArray[np.intp], Array]:
        """Image framelet ``k``, exposure index ``j`` and detector-side framelet line of image lines.

        The framelet line is what meets the detector: mirrored for flipped framelets and shifted by
        half the overlap (image lines).
        """
        line = np.asarray(line, dtype=float)
        h = self.framelet_lines
        k = np.clip(np.floor(line / h), 0, self.n_framelets - 1).astype(np.intp)
        fl = line - k * h
        if self.timing.framelets_flipped:
            fl = h - fl
        return k, self.exposure_index(k), np.asarray(fl + self._offset, dtype=np.float64)

    def exposure_index(self, k: ArrayLike) -> NDArray[np.intp]:
        """Exposure order of image framelets ``k`` (reversed images expose their last framelet first)."""
        k = np.asarray(k, dtype=np.intp)
        return self.n_framelets - 1 - k if self.timing.framelet_order_reversed else k

    def image_line(self, j: ArrayLike, detector_line: ArrayLike) -> Array:
        """Image line of a detector-side framelet line seen in the framelet of exposure index ``j``."""
        fl = np.asarray(detector_line, dtype=float) - self._offset
        h = float(self.framelet_lines)
        if self.timing.framelets_flipped:
            fl = h - fl
        k = self.exposure_index(j)
        # a projection on a framelet's edge, within rounding, is given a line of that framelet: the edge line
        # k h belongs to framelet k, the next one's top edge to framelet k + 1 (image_to_ground's floor)
        fl = np.where((fl < 0.0) & (fl >= -_EDGE), 0.0, fl)
        last = k == self.n_framelets - 1
        upper = (fl >= h) & (fl <= h + _EDGE) & ~last
        return np.where(upper, np.nextafter((k + 1) * h, 0.0), k * h + fl)

    def image_time(self, line: ArrayLike) -> Array:
        """Mid-exposure time (s after ``eo.epoch``) of the framelets of image lines."""
        _, j, _ = self.framelet_of_line(line)
        return np.asarray(self.framelet_times[j], dtype=np.float64)

    def sensor_position(self, line: ArrayLike, sample: ArrayLike) -> Array:
        """Sensor position (metres, body-fixed) at the exposure of image coordinates; shape ``(..., 3)``."""
        line, sample = _finite_pixels(line, sample)
        _, j, _ = self.framelet_of_line(line)
        return self._positions[j]

    # -- image to ground ---------------------------------------------------
    def _rays(self, line: Array, sample: Array) -> tuple[Array, Array]:
        _, j, fl = self.framelet_of_line(line)
        look_s = self._sensor_look(fl, sample)
        look = np.einsum("...ij,...j->...i", self._rotations[j], look_s)
        look /= np.linalg.norm(look, axis=-1, keepdims=True)
        return self._positions[j].copy(), look

    # -- ground to image ---------------------------------------------------
    def _sensor_vectors(self, g: Array, j: NDArray[np.intp]) -> Array:
        """Sensor-frame vectors from the framelets ``j`` exposure positions to points ``g`` (row by row)."""
        return np.einsum("nji,nj->ni", self._rotations[j], g - self._positions[j])

    def _centre_distance(self, g: Array, j: NDArray[np.intp], vectors: VectorFn | None = None) -> Array:
        """Undistorted detector-side framelet line minus the framelet's centre line (usgscsm's choice)."""
        v = (vectors or self._sensor_vectors)(g, j)
        f = self.interior.focal_length
        with np.errstate(divide="ignore", invalid="ignore"):
            front = v[:, 2] * f > 0.0
            ux = np.where(front, f * v[:, 0] / v[:, 2], np.nan)
            uy = np.where(front, f * v[:, 1] / v[:, 2], np.nan)
        line = self._A[0, 0] * ux + self._A[0, 1] * uy + self._b[0]
        return line - self._offset - 0.5 * self.framelet_lines

    def closest_framelets(self, g: Array, vectors: VectorFn | None = None) -> NDArray[np.intp]:
        """Exposure index of the framelet whose centre line is closest to each point ``(n, 3)``; -1 if none.

        ``vectors(g, j)``, optional, gives the sensor-frame vectors of points ``g`` seen from framelets ``j``
        (row by row) in place of the camera's own: the corrections choose framelets by the same rule.
        """
        def cd(pts: Array, jj: NDArray[np.intp]) -> Array:
            return self._centre_distance(pts, jj, vectors)

        n_f = self.n_framelets
        coarse = np.unique(np.round(np.linspace(0, n_f - 1, min(n_f, _COARSE))).astype(np.intp))
        m = g.shape[0]
        dist = np.stack([cd(g, np.full(m, c, dtype=np.intp)) for c in coarse], axis=1)
        with np.errstate(invalid="ignore"):
            change = (dist[:, :-1] * dist[:, 1:] <= 0.0) if coarse.size > 1 else np.zeros((m, 0), dtype=bool)
        has = change.any(axis=1)
        k = np.argmax(change, axis=1) if coarse.size > 1 else np.zeros(m, dtype=np.intp)
        absd = np.where(np.isfinite(dist), np.abs(dist), np.inf)
        best_coarse = np.argmin(absd, axis=1)
        start = coarse[best_coarse].astype(float)
        if coarse.size > 1:
            da, db = dist[np.arange(m), k], dist[np.arange(m), np.minimum(k + 1, coarse.size - 1)]
            ca, cb = coarse[k].astype(float), coarse[np.minimum(k + 1, coarse.size - 1)].astype(float)
            with np.errstate(divide="ignore", invalid="ignore"):
                interp = ca + (cb - ca) * da / (da - db)
            start = np.where(has & np.isfinite(interp), interp, start)
        best = np.clip(np.round(start), 0, n_f - 1).astype(np.intp)
        no_view = ~np.isfinite(absd).any(axis=1)
        # walk to the neighbour with the smaller distance until neither neighbour is closer
        d0 = np.abs(cd(g, best))
        act = np.flatnonzero(~no_view)
        for _ in range(_MAX_SHIFT):
            if act.size == 0:
                break
            jb = best[act]
            lo, hi = np.maximum(jb - 1, 0), np.minimum(jb + 1, n_f - 1)
            dl = np.abs(cd(g[act], lo))
            dh = np.abs(cd(g[act], hi))
            cur = d0[act]
            cur = np.where(np.isfinite(cur), cur, np.inf)
            go_lo = np.isfinite(dl) & (dl < cur) & ~(np.isfinite(dh) & (dh < dl))
            go_hi = np.isfinite(dh) & (dh < cur) & ~go_lo
            best[act] = np.where(go_lo, lo, np.where(go_hi, hi, jb))
            d0[act] = np.where(go_lo, dl, np.where(go_hi, dh, cur))
            act = act[go_lo | go_hi]
        best[no_view | ~np.isfinite(d0)] = -1
        return self._exact_choice(g, best, vectors)

    def _detector_lines(self, g: Array, j: NDArray[np.intp], vectors: VectorFn | None = None
                        ) -> tuple[Array, Array, NDArray[np.bool_]]:
        """Distorted detector-side framelet line, sample and validity of points ``g`` in framelets ``j``."""
        return self._project((vectors or self._sensor_vectors)(g, j))

    def _exact_choice(self, g: Array, best: NDArray[np.intp], vectors: VectorFn | None = None) -> NDArray[np.intp]:
        """Keep usgscsm's (undistorted) choice unless the exact, distorted projection leaves that framelet;
        then the neighbour whose exact projection is inside and closest to its centre line.

        Where distortion is strong (the WAC UV's 2.6 % radial term shifts its framelets' lines by ~0.3 image
        lines) the undistorted choice can be a framelet that sees the point just beyond its edge; usgscsm
        then returns a line in the neighbour framelet's image lines, whose image-to-ground is another point.
        """
        idx = np.flatnonzero(best >= 0)
        if idx.size == 0:
            return best
        h, tol = float(self.framelet_lines), 1e-9
        line, _, ok = self._detector_lines(g[idx], best[idx], vectors)
        fl = line - self._offset
        out_of = ~ok | (fl < -tol) | (fl > h + tol)
        fix = idx[out_of]
        if fix.size == 0:
            return best
        cand = np.clip(best[fix][:, None] + np.array([-1, 0, 1])[None, :], 0, self.n_framelets - 1)
        dist = np.empty(cand.shape)
        for c in range(3):
            lc, _, okc = self._detector_lines(g[fix], cand[:, c], vectors)
            flc = lc - self._offset
            inside = okc & (flc >= -tol) & (flc <= h + tol)
            dist[:, c] = np.where(inside, np.abs(flc - 0.5 * h), np.inf)
        pick = np.argmin(dist, axis=1)
        found = np.isfinite(dist[np.arange(fix.size), pick])
        out = best.copy()
        out[fix] = np.where(found, cand[np.arange(fix.size), pick], best[fix])
        return out

    def ground_to_image(self, xyz: ArrayLike, on_miss: OnMiss = "nan",
                        within_image: bool = True) -> tuple[Array, Array]:
        """Image coordinates of body-fixed ground points.

        Parameters
        ----------
        xyz : array_like, shape (..., 3)
            Ground points, metres, body-fixed.
        on_miss : {"nan", "raise"}
            Points not seen (module docstring): NaN coordinates, or
            :class:`~lunarmap.errors.GeometryError`.
        within_image : bool
            Treat coordinates outside the image, or outside their framelet (a gap between framelets),
            as not seen.

        Returns
        -------
        line, sample : ndarray, shape (...)
            Image coordinates, pixels (CSM convention).
        """
        _check_ground_on_miss(on_miss)
        xyz = _finite_xyz(xyz)
        shape = xyz.shape[:-1]
        g = np.ascontiguousarray(xyz.reshape(-1, 3))
        j = self.closest_framelets(g)
        line = np.full(g.shape[0], np.nan)
        sample = np.full(g.shape[0], np.nan)
        ok = j >= 0
        idx = np.flatnonzero(ok)
        if idx.size:
            jj = j[idx]
            det_line, smp, valid = self._project(self._sensor_vectors(g[idx], jj))
            line[idx] = self.image_line(jj, det_line)
            sample[idx] = smp
            valid &= ~self._occluded(self._positions[jj], g[idx])
            if within_image:
                fl = det_line - self._offset
                valid &= (fl >= -1e-6) & (fl <= self.framelet_lines + 1e-6)
            ok[idx] = valid
        line, sample = self._finish_ground_to_image(line, sample, ok, within_image, on_miss)
        return line.reshape(shape), sample.reshape(shape)


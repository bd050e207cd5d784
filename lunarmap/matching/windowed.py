"""Images the matcher samples anywhere but reads only by window: pixels of images of any size.

A :class:`WindowedImage` stands where the matcher used to take a whole image in memory: the
resamplers (:func:`~lunarmap.matching.resample.bilinear`, :func:`~lunarmap.matching.resample.bicubic`,
:func:`~lunarmap.matching.resample.bicubic_with_gradient`) ask it for the smallest region holding
every stencil of a call (:meth:`WindowedImage.region`), sample that region, and give exactly what
they give on the whole image (the region's edges are the image's wherever the image ends, and
interior edges lie beyond every stencil, so even the clamps and the NaN propagation are the same).
Invalid and saturated pixels become NaN as :func:`~lunarmap.matching.pairs.as_array` makes them;
least-squares matching's Gaussian pre-smoothing (:meth:`WindowedImage.smoothed`) is computed on
each region with an apron of the filter's radius, so the smoothed values are those of the
smoothed whole image (with numba only in the tiles of the region that the callers' stencils read:
``need`` of :meth:`WindowedImage.region`). Pixels held in memory without an invalid pixel are read
as views, neither copied nor cached. Pyramid levels come from a stored :class:`~lunarmap.io.pyramid.Pyramid`
or, without one, are block means of the cached regions of the level above (the same values as
``build_pyramid``'s; issue 32, item 5: not each level's regions reduced again from level 0).

Regions are kept in one least-recently-used cache per process, bounded in bytes
(:data:`CACHE_BYTES`, settable with :func:`set_cache_bytes`): a worker that matches many pairs of
many full-size images holds at most that much pixel data, whatever the images' size or number.
"""

from __future__ import annotations

import functools
import itertools
import threading
from collections import OrderedDict
from typing import Any, Sequence, cast

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidInputError
from ..io.pyramid import Pyramid, pyramid_shapes
from ..io.window import WindowSource, open_source

try:  # optional: smoothed regions computed tile by tile where they are read (issue 32, item 5)
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

__all__ = ["WindowedImage", "windowed_pyramid", "CACHE_BYTES", "set_cache_bytes", "cache_info", "spatial_order"]

Array = NDArray[np.float64]

#: Bytes of pixel regions a process keeps (all images, levels and smoothings together). 64 MB holds a
#: pair's working set: on a full-size NAC-like pair, 64 MB instead of 256 MB gave the same matches
#: (639 of 846), 17 % faster, and a worker peak of 0.99 GB instead of 1.32 GB.
CACHE_BYTES = 64 << 20
#: Extra pixels read around a region, so the next, slightly moved request (an LSM iteration) hits.
_PAD = 16
_TRUNCATE = 4.0          # scipy.ndimage.gaussian_filter's default


class _RegionCache:
    """Least-recently-used regions of every windowed image of the process, bounded in bytes."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = int(max_bytes)
        # arrays, or smoothed regions filled on demand (_Smoothed): anything with nbytes
        self.entries: OrderedDict[tuple[int, int, int, int, int], Any] = OrderedDict()
        self.by_owner: dict[int, list[tuple[int, int, int, int, int]]] = {}
        self.nbytes = 0
        self.hits = self.misses = 0
        self.lock = threading.Lock()

    def find(self, owner: int, l0: int, l1: int, s0: int, s1: int) -> tuple[tuple[int, int, int, int], Any] | None:
        with self.lock:
            for key in self.by_owner.get(owner, ()):
                _, a0, a1, b0, b1 = key
                if a0 <= l0 and l1 <= a1 and b0 <= s0 and s1 <= b1:
                    self.entries.move_to_end(key)
                    self.hits += 1
                    return (a0, a1, b0, b1), self.entries[key]
            self.misses += 1
            return None

    def put(self, owner: int, bounds: tuple[int, int, int, int], data: Any) -> None:
        key = (owner, *bounds)
        with self.lock:
            if key in self.entries:
                return
            self.entries[key] = data
            self.by_owner.setdefault(owner, []).append(key)
            self.nbytes += data.nbytes
            while self.nbytes > self.max_bytes and len(self.entries) > 1:
                old, arr = self.entries.popitem(last=False)
                self.by_owner[old[0]].remove(old)
                if not self.by_owner[old[0]]:
                    del self.by_owner[old[0]]
                self.nbytes -= arr.nbytes

    def drop(self, owner: int) -> None:
        with self.lock:
            for key in self.by_owner.pop(owner, []):
                self.nbytes -= self.entries.pop(key).nbytes


_CACHE = _RegionCache(CACHE_BYTES)
_OWNER = itertools.count(1)


def set_cache_bytes(n: int) -> None:
    """Bound the process's region cache (bytes; 0 disables caching)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise InvalidInputError(f"cache size must be an integer >= 0 bytes, got {n!r}")
    with _CACHE.lock:
        _CACHE.max_bytes = int(n)
    if n == 0:
        for owner in list(_CACHE.by_owner):
            _CACHE.drop(owner)


def cache_info() -> dict[str, int]:
    """The region cache's ``bytes``, ``max_bytes``, ``regions``, ``hits`` and ``misses``."""
    with _CACHE.lock:
        return {"bytes": _CACHE.nbytes, "max_bytes": _CACHE.max_bytes, "regions": len(_CACHE.entries),
                "hits": _CACHE.hits, "misses": _CACHE.misses}


class WindowedImage:
    """One level of an image, sampled by the resamplers through regions read by window (module docstring).

    Parameters
    ----------
    source : WindowSource, path-like or array_like
        The level's pixels (:func:`lunarmap.io.window.open_source`).
    saturation : float, optional
        Grey level from which pixels are invalid (NaN), as in :func:`~lunarmap.matching.pairs.as_array`;
        applied to level 0 only (stored and derived pyramid levels are made from masked pixels).
    smooth : float
        Sigma (pixels) of the Gaussian pre-smoothing of least-squares matching; 0 for raw pixels.
    pyramid : Pyramid, optional
        Stored pyramid levels of this image (level 0 only).
    factor : int
        Level of this image in its pyramid (``2^level`` image pixels per pixel); internal.
    """

    def __init__(self, source: Any, saturation: float | None = None, smooth: float = 0.0,
                 pyramid: Pyramid | None = None, *, _base: "WindowedImage | None" = None, _level: int = 0,
                 _parent: "WindowedImage | None" = None) -> None:
        self.source: WindowSource = open_source(source)
        self.shape = cast("tuple[int, int]", tuple(int(v) for v in self.source.shape))    # 2-D sources
        self.name = getattr(self.source, "name", "image")
        self.saturation = saturation
        self.smooth = float(smooth)
        if not (np.isfinite(self.smooth) and self.smooth >= 0.0):
            raise InvalidInputError(f"smoothing sigma must be >= 0 pixels, got {smooth}")
        self.stored = pyramid
        self._base = _base                # derived level: block means of the base image's regions
        self._level = int(_level)
        # derived level: the unsmoothed level above it, whose cached regions it reduces by one step
        self._parent = _parent
        self._owner = next(_OWNER)
        self.ndim = 2
        # the smoothed images and pyramids made of this one, kept: each is a region-cache owner of its own, so
        # a pair matched after another of this image reads their cached regions instead of the file again
        # (a worker's pairs share their images); they hold no pixels outside the cache (bounded in bytes)
        self._made: dict[tuple[str, float], Any] = {}

    # -- what the resamplers call ------------------------------------------------------------
    @property
    def fills_on_demand(self) -> bool:
        """Whether :meth:`region` computes only the pixels of its ``need`` boxes (a smoothed image, with numba)."""
        return self.smooth > 0.0 and _smooth_tiles_kernel is not None

    def region(self, l0: int, l1: int, s0: int, s1: int, need: NDArray[np.int64] | None = None) -> Array:
        """Pixels ``[l0, l1) x [s0, s1)`` (inside the image), invalid ones NaN, smoothed if so made.

        A view into a cached region: do not write into it. ``need``: boxes ``(k, 4)`` of
        ``[line0, line1) x [sample0, sample1)`` (image pixels) holding every pixel the caller will read;
        an image that :attr:`fills_on_demand` computes only those (the others are undefined), every
        other image ignores it.
        """
        h, w = self.shape
        if not (0 <= l0 < l1 <= h and 0 <= s0 < s1 <= w):
            raise InvalidInputError(f"{self.name}: region lines [{l0}, {l1}) samples [{s0}, {s1}) is outside the "
                                    f"{h} x {w} image")
        if self.smooth <= 0.0:
            view = self._view(l0, l1, s0, s1)
            if view is not None:        # pixels in memory, none invalid: no copy, nothing cached
                return view
        hit = _CACHE.find(self._owner, l0, l1, s0, s1) if _CACHE.max_bytes else None
        if hit is None:
            bounds = (max(l0 - _PAD, 0), min(l1 + _PAD, h), max(s0 - _PAD, 0), min(s1 + _PAD, w))
            data: Any = self._lazy(*bounds) if self.fills_on_demand else self._compute(*bounds)
            if isinstance(data, np.ndarray):
                data.setflags(write=False)
            if _CACHE.max_bytes:
                _CACHE.put(self._owner, bounds, data)
        else:
            bounds, data = hit
        a0, _, b0, _ = bounds
        if isinstance(data, _Smoothed):
            box = np.array([[l0, l1, s0, s1]], dtype=np.int64) if need is None else need
            out = data.fill(box)[l0 - a0:l1 - a0, s0 - b0:s1 - b0]
            out.flags.writeable = False
            return out
        return data[l0 - a0:l1 - a0, s0 - b0:s1 - b0]

    def _lazy(self, l0: int, l1: int, s0: int, s1: int) -> "_Smoothed":
        """The smoothed region ``[l0, l1) x [s0, s1)``, still empty: :meth:`_Smoothed.fill` computes its tiles."""
        r = int(_TRUNCATE * self.smooth + 0.5)
        h, w = self.shape
        a0, a1, b0, b1 = max(l0 - r, 0), min(l1 + r, h), max(s0 - r, 0), min(s1 + r, w)
        view = self._view(a0, a1, b0, b1)
        raw = self._raw(a0, a1, b0, b1) if view is None else view
        # NaN-aware (normalised) smoothing where the region's pixels hold a NaN, as lsm._smooth decides
        normalized = view is None and not bool(np.isfinite(raw).all())
        return _Smoothed(raw, (a0, b0), (l0, l1, s0, s1), _gauss_weights(self.smooth), normalized,
                         owns_raw=view is None)

    def _compute(self, l0: int, l1: int, s0: int, s1: int) -> Array:
        if self.smooth <= 0.0:
            return self._raw(l0, l1, s0, s1)
        # smoothed values of the whole image: the filter's reach around the region, cut off after
        r = int(_TRUNCATE * self.smooth + 0.5)
        h, w = self.shape
        a0, a1, b0, b1 = max(l0 - r, 0), min(l1 + r, h), max(s0 - r, 0), min(s1 + r, w)
        from .lsm import _smooth

        sm = _smooth(self._raw(a0, a1, b0, b1), self.smooth)
        return np.ascontiguousarray(sm[l0 - a0:l1 - a0, s0 - b0:s1 - b0])

    def _view(self, l0: int, l1: int, s0: int, s1: int) -> Array | None:
        """Raw pixels as a read-only view of a source in memory that has no invalid pixel, else ``None``."""
        if self._base is not None:
            return None
        view = getattr(self.source, "view", None)
        return None if view is None else view(l0, l1, s0, s1, self.saturation if self._level == 0 else None)

    def _raw(self, l0: int, l1: int, s0: int, s1: int) -> Array:
        if self._base is not None:
            return self._derived(l0, l1, s0, s1)
        v = self._view(l0, l1, s0, s1)
        if v is not None:
            return v
        a = self.source.read(l0, l1, s0, s1)
        if self._level == 0:
            bad = ~np.isfinite(a)
            if self.saturation is not None:
                with np.errstate(invalid="ignore"):
                    bad |= a >= self.saturation
            if bad.any():
                a[bad] = np.nan
        return a

    def _derived(self, l0: int, l1: int, s0: int, s1: int) -> Array:
        """Level-k pixels as block means of the base image's aligned ``2^k`` blocks (build_pyramid's values).

        With the level above (``_parent``): one 2 x 2 reduction of its region, read through the region
        cache, so a region of level k-1 that the search has just read is not read and reduced again
        from level 0 (k reductions of ``4^k`` times the pixels). The same arithmetic either way: block
        means of block means, in the same order.
        """
        if self._parent is not None:
            return _reduce(self._parent.region(2 * l0, 2 * l1, 2 * s0, 2 * s1))
        f = 2 ** self._level
        a = self._base._raw(l0 * f, l1 * f, s0 * f, s1 * f)  # type: ignore[union-attr]
        for _ in range(self._level):
            a = _reduce(a)
        return a

    # -- derived images ----------------------------------------------------------------------
    def smoothed(self, sigma: float) -> "WindowedImage":
        """The same image smoothed by a Gaussian of ``sigma`` pixels (NaN-aware, as least-squares matching's)."""
        if sigma == self.smooth:
            return self
        key = ("smoothed", float(sigma))
        made = self._made.get(key)
        if made is None:
            made = self._made[key] = WindowedImage(self.source, self.saturation, sigma, self.stored, _base=self._base,
                                                   _level=self._level, _parent=self._parent)
        return made

    def pyramid(self, levels: int) -> list["WindowedImage"]:
        """``[level 0 (this image), level 1, ...]``, at most ``levels`` reductions (``build_pyramid``'s rule)."""
        if self._level != 0:
            raise InvalidInputError("pyramid() is asked of level 0")
        key = ("pyramid", float(levels))
        made = self._made.get(key)
        if made is not None:
            return list(made)
        out = [self]
        shapes = pyramid_shapes(self.shape, levels)
        # each derived level reduces the raw (unsmoothed) level above it
        above: WindowedImage | None = self if self.smooth == 0.0 else self.smoothed(0.0)
        for k, (h, w) in enumerate(shapes, start=1):
            if self.stored is not None and k <= self.stored.levels:
                lev = WindowedImage(self.stored.level(k), None, 0.0, _level=k)
            else:
                lev = WindowedImage(_Shape((h, w), f"{self.name} level {k}"), None, 0.0, _base=self, _level=k,
                                    _parent=above)
            out.append(lev)
            # a stored level's pixels are as stored (perhaps rounded): levels under it reduce level 0
            above = lev if lev._parent is not None else None
        self._made[key] = tuple(out)
        return out

    def __del__(self) -> None:
        try:
            _CACHE.drop(self._owner)
        except Exception:  # pragma: no cover - interpreter shutdown
            pass

    # pickling: the source and settings, not the cache
    def __getstate__(self) -> dict[str, Any]:
        return {"source": self.source, "saturation": self.saturation, "smooth": self.smooth, "stored": self.stored,
                "base": self._base, "level": self._level, "parent": self._parent}

    def __setstate__(self, st: dict[str, Any]) -> None:
        self.__init__(st["source"], st["saturation"], st["smooth"], st["stored"], _base=st["base"],  # type: ignore[misc]
                      _level=st["level"], _parent=st.get("parent"))

    def __repr__(self) -> str:
        extra = f", level {self._level}" if self._level else ""
        extra += f", smoothed {self.smooth:g} px" if self.smooth else ""
        return f"WindowedImage({self.name!r}, {self.shape[0]} x {self.shape[1]}{extra})"


#: Side of the tiles in which a smoothed region is computed on demand, pixels. On the NAC-like pair 8 smoothed
#: 1.4 Mpx where 16 smoothed 2.3 and 32 4.5 (the lines' pass of a tile runs over ``2 x radius`` more columns,
#: 2x for sigma 1 at 8: still the least work), in 0.6x the time of 16.
_TILE = 8


@functools.lru_cache(maxsize=8)
def _gauss_weights(sigma: float) -> Array:
    """``scipy.ndimage.gaussian_filter1d``'s weights for ``sigma`` (its default truncation), centre first."""
    r = int(_TRUNCATE * sigma + 0.5)
    x = np.arange(-r, r + 1)
    phi = np.exp(-0.5 / (sigma * sigma) * x ** 2)
    w = (phi / phi.sum())[::-1]
    out = np.ascontiguousarray(w[r:])        # symmetric: the centre and the weights at +-1 .. +-r
    out.setflags(write=False)
    return out


class _Smoothed:
    """A region of a smoothed image whose pixels are computed tile by tile as callers need them.

    Least-squares matching reads ~24 x 24 pixels around each of a batch's matches, and the region
    holding a batch's windows is 10-25 times larger (issue 32, item 5: on a full-size NAC-like pair the
    smoothing of whole regions was a fifth of the time). :meth:`fill` smooths the tiles of
    :data:`_TILE` pixels that the callers' boxes touch, once, with the arithmetic of
    ``scipy.ndimage.gaussian_filter`` (``mode="nearest"``, lines first, symmetric weights folded: the
    same values bit for bit), and NaN-aware as :func:`lunarmap.matching.lsm._smooth` where the region's
    pixels hold a NaN.
    """

    def __init__(self, raw: Array, raw_origin: tuple[int, int], bounds: tuple[int, int, int, int],
                 weights: Array, normalized: bool, owns_raw: bool) -> None:
        l0, l1, s0, s1 = bounds
        self.raw, self.raw_origin, self.origin = raw, raw_origin, (l0, s0)
        self.weights, self.normalized = weights, normalized
        # pages of untouched tiles are never written (nor, for large regions, given memory by the system)
        self.data = np.empty((l1 - l0, s1 - s0))
        self.done = np.zeros((-(-(l1 - l0) // _TILE), -(-(s1 - s0) // _TILE)), dtype=np.bool_)
        self.nbytes = self.data.nbytes + self.done.nbytes + (raw.nbytes if owns_raw else 0)
        self.lock = threading.Lock()

    def fill(self, boxes: NDArray[np.int64]) -> Array:
        """The region's array with every pixel of ``boxes`` (image pixels, ``(k, 4)``) computed."""
        with self.lock:     # a tile is marked done before it is computed: no other thread may read it meanwhile
            _smooth_tiles_kernel(self.raw, self.raw_origin[0], self.raw_origin[1], self.data, self.origin[0],
                                 self.origin[1], self.done, _TILE, np.ascontiguousarray(boxes, dtype=np.int64),
                                 self.weights, self.normalized)
        return self.data


def _smooth_tiles_py(raw: Array, ro: int, co: int, out: Array, oo: int, po: int, done: NDArray[np.bool_], T: int,
                     boxes: NDArray[np.int64], c: Array, norm: bool) -> None:
    """Smooth the tiles of ``out`` (image pixels from ``(oo, po)``) that ``boxes`` touch and ``done`` does not mark.

    ``raw`` holds the image pixels from ``(ro, co)`` over ``out`` and the filter's reach around it (cut off at
    the image's edges, where the nearest pixel is repeated); ``c`` the weights, centre first. Per output
    pixel the lines' pass, then the samples' pass of ``scipy.ndimage.correlate1d`` for a symmetric kernel:
    ``c[0] x[0] + sum_{k=r..1} (x[-k] + x[k]) c[k]``, in this order (the loops run over pixels innermost,
    so they vectorise; each pixel's sum is unchanged). With ``norm``, NaN pixels weigh 0, the sum is
    divided by the sum of the weights of the valid pixels, and NaN pixels stay NaN.
    """
    R = c.size - 1
    rh, rw = raw.shape
    oh, ow = out.shape
    wt = T + 2 * R
    tmpn = np.empty((T, wt))
    tmpd = np.empty((T, wt))
    rown = np.empty(T)
    rowd = np.empty(T)
    for bi in range(boxes.shape[0]):
        l0 = max(boxes[bi, 0] - oo, 0)
        l1 = min(boxes[bi, 1] - oo, oh)
        s0 = max(boxes[bi, 2] - po, 0)
        s1 = min(boxes[bi, 3] - po, ow)
        if l0 >= l1 or s0 >= s1:
            continue
        for ti in range(l0 // T, (l1 - 1) // T + 1):
            for tj in range(s0 // T, (s1 - 1) // T + 1):
                if done[ti, tj]:
                    continue
                done[ti, tj] = True
                r0 = ti * T
                r1 = min(r0 + T, oh)
                c0 = tj * T
                c1 = min(c0 + T, ow)
                nc = c1 - c0
                # raw columns of the tile and the filter's reach (``first`` of them at tmp column ``lead``);
                # beyond the image's edge the edge column is repeated
                want = po + c0 - R - co
                q0 = max(want, 0)
                q1 = min(po + c1 + R - co, rw)
                nq = q1 - q0
                lead = q0 - want
                for i in range(r0, r1):
                    y = oo + i - ro
                    t = i - r0
                    # the lines' pass
                    if norm:
                        for q in range(nq):
                            g = raw[y, q0 + q]
                            fin = np.isfinite(g)
                            tmpn[t, lead + q] = (g if fin else 0.0) * c[0]
                            tmpd[t, lead + q] = (1.0 if fin else 0.0) * c[0]
                        for k in range(R, 0, -1):
                            ya = max(y - k, 0)
                            yb = min(y + k, rh - 1)
                            ck = c[k]
                            for q in range(nq):
                                ga = raw[ya, q0 + q]
                                gb = raw[yb, q0 + q]
                                fa = np.isfinite(ga)
                                fb = np.isfinite(gb)
                                tmpn[t, lead + q] += ((ga if fa else 0.0) + (gb if fb else 0.0)) * ck
                                tmpd[t, lead + q] += ((1.0 if fa else 0.0) + (1.0 if fb else 0.0)) * ck
                    else:
                        for q in range(nq):
                            tmpn[t, lead + q] = raw[y, q0 + q] * c[0]
                        for k in range(R, 0, -1):
                            ya = max(y - k, 0)
                            yb = min(y + k, rh - 1)
                            ck = c[k]
                            for q in range(nq):
                                tmpn[t, lead + q] += (raw[ya, q0 + q] + raw[yb, q0 + q]) * ck
                    for q in range(lead):
                        tmpn[t, q] = tmpn[t, lead]
                        tmpd[t, q] = tmpd[t, lead]
                    for q in range(lead + nq, nc + 2 * R):
                        tmpn[t, q] = tmpn[t, lead + nq - 1]
                        tmpd[t, q] = tmpd[t, lead + nq - 1]
                    # the samples' pass
                    for j in range(nc):
                        rown[j] = tmpn[t, R + j] * c[0]
                    for k in range(R, 0, -1):
                        ck = c[k]
                        for j in range(nc):
                            rown[j] += (tmpn[t, R + j - k] + tmpn[t, R + j + k]) * ck
                    if norm:
                        for j in range(nc):
                            rowd[j] = tmpd[t, R + j] * c[0]
                        for k in range(R, 0, -1):
                            ck = c[k]
                            for j in range(nc):
                                rowd[j] += (tmpd[t, R + j - k] + tmpd[t, R + j + k]) * ck
                        for j in range(nc):
                            g = raw[y, po + c0 + j - co]
                            out[i, c0 + j] = rown[j] / rowd[j] if np.isfinite(g) else np.nan
                    else:
                        for j in range(nc):
                            out[i, c0 + j] = rown[j]


_smooth_tiles_kernel: Any = (numba.njit(cache=True, nogil=True)(_smooth_tiles_py) if numba is not None else None)


class _Shape:
    """The shape of a derived pyramid level (its pixels come from the base image)."""

    def __init__(self, shape: tuple[int, int], name: str) -> None:
        self.shape, self.name = shape, name

    def read(self, l0: int, l1: int, s0: int, s1: int) -> Array:  # pragma: no cover - never called
        raise InvalidInputError(f"{self.name} is derived from its base image")


def windowed_pyramid(image: WindowedImage, levels: int) -> list[WindowedImage]:
    """:meth:`WindowedImage.pyramid` as a function."""
    return image.pyramid(levels)


def spatial_order(line: Array, sample: Array, cell: float = 64.0) -> NDArray[np.intp]:
    """Indices that visit points in Z (Morton) order of ``cell``-pixel cells: consecutive points are close.

    Batches of consecutive points then cover compact regions of the image (few, small windows).
    """
    l = np.nan_to_num(np.asarray(line, dtype=float) / cell, nan=0.0, posinf=0.0, neginf=0.0)
    s = np.nan_to_num(np.asarray(sample, dtype=float) / cell, nan=0.0, posinf=0.0, neginf=0.0)
    a = np.clip(l, 0, 65535).astype(np.uint64)
    b = np.clip(s, 0, 65535).astype(np.uint64)

    def spread(v: NDArray[np.uint64]) -> NDArray[np.uint64]:
        v = (v | (v << np.uint64(8))) & np.uint64(0x00FF00FF)
        v = (v | (v << np.uint64(4))) & np.uint64(0x0F0F0F0F)
        v = (v | (v << np.uint64(2))) & np.uint64(0x33333333)
        return (v | (v << np.uint64(1))) & np.uint64(0x55555555)

    return np.argsort((spread(a) << np.uint64(1)) | spread(b), kind="stable")


def region_groups(y: Array, x: Array, shape: Sequence[int], before: int, after: int,
                  max_pixels: int = 1 << 22) -> list[tuple[NDArray[np.intp], tuple[int, int, int, int]]]:
    """Groups of rows (axis 0) of coordinate arrays and the image region each group's stencils need.

    ``y``, ``x`` are array-index coordinates (CSM minus 0.5) of shape ``(n, ...)``; a stencil at
    ``i = floor(y)`` reaches rows ``i - before .. i + after``. Groups are split until each region
    holds at most ``max_pixels`` pixels (or one row is left). Rows without a finite coordinate, or
    whose stencils miss the image, are in no group.
    """
    return [(r, b) for r, b, _ in stencil_regions(y, x, shape, before, after, max_pixels)]


def stencil_regions(y: Array, x: Array, shape: Sequence[int], before: int, after: int,
                    max_pixels: int = 1 << 22) -> list[tuple[NDArray[np.intp], tuple[int, int, int, int],
                                                             NDArray[np.int64]]]:
    """:func:`region_groups`, each group with the boxes ``(rows, 4)`` of its rows' stencils.

    A box ``[line0, line1) x [sample0, sample1)`` (image pixels) holds every pixel a row's stencils
    read, and one more on every side (a stencil clamped at the image's last pixel starts one earlier);
    they are the ``need`` of :meth:`WindowedImage.region`.
    """
    h, w = int(shape[0]), int(shape[1])
    n = y.shape[0]
    yy = y.reshape(n, -1)
    xx = x.reshape(n, -1)
    if _extents_kernel is not None:
        # one pass over the coordinates (least-squares matching asks this of (128, 225) arrays every iteration)
        ext = np.empty((n, 4))
        _extents_kernel(np.ascontiguousarray(yy, dtype=float), np.ascontiguousarray(xx, dtype=float), ext)
        has: NDArray[np.bool_] = np.isfinite(ext[:, 0])
        with np.errstate(invalid="ignore"):
            lo_y, hi_y = np.floor(ext[:, 0]) - before, np.floor(ext[:, 1]) + after
            lo_x, hi_x = np.floor(ext[:, 2]) - before, np.floor(ext[:, 3]) + after
    else:  # pragma: no cover - without numba
        fin = np.isfinite(yy) & np.isfinite(xx)
        has = np.asarray(fin.any(axis=1))
        with np.errstate(invalid="ignore"):
            lo_y = np.floor(np.where(fin, yy, np.inf).min(axis=1)) - before
            hi_y = np.floor(np.where(fin, yy, -np.inf).max(axis=1)) + after
            lo_x = np.floor(np.where(fin, xx, np.inf).min(axis=1)) - before
            hi_x = np.floor(np.where(fin, xx, -np.inf).max(axis=1)) + after
    # a row whose stencils lie wholly outside the image samples nothing there
    use = has & (lo_y <= h - 1) & (hi_y >= 0) & (lo_x <= w - 1) & (hi_x >= 0)
    lo_y, lo_x = np.clip(lo_y, 0, h - 1), np.clip(lo_x, 0, w - 1)
    hi_y, hi_x = np.clip(hi_y, 0, h - 1), np.clip(hi_x, 0, w - 1)
    rows = np.flatnonzero(use)
    out: list[tuple[NDArray[np.intp], tuple[int, int, int, int], NDArray[np.int64]]] = []
    stack = [rows]
    while stack:
        r = stack.pop()
        if r.size == 0:
            continue
        a0, a1 = int(lo_y[r].min()), int(hi_y[r].max()) + 1
        b0, b1 = int(lo_x[r].min()), int(hi_x[r].max()) + 1
        if (a1 - a0) * (b1 - b0) <= max_pixels or r.size == 1:
            box = np.stack([np.maximum(lo_y[r] - 1, 0), np.minimum(hi_y[r] + 2, h), np.maximum(lo_x[r] - 1, 0),
                            np.minimum(hi_x[r] + 2, w)], axis=1).astype(np.int64)
            out.append((r, (a0, a1, b0, b1), box))
            continue
        # split at the median of the rows' centres along the region's longer side
        c = (lo_y[r] + hi_y[r]) if (a1 - a0) >= (b1 - b0) else (lo_x[r] + hi_x[r])
        order = np.argsort(c, kind="stable")
        half = r.size // 2
        stack += [r[order[half:]], r[order[:half]]]
    return out


def _extents_py(yy: Array, xx: Array, ext: Array) -> None:
    """Per row: the least and largest ``yy`` and ``xx`` where both are finite (NaN where none is)."""
    for b in range(yy.shape[0]):
        y0 = np.inf
        y1 = -np.inf
        x0 = np.inf
        x1 = -np.inf
        for i in range(yy.shape[1]):
            y = yy[b, i]
            x = xx[b, i]
            if np.isfinite(y) and np.isfinite(x):
                y0 = min(y0, y)
                y1 = max(y1, y)
                x0 = min(x0, x)
                x1 = max(x1, x)
        if y0 == np.inf:
            ext[b, 0] = ext[b, 1] = ext[b, 2] = ext[b, 3] = np.nan
        else:
            ext[b, 0], ext[b, 1], ext[b, 2], ext[b, 3] = y0, y1, x0, x1


_extents_kernel: Any = numba.njit(cache=True, nogil=True)(_extents_py) if numba is not None else None


def _reduce_py(a: Array, out: Array) -> None:
    """2 x 2 block means, summed as ``build_pyramid``'s ``downsample``: ((a00 + a10) + a01) + a11, times 0.25."""
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = 0.25 * (((a[2 * i, 2 * j] + a[2 * i + 1, 2 * j]) + a[2 * i, 2 * j + 1]) + a[2 * i + 1, 2 * j + 1])


_reduce_kernel: Any = numba.njit(cache=True, nogil=True)(_reduce_py) if numba is not None else None


def _reduce(a: Array) -> Array:
    """One pyramid step of an even-sized region (compiled: one pass, no temporaries; the same values)."""
    if _reduce_kernel is None:  # pragma: no cover - without numba
        return 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])
    out = np.empty((a.shape[0] // 2, a.shape[1] // 2))
    _reduce_kernel(a, out)
    return out

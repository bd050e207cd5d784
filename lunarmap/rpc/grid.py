"""Virtual control grids: image grid x height layers, projected with the rigorous model.

The LROC multi-image study (``seeds/001``, text after Eq. 12) derives the
RPCs from "virtual control points": a regular grid in image space, the
height range divided into layers, and the ground coordinates of every grid
point on every layer from the rigorous sensor model. :func:`fit_grid_nodes`
and :func:`check_grid_nodes` choose the nodes; :func:`rigorous_grid`
projects them (``camera.image_to_ground`` at each layer's height) and
refuses grids that miss the body or reach the limb.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..blas import single_threaded_blas
from ..camera.geodesy import xyz_to_lonlat_height
from ..camera.sensor import SensorModel
from ..errors import RpcGridError, RpcInputError, RpcLimbError

__all__ = ["GridNodes", "GroundGrid", "height_layers", "fit_grid_nodes", "check_grid_nodes",
           "rigorous_grid", "DEFAULT_HEIGHT_RANGE"]

Array = NDArray[np.float64]

#: Heights spanned by lunar terrain above the 1737.4 km sphere (LOLA: about
#: -9.1 km to +10.8 km), metres; the default height range of a fit.
DEFAULT_HEIGHT_RANGE = (-9200.0, 10800.0)


@dataclass(frozen=True)
class GridNodes:
    """Nodes of a virtual grid: image lines x samples (pixels, CSM) x heights (metres)."""

    lines: Array
    samples: Array
    heights: Array

    @property
    def size(self) -> int:
        return self.lines.size * self.samples.size * self.heights.size


@dataclass(frozen=True)
class GroundGrid:
    """Flat arrays of grid points: image coordinates and their ground coordinates.

    ``line, sample`` in pixels (CSM), ``lon, lat`` in degrees
    (planetocentric, east-positive), ``height`` in metres above the
    reference sphere; the order is layers x lines x samples, C order.
    """

    line: Array
    sample: Array
    lon: Array
    lat: Array
    height: Array

    @classmethod
    def concatenate(cls, parts: list["GroundGrid"]) -> "GroundGrid":
        return cls(*(np.concatenate([getattr(p, k) for p in parts])
                     for k in ("line", "sample", "lon", "lat", "height")))


def _check_range(height_range: tuple[float, float]) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in height_range)
    except (TypeError, ValueError) as exc:
        raise RpcInputError(f"height_range must be two numbers (metres), got {height_range!r}") from exc
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise RpcInputError(f"height_range holds NaN or infinite values: {height_range!r}")
    if not hi > lo:
        raise RpcInputError(f"height_range must span a positive height interval (metres), got "
                            f"[{lo}, {hi}]: a zero range leaves the RFM's height terms undetermined")
    return lo, hi


def height_layers(height_range: tuple[float, float], n_layers: int = 7, margin: float = 0.05) -> Array:
    """Heights of the fit's elevation layers, metres.

    ``n_layers`` equally spaced heights over ``height_range`` widened by
    ``margin`` (a fraction of its span) at both ends.
    """
    lo, hi = _check_range(height_range)
    if int(n_layers) < 4:
        raise RpcInputError(f"a cubic RFM needs at least 4 height layers, got {n_layers}")
    if not (np.isfinite(margin) and margin >= 0.0):
        raise RpcInputError(f"margin must be a non-negative fraction, got {margin}")
    pad = margin * (hi - lo)
    return np.linspace(lo - pad, hi + pad, int(n_layers))


def _axis_counts(n_lines: int, n_samples: int, short: int, long_max: int) -> tuple[int, int]:
    """Nodes per image axis: ``short`` on the shorter axis, about square cells, at most ``long_max``."""
    aspect = max(n_lines, n_samples) / max(min(n_lines, n_samples), 1)
    n_long = int(np.clip(round((short - 1) * aspect) + 1, short, long_max))
    return (n_long, short) if n_lines >= n_samples else (short, n_long)


def fit_grid_nodes(n_lines: int, n_samples: int, heights: ArrayLike, short_axis: int = 21,
                   long_axis_max: int = 161) -> GridNodes:
    """Fit-grid nodes covering the whole image, edges included.

    Parameters
    ----------
    n_lines, n_samples : int
        Image size, pixels.
    heights : array_like
        Layer heights, metres (see :func:`height_layers`).
    short_axis, long_axis_max : int
        Nodes along the shorter image axis, and at most along the longer one.
    """
    nl, ns = _axis_counts(n_lines, n_samples, short_axis, long_axis_max)
    return GridNodes(np.linspace(0.0, float(n_lines), nl), np.linspace(0.0, float(n_samples), ns),
                     np.asarray(heights, dtype=float))


def check_grid_nodes(n_lines: int, n_samples: int, fit_heights: ArrayLike, short_axis: int = 21,
                     long_axis_max: int = 161, density: int = 2, outside: float = 0.10) -> GridNodes:
    """An independent check grid: denser, off the fit nodes, heights between and beyond the layers.

    Image nodes: ``density`` times as many cells per axis as the fit grid,
    cell centres (none falls on a fit node when ``density`` is even) plus
    both image edges. Heights: the midpoints between consecutive fit layers
    and two heights ``outside`` (fraction of the fit span) below and above
    the fit range.
    """
    nl, ns = _axis_counts(n_lines, n_samples, short_axis, long_axis_max)
    h = np.asarray(fit_heights, dtype=float)
    span = h[-1] - h[0]

    def axis(n_nodes: int, size: int) -> Array:
        cells = density * (n_nodes - 1) + 1
        centres = (np.arange(cells) + 0.5) / cells * size
        return np.concatenate([[0.0], centres, [float(size)]])

    heights = np.concatenate([[h[0] - outside * span], 0.5 * (h[1:] + h[:-1]), [h[-1] + outside * span]])
    return GridNodes(axis(nl, n_lines), axis(ns, n_samples), heights)


def rigorous_grid(camera: SensorModel, nodes: GridNodes, max_emission: float = 85.0) -> GroundGrid:
    """Ground coordinates of grid nodes from the rigorous sensor model.

    Parameters
    ----------
    camera : SensorModel
        The rigorous model (FrameCamera, LineScanCamera); ``camera.image_to_ground`` at each layer height.
    nodes : GridNodes
        Image lines, samples (pixels, CSM) and heights (metres).
    max_emission : float
        Largest emission angle (degrees) accepted at any grid point: beyond
        it the footprint is at the limb, where a lat/lon RFM is meaningless.

    Returns
    -------
    GroundGrid
        Flat arrays in layer-major order.

    Raises
    ------
    RpcGridError
        Every ray misses the body (the camera looks past it).
    RpcLimbError
        Some rays miss the body, or graze it beyond ``max_emission``: the
        footprint crosses the limb.
    """
    with single_threaded_blas():
        return _rigorous_grid(camera, nodes, max_emission)


def _rigorous_grid(camera: SensorModel, nodes: GridNodes, max_emission: float) -> GroundGrid:
    L, S = np.meshgrid(nodes.lines, nodes.samples, indexing="ij")
    line = np.broadcast_to(L.ravel(), (nodes.heights.size, L.size))
    sample = np.broadcast_to(S.ravel(), (nodes.heights.size, S.size))
    height = np.broadcast_to(nodes.heights[:, None], line.shape)
    xyz = camera.image_to_ground(line, sample, height=height, on_miss="nan")
    miss = ~np.all(np.isfinite(xyz), axis=-1)
    name = repr(camera)
    if miss.all():
        raise RpcGridError(f"the virtual grid of {name} misses the body: none of its {miss.size} rays "
                           f"(heights {nodes.heights.min():.0f} to {nodes.heights.max():.0f} m) hits the "
                           f"shape")
    if miss.any():
        raise RpcLimbError(f"the footprint of {name} crosses the limb: {int(miss.sum())} of {miss.size} "
                           f"virtual grid rays miss the body (heights {nodes.heights.min():.0f} to "
                           f"{nodes.heights.max():.0f} m)")
    # Emission angle on the lowest layer's points (the highest emission for a given ray).
    g = xyz[0]
    to_sensor = -camera.look_vector(line[0], sample[0])
    cos_e = np.einsum("ij,ij->i", to_sensor, g) / (np.linalg.norm(to_sensor, axis=-1) * np.linalg.norm(g, axis=-1))
    emission = np.degrees(np.arccos(np.clip(cos_e, -1.0, 1.0)))
    if emission.max() > max_emission:
        raise RpcLimbError(f"the footprint of {name} reaches the limb: emission angles up to "
                           f"{emission.max():.1f} deg exceed max_emission={max_emission} deg")
    lon, lat, h = xyz_to_lonlat_height(xyz, camera.reference_radius)
    return GroundGrid(np.ascontiguousarray(line).ravel(), np.ascontiguousarray(sample).ravel(),
                      lon.ravel(), lat.ravel(), h.ravel())

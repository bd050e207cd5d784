"""lunarmap: planetary photogrammetry from SPICE kernels to adjusted orientations.

The calls that take a user from image labels to adjusted kernels::

    import lunarmap

    cam = lunarmap.load_camera("M103595705LE.lbl", "lro_nac.tm")        # label + kernels -> camera
    cam = lunarmap.camera_from_isd_file("M103595705LE.json")            # or an ALE/usgscsm ISD, no SPICE
    rpc = lunarmap.fit_rpc(cam).model                                   # cubic RFM of the camera
    ties = lunarmap.find_tiepoints(images, cameras)                     # tie-point table (dask)
    block = lunarmap.build_block(cameras, ties, navigation=spec)        # adjustment block
    result = lunarmap.solve(block)                                      # adjusted sensors, precision
    lon, lat, h = lunarmap.xyz_to_lonlat_height(result.points()["xyz"])  # ground points -> degrees, metres
    out = lunarmap.write_adjusted(result, isds, "out/", "lro_nac.tm")   # adjusted SPK + CK + meta-kernel

Everything else stays in its package (:mod:`lunarmap.camera`, :mod:`lunarmap.rpc`,
:mod:`lunarmap.matching`, :mod:`lunarmap.adjust`, ...). Library code logs to the ``lunarmap``
logger (a ``NullHandler`` is installed: configure ``logging`` to see it) and never prints.

Conventions
-----------
=====================  ==========================================================
quantity               unit / convention
=====================  ==========================================================
time                   ephemeris time (ET, TDB seconds past J2000) internally;
                       UTC only at input/output
ground coordinates     body-fixed Cartesian, **metres** (labels and ISDs use km)
lat / lon              planetocentric, degrees at the API surface, east-positive
height                 metres above the reference sphere/ellipsoid
image coordinates      ``(line, sample)``, pixels, USGS CSM convention: the centre
                       of the first pixel is ``(0.5, 0.5)`` (ISIS: ``(1, 1)``)
focal plane            millimetres, NAIF instrument frame, boresight +z
quaternions            SPICE order ``(w, x, y, z)``
=====================  ==========================================================

Data flow: ``spice`` (kernels) -> ``orientation`` -> ``camera`` -> rpc -> matching
-> adjust -> evaluate -> workflows. Nothing after ``orientation`` calls SPICE.
"""

from __future__ import annotations

import importlib
import logging
from typing import TYPE_CHECKING, Any

from . import errors
from .errors import LunarmapError

if TYPE_CHECKING:   # for the annotations of solve (imported on first use, not with lunarmap)
    from .adjust import AdjustmentResult, Block, BlockResult, BundleProblem, SolverOptions

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

# Public calls, imported on first use so that ``import lunarmap`` stays light (no dask, numba,
# SPICE until needed): name -> (module, attribute).
_LAZY = {
    "image_support": ("lunarmap.orientation.drivers", "image_support"),
    "ImageSupport": ("lunarmap.orientation.isd", "ImageSupport"),
    "camera_from_isd": ("lunarmap.camera.factory", "camera_from_isd"),
    "camera_from_isd_file": ("lunarmap.camera.factory", "camera_from_isd_file"),
    "load_camera": ("lunarmap.camera.factory", "load_camera"),
    "SensorModel": ("lunarmap.camera.sensor", "SensorModel"),
    "fit_rpc": ("lunarmap.rpc", "fit_rpc"),
    "find_tiepoints": ("lunarmap.matching", "find_tiepoints"),
    "network_from_tiepoints": ("lunarmap.adjust", "network_from_tiepoints"),
    "build_block": ("lunarmap.adjust", "build_block"),
    "NavigationSpec": ("lunarmap.adjust", "NavigationSpec"),
    "JitterSpec": ("lunarmap.adjust", "JitterSpec"),
    "write_adjusted": ("lunarmap.adjust", "write_adjusted"),
    # laser altimetry (LOLA-like shot tables) as observations: build_block(..., altimetry=[LaserAltimetry(...)])
    "LaserAltimetry": ("lunarmap.adjust", "LaserAltimetry"),
    "read_altimetry": ("lunarmap.io.altimetry", "read_altimetry"),
    # ground coordinates (body-fixed metres) <-> planetocentric longitude, latitude (degrees), height (metres)
    "xyz_to_lonlat_height": ("lunarmap.camera.geodesy", "xyz_to_lonlat_height"),
    "lonlat_height_to_xyz": ("lunarmap.camera.geodesy", "lonlat_height_to_xyz"),
    # ISIS and ASP interop (issue 14)
    "camera_from_cube": ("lunarmap.camera.cube", "camera_from_cube"),
    "open_image": ("lunarmap.io.raster", "open_image"),
    "read_isis_network": ("lunarmap.adjust.isis", "read_isis_network"),
    "write_isis_network": ("lunarmap.adjust.isis", "write_isis_network"),
}

__all__ = ["errors", "LunarmapError", "__version__", "solve", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'lunarmap' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


def solve(block_or_problem: Block | BundleProblem, options: SolverOptions | None = None,
          **kwargs: Any) -> BlockResult | AdjustmentResult:
    """Adjust a block (or a bare bundle problem) by damped Gauss-Newton with a sparse Schur complement.

    Parameters
    ----------
    block_or_problem : lunarmap.adjust.Block or lunarmap.adjust.BundleProblem
        A block from :func:`lunarmap.build_block` (cameras, network, navigation), or a problem built
        by hand.
    options : lunarmap.adjust.SolverOptions, optional
        Iteration controls (``ftol``, ``xtol``, ``max_iterations``, the factorisation ``backend``,
        ``progress``: seconds between iteration lines on the ``lunarmap`` logger).
    **kwargs
        ``reweight`` and ``callback`` for :func:`lunarmap.adjust.solve` (called after each accepted step).

    Returns
    -------
    lunarmap.adjust.BlockResult or lunarmap.adjust.AdjustmentResult
        For a block, a ``BlockResult``: ``sigma0``, ``converged``, ``adjusted_sensors()`` (new cameras;
        the originals are untouched), ``points()`` (adjusted coordinates with posterior sigmas),
        ``corrections()``, ``check_points()`` (errors against the check points' reference coordinates)
        and the underlying ``result``; for a problem, that ``AdjustmentResult`` (``state``,
        ``sigma0``, ``precision()``, ``residuals_dataset()``).

    Raises
    ------
    DatumDefectError
        The normal equations are singular: the block has no datum (add navigation observations or
        control points).
    AdjustmentDivergedError
        The cost became non-finite and no step could reduce it.
    """
    from . import adjust

    if isinstance(block_or_problem, adjust.Block):
        return adjust.solve_block(block_or_problem, options, **kwargs)
    return adjust.solve(block_or_problem, options, **kwargs)

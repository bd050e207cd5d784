"""Rational function models (RPC00B cubic RFM): fit, evaluate, store, scale out on dask.

* :class:`RationalFunctionModel` -- evaluation (``ground_to_image``,
  ``image_to_ground`` at a height) and analytic partials (``jacobian`` in
  lon/lat/height, ``jacobian_xyz`` in body-fixed metres);
* :func:`fit_rpc` -- terrain-independent fit from a virtual control grid in
  height layers with an independent check report (``seeds/001`` Eqs. 11-12);
* :mod:`~lunarmap.rpc.io` -- netCDF and GDAL ``_RPC.TXT``;
* :func:`fit_many` / :func:`fit_rpc_delayed` -- dask graphs.
"""

from ..errors import (
                         RpcConvergenceError,
                         RpcError,
                         RpcFitError,
                         RpcFormatError,
                         RpcGridError,
                         RpcInputError,
                         RpcLimbError,
)
from .fit import FitOptions, FitReport, RpcFit, check_fit, fit_from_grid, fit_rfm, fit_rpc
from .grid import (
                         DEFAULT_HEIGHT_RANGE,
                         GridNodes,
                         GroundGrid,
                         check_grid_nodes,
                         fit_grid_nodes,
                         height_layers,
                         rigorous_grid,
)
from .io import GDAL_PIXEL_SHIFT, read_netcdf, read_rpc_txt, rpc_txt_keywords, write_netcdf, write_rpc_txt
from .model import COORDINATES, POLYNOMIALS, RationalFunctionModel
from .parallel import fit_many, fit_rpc_delayed, rigorous_grid_delayed
from .terms import N_TERMS, TERM_NAMES, rpc_term_gradients, rpc_terms

__all__ = [
    "RationalFunctionModel", "POLYNOMIALS", "COORDINATES",
    "N_TERMS", "TERM_NAMES", "rpc_terms", "rpc_term_gradients",
    "FitOptions", "FitReport", "RpcFit", "fit_rpc", "fit_rfm", "fit_from_grid", "check_fit",
    "DEFAULT_HEIGHT_RANGE", "GridNodes", "GroundGrid", "height_layers", "fit_grid_nodes", "check_grid_nodes",
    "rigorous_grid",
    "write_netcdf", "read_netcdf", "write_rpc_txt", "read_rpc_txt", "rpc_txt_keywords", "GDAL_PIXEL_SHIFT",
    "fit_many", "fit_rpc_delayed", "rigorous_grid_delayed",
    "RpcError", "RpcInputError", "RpcFormatError", "RpcGridError", "RpcLimbError", "RpcFitError",
    "RpcConvergenceError",
]

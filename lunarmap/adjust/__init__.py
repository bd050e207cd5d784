"""Block adjustment: sparse bundle adjustment with navigation observations, RFM-affine adjustment, precision."""

from .bal import BALData, bal_to_problem, problem_to_bal_cameras, read_bal, write_bal
from .collinearity import FrameModel, frame_jacobians, project_frame
from ..errors import (
    AdjustmentDivergedError,
    AdjustmentError,
    AdjustmentInputError,
    DatumDefectError,
    InsufficientObservationsError,
    NetworkFormatError,
    UnobservedParameterError,
)
from .factor import available_backends, factorize
from .problem import BundleProblem, ImageObservations, PointPriors, ReducedTerm
from .result import AdjustmentResult
from .rfm_affine import AffineRFMModel
from .linescan_poly import LineScanPolyModel
from .control_points import lonlat_covariance_to_xyz, lonlat_priors
from .network import ControlNetwork, read_network, write_network
from .navigation import NavigationObservations
from .solver import AdjustmentState, SolverOptions, solve

__all__ = [
    "BALData", "read_bal", "write_bal", "bal_to_problem", "problem_to_bal_cameras",
    "FrameModel", "frame_jacobians", "project_frame",
    "AdjustmentError", "AdjustmentInputError", "InsufficientObservationsError", "UnobservedParameterError",
    "DatumDefectError", "AdjustmentDivergedError", "NetworkFormatError",
    "available_backends", "factorize",
    "BundleProblem", "ImageObservations", "PointPriors", "ReducedTerm",
    "AdjustmentResult", "AdjustmentState", "SolverOptions", "solve",
    "AffineRFMModel", "LineScanPolyModel", "lonlat_priors", "lonlat_covariance_to_xyz",
    "ControlNetwork", "read_network", "write_network", "NavigationObservations",
]

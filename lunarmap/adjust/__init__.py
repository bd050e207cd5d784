"""Block adjustment: sparse bundle adjustment of lunarmap's sensor models with navigation observations,
control points and full posterior precision.

* :func:`build_block` / :func:`solve_block` -- named images on their own sensor models
  (:class:`SensorImageModel`: frame and line-scan cameras with their distortion, RFMs), a control
  network (tie points from the matcher, control and check points), navigation observations with
  per-orbit offsets and drifts (:class:`NavigationSpec`); adjusted sensors out, written back as ISDs
  and SPICE kernels layered over the original set (:func:`write_adjusted`);
* :func:`solve` -- the Levenberg-Marquardt solver on a :class:`BundleProblem` (Schur complement,
  sparse Cholesky); :class:`AdjustmentResult` and its :meth:`~AdjustmentResult.precision`;
* :class:`FrameModel` and the BAL reader/writer -- the BAL collinearity model, kept for benchmarks
  against other solvers;
* :func:`quality_control` (:mod:`.qc`) -- Sequent pre-screening, robust reweighting, Baarda data
  snooping of every observation group, variance components per group, per-orbit offset/drift
  detection, with a report of every decision (issue 11);
* :class:`ReferenceDtm` (:mod:`.terrain`) -- reference DTM heights as observations of the tie points
  (issue 30), one variance-component group per DTM, snooped like the others;
* :class:`JitterSmoothness` (:mod:`.jitter`) -- the smoothness prior of line-scan jitter splines
  (``SensorImageModel(jitter_lines=...)``), an observation group of its own.
* :class:`LaserAltimetry` (:mod:`.altimetry`) -- laser-altimetry shots (LOLA-like tracks) observing the
  tie points' triangulated surface, with per-track offsets (and drifts); one group per instrument.
"""

from ..errors import (
    AdjustmentDivergedError,
    AdjustmentError,
    AdjustmentInputError,
    DatumDefectError,
    InsufficientObservationsError,
    NetworkFormatError,
    UnobservedParameterError,
)
from .altimetry import AltimetryObservations, LaserAltimetry, altimetry_observations
from .bal import BALData, bal_to_problem, problem_to_bal_cameras, read_bal, write_bal
from .block import Block, BlockResult, NavigationSpec, build_block, navigation_observations, solve_block
from .collinearity import FrameModel, frame_jacobians, project_frame
from .control_points import lonlat_covariance_to_xyz, lonlat_priors
from .export import AdjustedOrientation, adjusted_image_support, write_adjusted
from .factor import available_backends, factorize
from .intersection import IntersectionResult, intersect_points
from .jitter import JitterSmoothness, JitterSpec
from .navigation import NavigationObservations
from .network import ControlNetwork, merge_networks, network_from_tiepoints, read_network, write_network
from .problem import BundleProblem, ImageModel, ImageObservations, PointPriors, ReducedTerm
from .qc import QCOptions, QCReport, QCResult, quality_control
from .result import AdjustmentResult
from .sensors import SensorImageModel
from .solver import AdjustmentState, SolverOptions, solve
from .terrain import DtmGrid, DtmHeights, ReferenceDtm, dtm_heights
from .variance import (
    ObservationGroups,
    VarianceComponents,
    estimate_variance_components,
    observation_groups,
    variance_component_covariance,
)
from .weights import ScaledTerm, Weights, reweighted_problem

__all__ = [
    "Block", "BlockResult", "NavigationSpec", "build_block", "solve_block", "navigation_observations",
    "SensorImageModel", "ImageModel", "AdjustedOrientation", "adjusted_image_support", "write_adjusted",
    "BALData", "read_bal", "write_bal", "bal_to_problem", "problem_to_bal_cameras",
    "FrameModel", "frame_jacobians", "project_frame",
    "AdjustmentError", "AdjustmentInputError", "InsufficientObservationsError", "UnobservedParameterError",
    "DatumDefectError", "AdjustmentDivergedError", "NetworkFormatError",
    "available_backends", "factorize", "IntersectionResult", "intersect_points",
    "BundleProblem", "ImageObservations", "PointPriors", "ReducedTerm",
    "AdjustmentResult", "AdjustmentState", "SolverOptions", "solve",
    "lonlat_priors", "lonlat_covariance_to_xyz",
    "ControlNetwork", "read_network", "write_network", "network_from_tiepoints", "merge_networks",
    "NavigationObservations", "JitterSmoothness", "JitterSpec", "ReferenceDtm", "DtmGrid", "DtmHeights", "dtm_heights",
    "LaserAltimetry", "AltimetryObservations", "altimetry_observations",
    "ObservationGroups", "VarianceComponents", "estimate_variance_components", "observation_groups",
    "variance_component_covariance",
    "ScaledTerm", "Weights", "reweighted_problem", "QCOptions", "QCReport", "QCResult", "quality_control",
]

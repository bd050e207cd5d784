"""Evaluation and planning: check points, stereo geometry, theoretical precision, image combinations, plots.

* :mod:`.geometry` -- viewing and illumination geometry of every image and pair from its sensor model
  (emission, incidence, phase, sub-solar azimuths, slew, scaled pixel size and aspect ratio, convergence,
  B/H, shadow-tip distance, ratio of aspect ratios, overlap area);
* :mod:`.footprint` -- footprints on the reference sphere and overlaps (equal-area projection);
* :mod:`.checkpoints` -- check-point errors along-track / cross-track / height and east / north / up
  next to the predicted sigma, for a solved block or triangulated points;
* :mod:`.theory` -- the study's Eq. 15 (precision of a symmetric convergent pair) and the matching
  error as a linear function of the convergence angle, fitted from simulation;
* :mod:`.combinations` -- all k-image combinations of a site and the progressive selection, on dask;
* :mod:`.qc_truth` -- quality control's removals against a simulation's truth cameras and DTM (true error
  of every tie observation; precision, recall and false removals at several thresholds);
* :mod:`.plots` -- the study's figures with matplotlib (optional dependency).

The layering is ``... -> adjust -> evaluate``: evaluate uses the adjustment, never the reverse.
"""

from .checkpoints import (
                          ENU,
                          TRACK,
                          Triangulation,
                          along_track_azimuth,
                          block_check_errors,
                          check_point_errors,
                          track_basis,
                          triangulate,
)
from .combinations import (
                          best_combinations,
                          combination_name,
                          compare_with_exhaustive,
                          evaluate_combination,
                          evaluate_combinations,
                          progressive_selection,
                          site_network,
                          subset_network,
)
from .footprint import Footprint, Overlap, candidate_pairs, footprint, laea_forward, laea_inverse, overlap, polygon_area
from .geometry import (
                          ViewGeometry,
                          image_centre_point,
                          image_geometry,
                          pair_geometry,
                          parallax_height_ratio,
                          shadow_tip_distance,
                          view_geometry,
)
from .plots import (
                          plot_error_vs_convergence,
                          plot_footprints,
                          plot_matching_error,
                          plot_pair_quantity,
                          plot_precision_vs_convergence,
                          plot_precision_vs_images,
                          power_law_fit,
                          save_figure,
)
from .qc_truth import QC_TRUTH_LIMITS_PX, QC_TRUTH_LIMITS_SIGMA, qc_against_truth, removal_scores, true_tie_errors
from .theory import (
                          NAC_MATCHING_ERROR,
                          MatchingErrorModel,
                          eq15_precision,
                          fit_matching_error,
                          pair_precision,
                          simulate_matching_errors,
)

__all__ = [
    "Footprint", "Overlap", "footprint", "overlap", "candidate_pairs", "laea_forward", "laea_inverse", "polygon_area",
    "ViewGeometry", "view_geometry", "image_geometry", "pair_geometry", "shadow_tip_distance",
    "parallax_height_ratio", "image_centre_point",
    "TRACK", "ENU", "Triangulation", "along_track_azimuth", "track_basis", "check_point_errors", "block_check_errors",
    "triangulate",
    "site_network", "subset_network", "combination_name", "evaluate_combination", "evaluate_combinations",
    "progressive_selection", "compare_with_exhaustive", "best_combinations",
    "NAC_MATCHING_ERROR", "MatchingErrorModel", "eq15_precision", "fit_matching_error", "simulate_matching_errors",
    "pair_precision",
    "plot_error_vs_convergence", "plot_matching_error", "plot_precision_vs_convergence", "plot_pair_quantity",
    "plot_precision_vs_images", "plot_footprints", "save_figure", "power_law_fit",
    "QC_TRUTH_LIMITS_PX", "QC_TRUTH_LIMITS_SIGMA", "true_tie_errors", "removal_scores", "qc_against_truth",
]

"""Evaluation and planning: check points, stereo geometry, theoretical precision, image combinations, plots.

* :mod:`.geometry` -- viewing and illumination geometry of every image and pair from its sensor model
  (emission, incidence, phase, sub-solar azimuths, slew, scaled pixel size and aspect ratio, convergence,
  B/H, shadow-tip distance, ratio of aspect ratios, overlap area);
* :mod:`.footprint` -- footprints on the reference sphere and overlaps (equal-area projection).
"""

from .footprint import Footprint, Overlap, footprint, laea_forward, laea_inverse, overlap, polygon_area
from .geometry import (ViewGeometry, image_centre_point, image_geometry, pair_geometry, parallax_height_ratio,
                       shadow_tip_distance, view_geometry)

__all__ = [
    "Footprint", "Overlap", "footprint", "overlap", "laea_forward", "laea_inverse", "polygon_area",
    "ViewGeometry", "view_geometry", "image_geometry", "pair_geometry", "shadow_tip_distance",
    "parallax_height_ratio", "image_centre_point",
]

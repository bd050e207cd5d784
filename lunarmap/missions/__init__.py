"""Historical missions: reconstructed pointing, film and vidicon geometry, multi-ray intersection.

* :mod:`~lunarmap.missions.flight_parameters` -- the Ranger flight-parameter table (``LATs``, ``LONs``,
  ``LATp``, ``LONp``, ``R``, ``Range``, ``Alt``, ``AZN``, ``AZS/C`` per photo; CSV and netCDF), checked on
  reading;
* :mod:`~lunarmap.missions.five_rotations` -- the Ranger paper's orientation from those parameters
  (``seeds/000``: five rotations into the selenocentric frame) and back;
* :mod:`~lunarmap.missions.ranger` -- Ranger cameras (:class:`RangerCamera`: photo coordinates in mm
  <-> CSM pixels) built from a table, the paper's selenocentric ``X'Y'Z'`` and its tables' latitude,
  longitude and elevation, base-height ratios;
* :mod:`~lunarmap.missions.reseau` -- reseau-grid correction of image measurements (a projective or
  bilinear transformation per grid cell) with a residual report per mark;
* :mod:`~lunarmap.missions.multiray` -- multi-ray intersection of points measured on 2-n photos in the
  monoscopic or stereoscopic point-transfer mode, with ``S0`` and ``sigma X', Y', Z'`` (the paper's
  Table IV), on :func:`lunarmap.adjust.intersect_points`;
* :mod:`~lunarmap.missions.ranger_kernels` -- a reconstructed sequence written as SPICE kernels (SPK,
  CK, FK, IK, SCLK, LSK, PCK, meta-kernel) and ISIS-like labels, so that it loads like any mission;
* :mod:`~lunarmap.missions.ranger_simulation` -- Ranger-like descending sequences with known truth;
* :mod:`~lunarmap.missions.clementine` -- a Clementine multi-orbit block through the real UVVIS
  interior orientation, adjusted with navigation observations.
"""

from __future__ import annotations

from .five_rotations import five_rotations, orientation_angles, photo_to_body, sensor_to_body, tilt_from_ranges
from .flight_parameters import FlightParameters, flight_parameters_from_orientation, read_flight_parameters
from .multiray import MultiRayResult, TransferMode, intersect_photos
from .ranger import (
                     RangerCamera,
                     base_height_ratio,
                     body_fixed_to_paper,
                     paper_to_body_fixed,
                     ranger_cameras,
                     table_coordinates,
)
from .reseau import ReseauCorrection, ReseauGrid

__all__ = [
    "FlightParameters", "read_flight_parameters",
    "five_rotations", "photo_to_body", "sensor_to_body", "tilt_from_ranges", "orientation_angles",
    "flight_parameters_from_orientation",
    "RangerCamera", "ranger_cameras", "paper_to_body_fixed", "body_fixed_to_paper", "table_coordinates",
    "base_height_ratio",
    "ReseauGrid", "ReseauCorrection",
    "TransferMode", "MultiRayResult", "intersect_photos",
]

"""Exterior orientation: sampled once from SPICE, interpolated with numpy afterwards."""

from .exterior import ExteriorOrientation
from .rotation import align_quaternion_signs, matrix_to_quat, normalize_quat, quat_to_matrix

__all__ = ["ExteriorOrientation", "quat_to_matrix", "matrix_to_quat", "align_quaternion_signs",
           "normalize_quat"]

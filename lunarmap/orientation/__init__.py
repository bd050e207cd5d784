"""Exterior orientation: sampled once from SPICE, interpolated with numpy afterwards.

Adjusted orientation goes back the other way with :func:`updated_image_support`
(an adjusted ISD, no SPICE) and :func:`lunarmap.orientation.kernels.write_orientation_kernels`
(SPK + CK + meta-kernel over the original set; imported from its module, as it uses SPICE).
"""

from .exterior import ExteriorOrientation
from .rotation import align_quaternion_signs, matrix_to_quat, normalize_quat, quat_to_matrix
from .update import updated_image_support

__all__ = ["ExteriorOrientation", "quat_to_matrix", "matrix_to_quat", "align_quaternion_signs",
           "normalize_quat", "updated_image_support"]

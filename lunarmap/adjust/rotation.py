"""Rotation-vector helpers used by the adjustment's Jacobians (defined in :mod:`lunarmap.orientation.rotation`)."""

from ..orientation.rotation import left_jacobian, matrix_to_rotvec, rotate, rotvec_to_matrix, skew

__all__ = ["skew", "rotvec_to_matrix", "matrix_to_rotvec", "rotate", "left_jacobian"]

"""Helpers for tests and benchmarks: synthetic, SPICE-free camera set-ups."""

from .cameras import NAC_LINE_TIME, NAC_LINES, NAC_SAMPLES, nac_like_interior, polar_orbit_eo

__all__ = ["NAC_LINE_TIME", "NAC_LINES", "NAC_SAMPLES", "nac_like_interior", "polar_orbit_eo"]

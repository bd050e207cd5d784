"""Rigorous sensor models: interior orientation, distortion, frame and line-scan cameras."""

from .interior import InteriorOrientation

__all__ = ["InteriorOrientation"]

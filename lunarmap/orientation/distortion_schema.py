"""The ``optical_distortion`` blocks an ISD may carry: model names and the keys of each.

The ISD reader checks a document's distortion block against :data:`DISTORTION_SCHEMAS`
(here, at the orientation level, so that reading an ISD needs no camera code); the camera
package builds the models themselves (:mod:`lunarmap.camera.distortion`) and its registry
holds exactly these names (a test asserts it).

Names and keys are usgscsm's and ALE's (``Utilities.cpp getDistortionCoeffs``), plus the two
film-camera models lunarmap adds (``lunarorbiter``'s ``coefficients``, and ``apollometric``,
which usgscsm does not know: ``lunarmap isd --csm`` replaces both by a fitted ``transverse``
polynomial usgscsm applies). A key is ``(kind, min_length, max_length, required)``:
``"list"`` a list of numbers (a bare number counts as a list of one), ``"number"`` a scalar.
"""

from __future__ import annotations

from collections.abc import Mapping
from numbers import Real
from typing import Any, NamedTuple

__all__ = ["DistortionKey", "DISTORTION_SCHEMAS", "distortion_block_problem"]


class DistortionKey(NamedTuple):
    """One key of a distortion block."""

    kind: str            #: ``"list"`` or ``"number"``
    min_length: int = 1
    max_length: int = 1
    required: bool = True


def _coefficients(lo: int, hi: int) -> dict[str, DistortionKey]:
    return {"coefficients": DistortionKey("list", lo, hi)}


_NUMBER = DistortionKey("number")

#: Distortion model name -> its keys (usgscsm / ALE names, lower case).
DISTORTION_SCHEMAS: dict[str, dict[str, DistortionKey]] = {
    "none": {},
    # ISIS OD_K (k0, k1, k2); usgscsm pads nothing: fewer than 3 are read as zeros by lunarmap
    "radial": _coefficients(1, 3),
    "lrolrocnac": _coefficients(1, 1),
    "kaguyalism": {"x": DistortionKey("list", 1, 4), "y": DistortionKey("list", 1, 4),
                   "boresight_x": _NUMBER, "boresight_y": _NUMBER},
    # third-order polynomials in (x, y), 10 terms each (usgscsm pads shorter lists with zeros)
    "transverse": {"x": DistortionKey("list", 1, 10), "y": DistortionKey("list", 1, 10)},
    # OpenCV order (k1, k2, p1, p2, k3), normalised by the focal length
    "radtan": _coefficients(5, 5),
    "dawnfc": _coefficients(1, 1),
    "kplo_shadowcam": _coefficients(1, 1),
    "lunarorbiter": {"perspective_x": _NUMBER, "perspective_y": _NUMBER, "center_point_x": _NUMBER,
                     "center_point_y": _NUMBER, "coefficients": DistortionKey("list", 1, 3, required=False)},
    "apollometric": {"principal_point": DistortionKey("list", 2, 2), "coefficients": DistortionKey("list", 1, 3),
                     "decentering": DistortionKey("list", 3, 3)},
}


def _is_number(v: Any) -> bool:
    return isinstance(v, Real) and not isinstance(v, bool)


def distortion_block_problem(model: str, block: Any) -> tuple[str, str] | None:
    """What is wrong with a distortion block, as ``(key, problem)``, or ``None`` when it is well formed.

    Parameters
    ----------
    model : str
        The model name (case-insensitive).
    block : object
        The ``optical_distortion.<model>`` value of the document.
    """
    schema = DISTORTION_SCHEMAS.get(str(model).lower())
    if schema is None:
        return "", f"names a distortion model lunarmap does not know; known: {sorted(DISTORTION_SCHEMAS)}"
    if not isinstance(block, Mapping):
        return "", f"must be a JSON object, got {type(block).__name__}"
    for key, spec in schema.items():
        if key not in block:
            if spec.required:
                return key, "is missing"
            continue
        value = block[key]
        if spec.kind == "number":
            if not _is_number(value):
                return key, f"must be a number, got {value!r:.40}"
            continue
        values = value if isinstance(value, list) else [value]
        if not all(_is_number(v) for v in values):
            return key, f"must be a list of numbers, got {value!r:.60}"
        if not spec.min_length <= len(values) <= spec.max_length:
            want = str(spec.min_length) if spec.min_length == spec.max_length else \
                f"{spec.min_length} to {spec.max_length}"
            return key, f"must hold {want} numbers, got {len(values)}"
    return None

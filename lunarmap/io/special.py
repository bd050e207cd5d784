"""ISIS special pixel values (NULL, LRS, LIS, HIS, HRS) of every cube pixel type.

ISIS reserves, per stored pixel type, a few values that are not data: *Null* (no data),
*Lis*/*His* (low/high saturation on the instrument) and *Lrs*/*Hrs* (low/high
saturation of the representation, e.g. a computation overflowed). Reading turns them
into NaN and reports which one each pixel was (:data:`SPECIAL_CODES`); writing turns
NaN and those codes back into the stored values. The values are those of ISIS's
``SpecialPixel.h`` (public, USGS Astrogeology): float bit patterns ``0xFF7FFFFB``..
``0xFF7FFFFF`` for ``Real``, the lowest / highest integers for the integer types.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..errors import CubeFormatError

__all__ = ["PIXEL_TYPES", "SPECIAL_CODES", "SPECIAL_NAMES", "special_values", "classify", "encode_special"]

#: ISIS ``Pixels/Type`` -> numpy dtype character code (byte order applied separately).
PIXEL_TYPES = {
    "UnsignedByte": "u1",
    "SignedWord": "i2",
    "UnsignedWord": "u2",
    "SignedInteger": "i4",
    "UnsignedInteger": "u4",
    "Real": "f4",
}

#: Codes of the special-pixel mask: 0 valid data, then the ISIS special pixels.
SPECIAL_CODES = {"valid": 0, "Null": 1, "Lrs": 2, "Lis": 3, "His": 4, "Hrs": 5}
SPECIAL_NAMES = {v: k for k, v in SPECIAL_CODES.items()}

_F4 = {"Null": 0xFF7FFFFB, "Lrs": 0xFF7FFFFC, "Lis": 0xFF7FFFFD, "His": 0xFF7FFFFE, "Hrs": 0xFF7FFFFF}
_F4_VALID_MIN = np.array([0xFF7FFFFA], dtype=np.uint32).view(np.float32)[0]

# stored value of each special pixel (ISIS SpecialPixel.h); UnsignedByte has only 0 and 255,
# so Null/Lrs/Lis share 0 (read back as Null) and His/Hrs share 255 (read back as Hrs)
_INTEGER = {
    "u1": ({"Null": 0, "Lrs": 0, "Lis": 0, "His": 255, "Hrs": 255}, 1, 254),
    "i2": ({"Null": -32768, "Lrs": -32767, "Lis": -32766, "His": -32765, "Hrs": -32764}, -32752, 32767),
    "u2": ({"Null": 0, "Lrs": 1, "Lis": 2, "His": 65534, "Hrs": 65535}, 3, 65522),
    "u4": ({"Null": 0, "Lrs": 1, "Lis": 2, "His": 4294967294, "Hrs": 4294967295}, 3, 4294967282),
    # SignedInteger uses the integers whose bits are the Real special values
    # SignedInteger uses the integers whose bits are the Real special values; no valid range
    "i4": ({k: int(np.array([v], np.uint32).view(np.int32)[0]) for k, v in _F4.items()}, -2**31, 2**31 - 1),
}


def special_values(code: str) -> dict[str, float | int]:
    """Stored value of each special pixel for a pixel dtype code (``"f4"``, ``"u1"``, ...)."""
    if code == "f4":
        return {k: float(np.array([v], np.uint32).view(np.float32)[0]) for k, v in _F4.items()}
    if code not in _INTEGER:
        raise CubeFormatError(f"no ISIS special pixels for pixel type {code!r}")
    return dict(_INTEGER[code][0])


def classify(raw: NDArray) -> NDArray[np.int8]:
    """Special-pixel codes (:data:`SPECIAL_CODES`) of stored pixel values (native byte order).

    Values below the valid range that are not one of the five special values count as
    Lrs, as ISIS's ``TestPixel`` does; for Real, non-finite values count as Hrs.
    """
    raw = np.asarray(raw)
    code = raw.dtype.str[1:]
    out = np.zeros(raw.shape, dtype=np.int8)
    if code == "f4":
        bits = raw.view(np.uint32)
        low = raw < _F4_VALID_MIN
        out[low] = SPECIAL_CODES["Lrs"]
        for name, v in _F4.items():
            out[bits == v] = SPECIAL_CODES[name]
        out[~np.isfinite(raw)] = SPECIAL_CODES["Hrs"]
        return out
    if code not in _INTEGER:
        raise CubeFormatError(f"no ISIS special pixels for pixel type {raw.dtype}")
    values, vmin, vmax = _INTEGER[code]
    out[raw < vmin] = SPECIAL_CODES["Lrs"]
    out[raw > vmax] = SPECIAL_CODES["Hrs"]
    # write in this order so that shared values (UnsignedByte) end as Null and Hrs
    for name in ("Lis", "Lrs", "Null", "His", "Hrs"):
        out[raw == values[name]] = SPECIAL_CODES[name]
    return out


def encode_special(raw: NDArray, codes: NDArray) -> NDArray:
    """``raw`` with the special values of ``codes`` (non-zero entries) written in place; returned."""
    table = special_values(raw.dtype.str[1:])
    for name, c in SPECIAL_CODES.items():
        if c == 0:
            continue
        sel = codes == c
        if np.any(sel):
            if raw.dtype.kind == "f":
                raw.view(np.uint32)[sel] = _F4[name]
            else:
                raw[sel] = table[name]
    return raw

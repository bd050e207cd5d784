"""ISIS3-cube-like PVL labels of the synthetic images (label text only, no pixels)."""

from __future__ import annotations

from typing import Any

__all__ = ["isis_label", "isis_label_groups"]


def isis_label(*, samples: int, lines: int, spacecraft_name: str, instrument_id: str,
               start_time: str, stop_time: str, sclk_start: str, naif_frame_code: int,
               line_time_ms: float | None = None, exposure_ms: float | None = None) -> str:
    """The text of an ISIS3 cube label with the keywords camera models read.

    Parameters
    ----------
    samples, lines : int
        Image size, pixels.
    spacecraft_name, instrument_id : str
        ``SpacecraftName`` (quoted) and ``InstrumentId``.
    start_time, stop_time : str
        UTC, ISO calendar format (``2026-03-21T00:18:50.123``).
    sclk_start : str
        ``SpacecraftClockStartCount`` (``1/0006912000:32768``).
    naif_frame_code : int
        ``Kernels/NaifFrameCode``: the instrument id.
    line_time_ms : float, optional
        ``LineExposureDuration`` of a line-scan image, milliseconds.
    exposure_ms : float, optional
        ``ExposureDuration`` of a frame image, milliseconds.

    Returns
    -------
    str
        The label, ending with ``End`` and a newline.
    """
    if (line_time_ms is None) == (exposure_ms is None):
        raise ValueError("give exactly one of line_time_ms (line-scan) and exposure_ms (frame)")
    inst = [
        ("SpacecraftName", f'"{spacecraft_name}"'),
        ("InstrumentId", instrument_id),
        ("TargetName", "MOON"),
        ("StartTime", start_time),
        ("StopTime", stop_time),
        ("SpacecraftClockStartCount", sclk_start),
    ]
    if line_time_ms is not None:
        inst.append(("LineExposureDuration", f"{line_time_ms:.6f} <ms>"))
    else:
        inst.append(("ExposureDuration", f"{exposure_ms:.6f} <ms>"))
    width = max(len(k) for k, _ in inst)
    out = [
        "Object = IsisCube",
        "  Object = Core",
        "    Group = Dimensions",
        f"      Samples = {samples}",
        f"      Lines   = {lines}",
        "      Bands   = 1",
        "    End_Group",
        "  End_Object",
        "",
        "  Group = Instrument",
        *[f"    {k.ljust(width)} = {v}" for k, v in inst],
        "  End_Group",
        "",
        "  Group = Kernels",
        f"    NaifFrameCode = {naif_frame_code}",
        "  End_Group",
        "End_Object",
        "End",
    ]
    return "\n".join(out) + "\n"


def isis_label_groups(*, spacecraft_name: str, instrument_id: str, start_time: str, stop_time: str,
                      sclk_start: str, naif_frame_code: int, line_time_ms: float | None = None,
                      exposure_ms: float | None = None) -> list[Any]:
    """The ``Instrument`` and ``Kernels`` groups of :func:`isis_label` as PVL items, for a cube's label.

    See :func:`isis_label` for the parameters; the items go to :func:`lunarmap.io.write_cube` or
    :class:`lunarmap.io.CubeWriter` (``groups=``), so that a rendered cube carries its own camera keywords.
    """
    from ..io.pvl_write import Unit

    if (line_time_ms is None) == (exposure_ms is None):
        raise ValueError("give exactly one of line_time_ms (line-scan) and exposure_ms (frame)")
    inst: list[Any] = [("SpacecraftName", spacecraft_name), ("InstrumentId", instrument_id), ("TargetName", "MOON"),
                       ("StartTime", start_time), ("StopTime", stop_time), ("SpacecraftClockStartCount", sclk_start)]
    if line_time_ms is not None:
        inst.append(("LineExposureDuration", Unit(float(line_time_ms), "ms")))
    else:
        if exposure_ms is None:
            raise TypeError("isis_label needs line_time_ms or exposure_ms")
        inst.append(("ExposureDuration", Unit(float(exposure_ms), "ms")))
    return [("Group", "Instrument", inst), ("Group", "Kernels", [("NaifFrameCode", int(naif_frame_code))])]

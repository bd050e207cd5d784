"""Adjusted orientation out of an adjustment: ISDs and SPICE kernels that load like any mission.

The adjusted cameras of a :class:`~lunarmap.adjust.block.BlockResult` carry new exterior
orientations; with the images' original image support data (sampled by a driver from the original
kernel set) they become adjusted ISDs (:func:`~lunarmap.orientation.update.updated_image_support`)
and an SPK + CK + meta-kernel layered over the original set
(:func:`~lunarmap.orientation.kernels.write_orientation_kernels`): loading that meta-kernel and
building the cameras from the unchanged labels reproduces the adjusted cameras.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from ..errors import AdjustmentInputError
from ..orientation.isd import ImageSupport
from ..orientation.kernels import write_orientation_kernels
from ..orientation.update import updated_image_support
from ..spice import KernelSet
from .block import BlockResult

__all__ = ["AdjustedOrientation", "adjusted_image_support", "write_adjusted"]


@dataclass
class AdjustedOrientation:
    """Where :func:`write_adjusted` put the adjusted orientation.

    Attributes
    ----------
    metakernel : pathlib.Path
        The original kernels followed by the adjusted SPK and CK.
    isds : dict image name -> pathlib.Path
        Adjusted ISD JSON files (ALE/usgscsm layout).
    """

    metakernel: Path
    isds: dict[str, Path] = field(default_factory=dict)


def adjusted_image_support(result: BlockResult, isds: Mapping[str, ImageSupport]) -> dict[str, ImageSupport]:
    """The adjusted ISD of every image of the block (new objects; ``isds`` are untouched).

    Parameters
    ----------
    result : BlockResult
        A solved block whose sensors are cameras built from ``isds``.
    isds : mapping image name -> ImageSupport
        The original image support data of the block's images.

    Raises
    ------
    AdjustmentInputError
        An image without ISD, or a sensor without an exterior orientation (an RFM).
    """
    missing = [n for n in result.block.names if n not in isds]
    if missing:
        raise AdjustmentInputError(f"no image support data for {len(missing)} image(s): {', '.join(missing[:5])}")
    out = {}
    for name, sensor in result.adjusted_sensors().items():
        eo = getattr(sensor, "eo", None)
        if eo is None:
            raise AdjustmentInputError(f"{name}: {type(sensor).__name__} has no exterior orientation to write back")
        out[name] = updated_image_support(isds[name], eo)
    return out


def write_adjusted(result: BlockResult, isds: Mapping[str, ImageSupport], folder: str | os.PathLike[str],
                   base: KernelSet | str | os.PathLike[str], name: str = "adjusted",
                   write_isds: bool = True) -> AdjustedOrientation:
    """Write the adjusted orientation as SPICE kernels layered over ``base`` and, optionally, ISD JSON files.

    Parameters
    ----------
    result : BlockResult
        The solved block.
    isds : mapping image name -> ImageSupport
        Original image support data of the block's images (made from ``base``).
    folder : path-like
        Existing output folder.
    base : KernelSet or path-like
        The original kernel set or its meta-kernel (never modified).
    name : str
        Base name of ``<name>.bsp``, ``<name>.bc``, ``<name>.tm``; ISDs are ``<image>.<name>.json``.
    write_isds : bool
        Also write the adjusted ISDs.

    Returns
    -------
    AdjustedOrientation
    """
    adjusted = adjusted_image_support(result, isds)
    mk = write_orientation_kernels(list(adjusted.values()), folder, base, name)
    paths = {}
    if write_isds:
        for img, isd in adjusted.items():
            p = Path(folder) / f"{img}.{name}.json"
            isd.write_json(p)
            paths[img] = p
    return AdjustedOrientation(mk, paths)

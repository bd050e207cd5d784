"""Instrument drivers: image label + loaded kernels -> :class:`~lunarmap.orientation.isd.ImageSupport`.

Drivers are the last step that talks to SPICE. :func:`image_support` is the
one-call entry point::

    from lunarmap.orientation.drivers import image_support
    isd = image_support("M103595705LE_isis3.lbl", "lro_nac.tm")
    eo = isd.exterior_orientation()
"""

from __future__ import annotations

import os
from typing import Callable

from ...errors import UnknownInstrumentError
from ...labels import Label, load_label
from ...spice import KernelSet, kernels
from ..isd import ImageSupport

# historical film cameras (issue 13)
from .apollo import ApolloMetricDriver
from .base import Driver

# issue 26
from .chandrayaan import Chandrayaan1M3Driver, Chandrayaan1M3Pds3Driver, Chandrayaan2OhrcDriver, Chandrayaan2TmcDriver
from .clementine import ClementineDriver, ClementineUvvisDriver
from .generic import GenericDriver
from .kaguya import KaguyaMiDriver, KaguyaTcDriver
from .lro import LroNacDriver, LroNacPds3Driver
from .lro_minirf import LroMiniRfDriver
from .lro_wac import LroWacDriver
from .lunar_orbiter import LunarOrbiterHighDriver, LunarOrbiterMediumDriver

__all__ = ["Driver", "LroNacDriver", "LroNacPds3Driver", "ClementineUvvisDriver", "KaguyaTcDriver", "GenericDriver",
           "LunarOrbiterHighDriver", "ApolloMetricDriver", "LroWacDriver", "LroMiniRfDriver",
           "ClementineDriver", "Chandrayaan2OhrcDriver", "Chandrayaan2TmcDriver", "Chandrayaan1M3Driver",
           "Chandrayaan1M3Pds3Driver", "KaguyaMiDriver", "LunarOrbiterMediumDriver",
           "DRIVERS", "UNSUPPORTED_LABELS", "driver_for", "image_support", "radar_label"]

#: Drivers in the order they are asked; the generic IK-configured driver is last.
DRIVERS: list[type[Driver]] = [LroNacDriver, LroNacPds3Driver, ClementineDriver, KaguyaTcDriver,
                               LunarOrbiterHighDriver, ApolloMetricDriver, LroWacDriver, LroMiniRfDriver,
                               Chandrayaan2OhrcDriver, Chandrayaan2TmcDriver, Chandrayaan1M3Driver,
                               Chandrayaan1M3Pds3Driver, KaguyaMiDriver, LunarOrbiterMediumDriver, GenericDriver]


def _kaguya_tc_isis(label: Label) -> bool:
    inst = Driver.isis_instrument(label)
    return inst is not None and str(inst.get("SpacecraftName", "")).upper() in ("KAGUYA", "SELENE") and \
        str(inst.get("InstrumentId", "")).upper() in ("TC1", "TC2")


_RADAR_WORDS = ("MINI-RF", "MINIRF", "MRFLRO", "MINI_RF", "SAR", "RADAR", "DFSAR")


def radar_label(label: Label) -> str | None:
    """The instrument named by a radar (SAR) label, or ``None``: a radar is not a camera, and lunarmap
    models one radar (LRO Mini-RF from its ISIS cube label, :class:`LroMiniRfDriver`)."""
    names = [str(label.find(k) or "") for k in ("InstrumentId", "INSTRUMENT_ID", "InstrumentName", "INSTRUMENT_NAME")]
    upper = " ".join(names).upper().replace("(", " ").replace(")", " ")
    if any(w in upper.split() or w in upper.replace(" ", "") for w in _RADAR_WORDS[:4]) or \
            any(w in upper.split() for w in _RADAR_WORDS[4:]) or \
            any(label.find(k) is not None for k in ("RangeCoefficientSet", "LookDirection", "RANGE_COEFFICIENT_SET")):
        return next((n for n in names if n), "radar")
    return None


def _radar_message(label: Label, source: str) -> str:
    return (f"label {source}: {radar_label(label)!r} is a radar (SAR) instrument, not a camera; lunarmap supports "
            "LRO Mini-RF from its ISIS cube label (mrf2isis + spiceinit) only: other radar labels are not supported "
            "yet")


#: Labels of cameras lunarmap models from another label kind only. They are refused by
#: name after the specific drivers and before :class:`GenericDriver`, which would
#: otherwise claim them (they are ISIS labels with a NAIF frame code) and fail deep
#: inside SPICE, or worse, succeed with the wrong conventions.
UNSUPPORTED_LABELS: list[tuple[Callable[[Label], bool], str]] = [
    (_kaguya_tc_isis, "Kaguya TC is supported from its PDS3 level-2B0 label only (the ISIS label's start time "
                      "and detector keywords are not read); give the PDS3 label"),
]
#: Radar labels that no specific driver claimed are named as radars (not "no focal length in the IK").
UNSUPPORTED_LABELS.append((lambda lab: radar_label(lab) is not None, "RADAR"))


def driver_for(label: Label, source: str = "") -> Driver:
    """The driver that claims ``label``.

    Raises
    ------
    UnknownInstrumentError
        No driver recognises the label (instrument, spacecraft and label type are named),
        the label is one of :data:`UNSUPPORTED_LABELS`, or the driver that claims it
        refuses the camera (an LROC PDS3 label of the WAC).
    LabelError
        The claiming driver finds the label unusable before loading kernels.
    """
    for cls in DRIVERS:
        if cls is GenericDriver:
            for refuses, why in UNSUPPORTED_LABELS:
                if refuses(label):
                    raise UnknownInstrumentError(_radar_message(label, source) if why == "RADAR"
                                                 else f"label {source}: {why}")
        if cls.matches(label):
            return cls(label, source)
    if radar_label(label) is not None:
        raise UnknownInstrumentError(_radar_message(label, source))
    inst = label.find("InstrumentId") or label.find("INSTRUMENT_ID") or "?"
    host = label.find("SpacecraftName") or label.find("MISSION_NAME") or "?"
    raise UnknownInstrumentError(f"no lunarmap driver for instrument {inst!r} of {host!r} in label {source}; "
                                 f"known: {', '.join(c.name for c in DRIVERS)}")


def image_support(label: str | os.PathLike[str] | Label, kernel_set: KernelSet | str | os.PathLike[str]) -> ImageSupport:
    """Read a label, load the kernels (under the SPICE lock) and sample the image's geometry.

    Parameters
    ----------
    label : path-like or Label
        ISIS cube / label file or PDS3 label, or an already parsed label.
    kernel_set : KernelSet or path-like
        A kernel set or the path of a meta-kernel.

    Returns
    -------
    ImageSupport
        The image's support data: times, positions, velocities, attitudes, instrument model
        (write it with ``write_json``; build its camera with :func:`lunarmap.camera_from_isd`).

    Raises
    ------
    UnknownInstrumentError
        A label of an instrument lunarmap has no driver for (a radar such as Mini-RF is named as
        such: not supported yet).
    MissingKernelError
        A kernel the instrument needs is not in the kernel set.
    """
    source = "" if isinstance(label, Label) else os.fspath(label)
    lab = label if isinstance(label, Label) else load_label(label)
    kset = kernel_set if isinstance(kernel_set, KernelSet) else KernelSet.from_metakernel(kernel_set)
    driver = driver_for(lab, source)
    with kernels(kset):
        isd = driver.image_support()
    isd.provenance["kernels"] = kset.source or ";".join(kset.paths)
    return isd

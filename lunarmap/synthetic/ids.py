"""Names and NAIF ids of the fictional LUNARMAP-SIM mission.

The ids live in the otherwise unused ``-990xxx`` range: spacecraft ``-990``
(also its clock), bus frame ``-990000`` and instruments ``-990100`` /
``-990200`` (each instrument's frame has the instrument's id, as for LRO).
"""

from __future__ import annotations

__all__ = [
    "SPACECRAFT_NAME", "SPACECRAFT_ID", "SCLK_ID", "BUS_FRAME", "BUS_FRAME_ID",
    "NAC_NAME", "NAC_ID", "NAC_FRAME", "FRAME_CAMERA_NAME", "FRAME_CAMERA_ID", "FRAME_CAMERA_FRAME",
    "MOON_ID", "SUN_ID", "SSB_ID", "MOON_FRAME", "INERTIAL_FRAME",
    "KW_CAMERA_TYPE", "KW_DISTORTION_MODEL", "KW_LIGHTTIME_CORRECTION",
    "IMAGE_NAMES", "KERNEL_FILES", "METAKERNEL_NAME", "MANIFEST_NAME",
]

SPACECRAFT_NAME = "LUNARMAP-SIM"
SPACECRAFT_ID = -990
#: The spacecraft clock id (SPICE's default for CK frame -990000 is -990000/1000).
SCLK_ID = -990

BUS_FRAME = "SIM_SC_BUS"
BUS_FRAME_ID = -990000

NAC_NAME = "SIM_NAC"
NAC_ID = -990100
NAC_FRAME = "SIM_NAC"

FRAME_CAMERA_NAME = "SIM_FRAME"
FRAME_CAMERA_ID = -990200
FRAME_CAMERA_FRAME = "SIM_FRAME"

MOON_ID = 301
SUN_ID = 10
SSB_ID = 0
MOON_FRAME = "IAU_MOON"
INERTIAL_FRAME = "J2000"

#: IK keyword suffixes (``INS<id>_<suffix>``) read by lunarmap. SPICE limits
#: pool names to 32 characters, so with a 7-character id
#: ``INS-990100_LUNARMAP_DISTORTION_MODEL`` (36) cannot exist; the distortion
#: model keyword is therefore ``LUNARMAP_DISTORTION``.
KW_CAMERA_TYPE = "LUNARMAP_CAMERA_TYPE"
KW_DISTORTION_MODEL = "LUNARMAP_DISTORTION"
KW_LIGHTTIME_CORRECTION = "LIGHTTIME_CORRECTION"

#: The predefined images, in time order of definition.
IMAGE_NAMES = ("sim_nac_equator", "sim_nac_flipped", "sim_nac_85n", "sim_frame_a", "sim_frame_b")

#: Kernel files written by :func:`lunarmap.synthetic.write_mission`, in load order.
KERNEL_FILES = (
    "lunarmap_sim.tls",
    "lunarmap_sim.tsc",
    "lunarmap_sim.tpc",
    "lunarmap_sim.tf",
    "lunarmap_sim_nac.ti",
    "lunarmap_sim_frame.ti",
    "lunarmap_sim_planets.bsp",
    "lunarmap_sim_orbit.bsp",
    "lunarmap_sim_bus.bc",
)
METAKERNEL_NAME = "synthetic_mission.tm"
MANIFEST_NAME = "mission.json"

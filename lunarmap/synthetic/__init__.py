"""A synthetic lunar mission (LUNARMAP-SIM) with self-consistent SPICE kernels, for tests and examples.

:func:`write_mission` writes the kernel set (LSK, SCLK, PCK, FK, two IKs, two
SPKs, one CK), ISIS-like labels of five predefined images and a
``mission.json`` manifest, and returns the meta-kernel path;
:func:`build_mission` gives the numpy truth model behind the kernels.

:func:`write_block_mission` writes a second scenario: an imaging block of one
site seen on consecutive orbits by three cameras (NAC-like and Kaguya-TC-like
pushbrooms, a Clementine-like frame camera), with TRUTH and NAVIGATION
kernel sets (the latter with per-orbit position and attitude errors), or
of several sites along each orbit's ground track (``sites=n``);
:func:`build_block_model` is its numpy model.
"""

from .block import BlockImagePlan, BlockModel, BlockPass, BlockSite, block_geometry, build_block_model
from .block_cameras import BLOCK_CAMERAS, BLOCK_FRAME, BLOCK_NAC, BLOCK_TC, BlockCameraSpec
from .block_writing import (
                            BLOCK_MANIFEST_NAME,
                            NAVIGATION_METAKERNEL,
                            TRUTH_METAKERNEL,
                            BlockMission,
                            open_block_mission,
                            write_block_mission,
)
from .cameras import FRAME_CAMERA, NAC, CameraSpec
from .ids import (
                            BUS_FRAME,
                            BUS_FRAME_ID,
                            FRAME_CAMERA_FRAME,
                            FRAME_CAMERA_ID,
                            FRAME_CAMERA_NAME,
                            IMAGE_NAMES,
                            INERTIAL_FRAME,
                            KERNEL_FILES,
                            KW_CAMERA_TYPE,
                            KW_DISTORTION_MODEL,
                            KW_LIGHTTIME_CORRECTION,
                            MANIFEST_NAME,
                            METAKERNEL_NAME,
                            MOON_FRAME,
                            MOON_ID,
                            NAC_FRAME,
                            NAC_ID,
                            NAC_NAME,
                            SCLK_ID,
                            SPACECRAFT_ID,
                            SPACECRAFT_NAME,
                            SSB_ID,
                            SUN_ID,
)
from .mission import ImagePlan, SimMission, build_mission
from .nav_errors import NavigationErrors, NavigationErrorSpec
from .writing import load_manifest, write_mission

__all__ = [
    "write_mission", "build_mission", "load_manifest", "SimMission", "ImagePlan", "CameraSpec", "NAC",
    "FRAME_CAMERA", "SPACECRAFT_NAME", "SPACECRAFT_ID", "SCLK_ID", "BUS_FRAME", "BUS_FRAME_ID",
    "NAC_NAME", "NAC_ID", "NAC_FRAME", "FRAME_CAMERA_NAME", "FRAME_CAMERA_ID", "FRAME_CAMERA_FRAME",
    "MOON_ID", "SUN_ID", "SSB_ID", "MOON_FRAME", "INERTIAL_FRAME", "KW_CAMERA_TYPE",
    "KW_DISTORTION_MODEL", "KW_LIGHTTIME_CORRECTION", "IMAGE_NAMES", "KERNEL_FILES", "METAKERNEL_NAME",
    "MANIFEST_NAME",
    "write_block_mission", "open_block_mission", "BlockMission", "build_block_model", "BlockModel", "BlockPass",
    "BlockSite", "BlockImagePlan", "block_geometry", "BlockCameraSpec", "BLOCK_NAC", "BLOCK_TC", "BLOCK_FRAME",
    "BLOCK_CAMERAS",
    "NavigationErrorSpec", "NavigationErrors", "BLOCK_MANIFEST_NAME", "TRUTH_METAKERNEL", "NAVIGATION_METAKERNEL",
]

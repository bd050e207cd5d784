"""Simulation with known truth: terrain and albedo, a DTM + orthoimage renderer (numpy, and compiled for
full-size images written into ISIS cubes stripe by stripe), stereo geometry, adjustment blocks."""

from ..errors import SimulationWarning
from .albedo import TiledAlbedo, tiled_albedo
from .altimetry import SimulatedAltimetry, altimetry_tracks
from .blocks import Measurements, SimulatedBlock, frame_block, frame_block_height, linescan_site, local_enu, observe
from .compiled_render import RenderedCube, RenderScene, render_cube, render_window
from .dlr import Blunders, DlrSimulation, dlr_block, inject_blunders
from .mission import RenderedBlock, block_cameras, block_check_points, block_scene, render_block, render_block_cubes
from .reference_dtm import SimulatedDtm, reference_dtm
from .render import RenderSpec, render_image, surface_normals
from .sampling import RasterSampler
from .site import APOLLO11_LIKE, SimulatedSite, SiteImageSpec, lroc_site
from .stereo import look_angle_for_emission, pointed_camera, stereo_pair
from .terrain import (
    add_craters,
    local_grid,
    rolling_terrain,
    synthetic_albedo,
    synthetic_dtm,
    synthetic_scene,
)
from .truth import matching_errors, true_conjugates

__all__ = [
    "render_image", "RenderSpec", "surface_normals", "RasterSampler", "SimulationWarning",
    "local_grid", "rolling_terrain", "add_craters", "synthetic_dtm", "synthetic_albedo", "synthetic_scene",
    "look_angle_for_emission", "pointed_camera", "stereo_pair", "true_conjugates", "matching_errors",
    "Measurements", "SimulatedBlock", "frame_block", "linescan_site", "local_enu", "observe",
    "render_block", "RenderedBlock", "block_scene", "block_cameras", "block_check_points", "render_block_cubes",
    "render_cube", "render_window", "RenderScene", "RenderedCube", "TiledAlbedo", "tiled_albedo",
    "lroc_site", "SimulatedSite", "SiteImageSpec", "APOLLO11_LIKE",
    "dlr_block", "inject_blunders", "DlrSimulation", "Blunders",
    "frame_block_height", "reference_dtm", "SimulatedDtm", "altimetry_tracks", "SimulatedAltimetry",
]

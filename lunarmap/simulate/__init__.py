"""Image simulation with known truth: synthetic terrain and albedo, and a DTM + orthoimage renderer."""

from ..errors import SimulationWarning
from .block import RenderedBlock, block_cameras, block_check_points, block_scene, render_block
from .render import RenderSpec, render_image, surface_normals
from .sampling import RasterSampler
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
    "render_block", "RenderedBlock", "block_scene", "block_cameras", "block_check_points",
]

"""Image and network files of the planetary mapping world: ISIS cubes, PDS3 images, GeoTIFF, ISIS control networks.

* :mod:`lunarmap.io.cube`: ISIS cubes (label, lazily chunked pixels as ``xarray.DataArray``,
  special pixels, tables; writing cubes, whole or stripe by stripe, and copies with replaced tables);
* :mod:`lunarmap.io.raster`: one entry point for ISIS cubes, PDS3 ``.IMG`` and GeoTIFF pixels;
* :mod:`lunarmap.io.altimetry`: laser-altimetry shot tables (LOLA RDR-like CSV / netCDF);
* :mod:`lunarmap.io.isis_network`: ISIS control networks (binary protobuf versions 2 and 5,
  PVL) to and from the project's control-network ``xarray.Dataset``.

This package sits beside :mod:`lunarmap.labels` in the layering: it imports nothing but
``labels``. Cameras from cubes are :func:`lunarmap.camera.cube.camera_from_cube`; control
networks as :class:`~lunarmap.adjust.network.ControlNetwork` are in :mod:`lunarmap.adjust.isis`.
"""

from .altimetry import AltimetryShots, read_altimetry, write_altimetry
from .cube import CubeWriter, IsisCube, Table, copy_cube_with_tables, open_cube, write_cube
from .isis_network import read_isis_network, write_isis_network
from .isis_network_pvl import write_pvl_network
from .raster import open_image
from .special import SPECIAL_CODES

__all__ = ["IsisCube", "Table", "open_cube", "write_cube", "CubeWriter", "copy_cube_with_tables", "SPECIAL_CODES", "open_image",
           "read_isis_network", "write_isis_network", "write_pvl_network", "AltimetryShots", "read_altimetry",
           "write_altimetry"]

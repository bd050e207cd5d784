"""lunarmap: planetary photogrammetry from SPICE kernels to adjusted orientations.

Conventions
-----------
=====================  ==========================================================
quantity               unit / convention
=====================  ==========================================================
time                   ephemeris time (ET, TDB seconds past J2000) internally;
                       UTC only at input/output
ground coordinates     body-fixed Cartesian, **metres** (labels and ISDs use km)
lat / lon              planetocentric, degrees at the API surface, east-positive
height                 metres above the reference sphere/ellipsoid
image coordinates      ``(line, sample)``, pixels, USGS CSM convention: the centre
                       of the first pixel is ``(0.5, 0.5)`` (ISIS: ``(1, 1)``)
focal plane            millimetres, NAIF instrument frame, boresight +z
quaternions            SPICE order ``(w, x, y, z)``
=====================  ==========================================================

Data flow: ``spice`` (kernels) -> ``orientation`` -> ``camera`` -> rpc -> matching
-> adjust -> evaluate -> workflows. Nothing after ``orientation`` calls SPICE.
"""

from . import errors
from .errors import LunarmapError

__version__ = "0.1.0"

__all__ = ["errors", "LunarmapError", "__version__"]

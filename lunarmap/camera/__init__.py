"""Sensor models: the SensorModel protocol, interior orientation, distortion, frame, line-scan and push-frame
cameras, SAR, their correction parameters."""

from .corrections import (
    AffineCorrectedSensor,
    AffineCorrections,
    FrameCorrections,
    LineScanCorrections,
    PushFrameCorrections,
)
from .csm import USGSCSM_DISTORTIONS, csm_image_support
from .distortion import (
    DISTORTION_MODELS,
    Distortion,
    KaguyaLismDistortion,
    LroNacDistortion,
    NoDistortion,
    RadialDistortion,
    distortion_from_interior,
    make_distortion,
)
from .distortion_csm import (  # registers usgscsm's transverse, radtan, dawnfc, kplo_shadowcam
    DawnFcDistortion,
    RadTanDistortion,
    ShadowCamDistortion,
    TransverseDistortion,
    fit_transverse,
)
from .factory import camera_from_isd, camera_from_isd_file, load_camera
from .frame import FrameCamera, focal_to_image, image_to_focal
from .geodesy import (
    enu_basis,
    lonlat_height_to_xyz,
    moon_geocentric_crs,
    moon_geographic_crs,
    pyproj_lonlat_height_to_xyz,
    pyproj_xyz_to_lonlat_height,
    xyz_to_lonlat_height,
)
from .interior import InteriorOrientation
from .intersect import DtmSampler, intersect_dtm, intersect_ellipsoid, intersect_sphere
from .linescan import LineScanCamera, LineTimes
from .pushframe import FrameletTiming, PushFrameCamera
from .sar import RangeConversion, SarCorrections, SarSensor
from .sensor import Corrections, SensorModel
from .shape import MOON_RADIUS, MOON_RADIUS_HISTORICAL, Shape

__all__ = [
    "InteriorOrientation",
    "Distortion", "NoDistortion", "LroNacDistortion", "RadialDistortion", "KaguyaLismDistortion",
    "DISTORTION_MODELS", "make_distortion", "distortion_from_interior",
    "TransverseDistortion", "RadTanDistortion", "DawnFcDistortion", "ShadowCamDistortion", "fit_transverse",
    "Shape", "MOON_RADIUS", "MOON_RADIUS_HISTORICAL",
    "xyz_to_lonlat_height", "lonlat_height_to_xyz", "pyproj_xyz_to_lonlat_height",
    "pyproj_lonlat_height_to_xyz", "moon_geographic_crs", "moon_geocentric_crs", "enu_basis",
    "intersect_ellipsoid", "intersect_sphere", "intersect_dtm", "DtmSampler",
    "FrameCamera", "image_to_focal", "focal_to_image",
    "LineScanCamera", "LineTimes",
    "PushFrameCamera", "FrameletTiming", "PushFrameCorrections",
    "SarSensor", "SarCorrections", "RangeConversion",
    "camera_from_isd", "camera_from_isd_file", "load_camera", "csm_image_support", "USGSCSM_DISTORTIONS",
    "SensorModel", "Corrections", "FrameCorrections", "LineScanCorrections", "AffineCorrections",
    "AffineCorrectedSensor",
]

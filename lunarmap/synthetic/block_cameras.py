"""The three cameras of the synthetic imaging block: NAC-like and Kaguya-TC-like pushbrooms, a Clementine-like frame.

All three sit on the LUNARMAP-SIM bus and have an instantaneous field of view
of about 20 microradians, i.e. a ground sample distance of about 1 m from the
50 km orbit, so that one DTM and albedo map serve all images and any two
images can be matched against each other. Detector sizes are small
(512 or 384 pixels across) so that a whole block renders in about a minute.

Each camera carries a real distortion model, scaled to its small focal plane
so that it moves the outermost pixels by about one pixel (and so matters):

* ``SIM_BLK_NAC`` - LRO NAC's ``lrolrocnac`` model, ``dy = uy (1 + k1 uy^2)``
  approximately; ``k1 = 1.2e-3 mm^-2`` moves the detector ends
  (``|y| = 1.792 mm``) by ``k1 y^3 = 6.9e-3 mm = 0.99 px`` (LRO NAC-L: 1.81e-5).
* ``SIM_BLK_TC`` - Kaguya TC's ``kaguyalism`` model with TC1's coefficients
  (``SEL_TC_V01.TI``, ``INS-131351_DISTORTION_COEF_X/Y`` and ``BORESIGHT``)
  rescaled from TC1's 14.3 mm half-detector to this 1.79 mm one:
  ``a_k' = c a_k s^k`` with ``s = 14.336 / 1.792 = 8`` (so the polynomial has
  TC1's shape across the detector) and ``c = 0.37`` (so its size is about one
  pixel: the across-track term reaches 0.37 * 18.9 um = 7.0 um = 1.0 px at the
  detector ends); the boresight offsets are TC1's times ``c``.
* ``SIM_BLK_FRAME`` - the ISIS ``OD_K`` radial model of Clementine UVVIS with
  ``k1 = -9.4e-5 mm^-2`` (UVVIS: -2.42e-5): at the corners (``r = 6.25 mm``)
  ``|k1| r^3 = 0.023 mm = 1.0 px``.

Mountings: the NAC looks along the bus +z axis; the TC is pitched forward and
the frame camera aft by :data:`PITCH_DEG` about the bus +y axis (so within
one orbit the TC sees the site a few seconds before the NAC and the frame
camera a few seconds after it); every camera also has a random misalignment
of a few hundredths of a degree drawn from the mission seed.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..camera.distortion import Distortion, make_distortion
from .cameras import CameraSpec

__all__ = [
    "BlockCameraSpec", "BLOCK_NAC", "BLOCK_TC", "BLOCK_FRAME", "BLOCK_CAMERAS", "PITCH_DEG",
    "BLK_NAC_NAME", "BLK_NAC_ID", "BLK_TC_NAME", "BLK_TC_ID", "BLK_FRAME_NAME", "BLK_FRAME_ID",
    "KAGUYA_TC1_COEF_X", "KAGUYA_TC1_COEF_Y", "KAGUYA_TC1_BORESIGHT_MM", "KAGUYA_SCALE_RADIUS",
    "KAGUYA_SCALE_SIZE", "FULL_NACL", "FULL_NACR", "FULL_SIZE_CAMERAS", "FULL_NAC_ROLL_DEG", "FULL_NAC_LINES",
    "FULL_NACL_NAME", "FULL_NACL_ID", "FULL_NACR_NAME", "FULL_NACR_ID",
]

BLK_NAC_NAME = "SIM_BLK_NAC"
BLK_NAC_ID = -990300
BLK_TC_NAME = "SIM_BLK_TC"
BLK_TC_ID = -990400
BLK_FRAME_NAME = "SIM_BLK_FRAME"
BLK_FRAME_ID = -990500
FULL_NACL_NAME = "SIM_FULL_NACL"
FULL_NACL_ID = -990600
FULL_NACR_NAME = "SIM_FULL_NACR"
FULL_NACR_ID = -990610

#: Forward pitch of the TC and aft pitch of the frame camera relative to the bus, degrees.
PITCH_DEG = 6.0

#: Kaguya TC1 distortion coefficients (SEL_TC_V01.TI, INS-131351_DISTORTION_COEF_X/Y): mm, 1, 1/mm, 1/mm^2.
KAGUYA_TC1_COEF_X = (-9.6499e-4, 9.8441e-4, 8.5773e-6, -3.7438e-6)
KAGUYA_TC1_COEF_Y = (-1.3796e-3, 1.3502e-5, 2.7251e-6, -6.1938e-6)
#: Kaguya TC1 boresight offsets (INS-131351_BORESIGHT x, y), mm.
KAGUYA_TC1_BORESIGHT_MM = (-0.0725, 0.0214)
#: Radius scale of the TC1 polynomials: TC1 half-detector (2048 px * 7 um) over SIM_BLK_TC's (256 px * 7 um).
KAGUYA_SCALE_RADIUS = 8.0
#: Size scale of the rescaled TC1 distortion (about 1 px at the detector ends).
KAGUYA_SCALE_SIZE = 0.37


def _scaled(coef: tuple[float, ...]) -> tuple[float, ...]:
    """TC1 coefficients rescaled to SIM_BLK_TC's focal plane, 5 significant digits."""
    return tuple(float(f"{KAGUYA_SCALE_SIZE * c * KAGUYA_SCALE_RADIUS ** k:.5g}") for k, c in enumerate(coef))


@dataclass(frozen=True)
class BlockCameraSpec(CameraSpec):
    """A block camera: :class:`CameraSpec` plus its nominal mounting and Kaguya-style distortion terms.

    Parameters
    ----------
    nominal_angles_deg : tuple of 3 float
        TK ``ANGLES`` (about bus x, y, z; SPICE axes 1, 2, 3) before the
        seed's misalignment, degrees.
    coef_x, coef_y : tuple of float
        ``kaguyalism`` coefficients ``(a0..a3)``, ``(b0..b3)`` (IK
        ``DISTORTION_COEF_X/Y``): mm, 1, 1/mm, 1/mm^2; empty for other models.
    boresight_offset_mm : tuple of 2 float
        ``kaguyalism`` boresight offsets, mm (written into the IK's
        ``BORESIGHT`` as ``(x/f, y/f, 1)``).
    """

    nominal_angles_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    coef_x: tuple[float, ...] = ()
    coef_y: tuple[float, ...] = ()
    boresight_offset_mm: tuple[float, float] = (0.0, 0.0)

    def distortion(self) -> Distortion:
        """The lunarmap distortion model this camera's IK describes."""
        if self.distortion_model == "kaguyalism":
            return make_distortion("kaguyalism", {"x": list(self.coef_x), "y": list(self.coef_y),
                                                  "boresight_x": self.boresight_offset_mm[0],
                                                  "boresight_y": self.boresight_offset_mm[1]})
        if self.distortion_model == "lrolrocnac":
            return make_distortion("lrolrocnac", {"coefficients": [self.od_k[0]]})
        return make_distortion(self.distortion_model, {"coefficients": list(self.od_k)})

    @property
    def kind(self) -> str:
        """``'nac'``, ``'tc'`` or ``'frame'``: the short name used in image names."""
        return {BLK_NAC_ID: "nac", BLK_TC_ID: "tc", BLK_FRAME_ID: "frame", FULL_NACL_ID: "nacl",
                FULL_NACR_ID: "nacr"}[self.naif_id]


_LS_PITCH = 0.007  # mm, the LRO NAC and Kaguya TC pixel pitch
_FR_PITCH = 0.023  # mm, Clementine UVVIS's

#: LRO-NAC-like pushbroom: detector line along +y (sample), time along +x, as the LROC IK.
BLOCK_NAC = BlockCameraSpec(
    name=BLK_NAC_NAME, naif_id=BLK_NAC_ID, camera_type="LINESCAN", samples=512, lines=1,
    focal_length_mm=350.0, pixel_pitch_mm=_LS_PITCH, boresight_sample=256.5, boresight_line=0.0,
    transx=(0.0, 0.0, _LS_PITCH), transy=(0.0, _LS_PITCH, 0.0),
    distortion_model="lrolrocnac", od_k=(1.2e-3,),
    description="pushbroom, 512 samples, f = 350 mm, 7 um pixels (LRO NAC-like, 20 urad IFOV).",
)

#: Kaguya-TC-like pushbroom: samples run along -y, as in the Kaguya TC IK addendum (TRANSY = (0, -p, 0)).
BLOCK_TC = BlockCameraSpec(
    name=BLK_TC_NAME, naif_id=BLK_TC_ID, camera_type="LINESCAN", samples=512, lines=1,
    focal_length_mm=345.0, pixel_pitch_mm=_LS_PITCH, boresight_sample=256.5, boresight_line=0.0,
    transx=(0.0, 0.0, _LS_PITCH), transy=(0.0, -_LS_PITCH, 0.0),
    distortion_model="kaguyalism", od_k=(0.0,),
    description="pushbroom, 512 samples, f = 345 mm, 7 um pixels (Kaguya-TC-like, pitched forward).",
    nominal_angles_deg=(0.0, -PITCH_DEG, 0.0),
    coef_x=_scaled(KAGUYA_TC1_COEF_X), coef_y=_scaled(KAGUYA_TC1_COEF_Y),
    boresight_offset_mm=(KAGUYA_SCALE_SIZE * KAGUYA_TC1_BORESIGHT_MM[0],
                         KAGUYA_SCALE_SIZE * KAGUYA_TC1_BORESIGHT_MM[1]),
)

#: Clementine-UVVIS-like framing camera: samples along +x (along track), lines along +y.
BLOCK_FRAME = BlockCameraSpec(
    name=BLK_FRAME_NAME, naif_id=BLK_FRAME_ID, camera_type="FRAME", samples=384, lines=384,
    focal_length_mm=1150.0, pixel_pitch_mm=_FR_PITCH, boresight_sample=192.5, boresight_line=192.5,
    transx=(0.0, _FR_PITCH, 0.0), transy=(0.0, 0.0, _FR_PITCH),
    distortion_model="radial", od_k=(0.0, -9.4e-5, 0.0),
    description="framing, 384 x 384 pixels, f = 1150 mm, 23 um pixels (Clementine-UVVIS-like, pitched aft).",
    nominal_angles_deg=(0.0, PITCH_DEG, 0.0),
)

#: The block's cameras in IK/FK order.
BLOCK_CAMERAS = (BLOCK_NAC, BLOCK_TC, BLOCK_FRAME)


#: Roll of the full-size NAC-L (+) and NAC-R (-) about the bus +x axis, degrees: their fields of view
#: (5,064 x ~10 urad = 2.9 degrees each, principal points off-centre as LRO's) meet across the bus
#: +z axis, their footprints overlapping by about 70 m (140 pixels), as LRO's two NACs' do.
FULL_NAC_ROLL_DEG = 1.42
#: Lines of a full-size NAC image (an LRO NAC EDR's 52,224).
FULL_NAC_LINES = 52224

#: Full-size LRO-NAC-L-like pushbroom: LRO's IK values (LRO_LROC_V18.TI: f, principal point, OD_K,
#: TRANSX/TRANSY); about 0.5 m pixels from the block's ~50 km orbit.
FULL_NACL = BlockCameraSpec(
    name=FULL_NACL_NAME, naif_id=FULL_NACL_ID, camera_type="LINESCAN", samples=5064, lines=1,
    focal_length_mm=699.62, pixel_pitch_mm=_LS_PITCH, boresight_sample=2548.0, boresight_line=0.0,
    transx=(0.0, 0.0, _LS_PITCH), transy=(0.0, _LS_PITCH, 0.0),
    distortion_model="lrolrocnac", od_k=(1.81e-5,),
    description="pushbroom, 5064 samples, f = 699.62 mm, 7 um pixels (LRO NAC-L's IK values).",
    nominal_angles_deg=(FULL_NAC_ROLL_DEG, 0.0, 0.0),
)

#: Full-size LRO-NAC-R-like pushbroom: LRO's NAC-R frame is turned 180 degrees about its boresight
#: and its TRANSX/TRANSY are negated (LRO_LROC_V18.TI), so its samples run the same way as NAC-L's.
FULL_NACR = BlockCameraSpec(
    name=FULL_NACR_NAME, naif_id=FULL_NACR_ID, camera_type="LINESCAN", samples=5064, lines=1,
    focal_length_mm=701.57, pixel_pitch_mm=_LS_PITCH, boresight_sample=2496.0, boresight_line=0.0,
    transx=(0.0, 0.0, -_LS_PITCH), transy=(0.0, -_LS_PITCH, 0.0),
    distortion_model="lrolrocnac", od_k=(1.83e-5,),
    description="pushbroom, 5064 samples, f = 701.57 mm, 7 um pixels (LRO NAC-R's IK values).",
    nominal_angles_deg=(-FULL_NAC_ROLL_DEG, 0.0, 180.0),
)

#: The full-size layout's cameras in IK/FK order.
FULL_SIZE_CAMERAS = (FULL_NACL, FULL_NACR)

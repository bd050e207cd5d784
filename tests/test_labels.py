"""PVL label reading and driver selection."""

from __future__ import annotations

import pytest

from lunarmap.errors import LabelError, UnknownInstrumentError
from lunarmap.labels import Quantity, load_label, parse_label
from lunarmap.orientation.drivers import GenericDriver, LroNacDriver, driver_for

ISIS = """Object = IsisCube
  Object = Core
    Group = Dimensions
      Samples = 5064
      Lines   = 400
    End_Group
  End_Object
  Group = Instrument
    SpacecraftName = "LUNAR RECONNAISSANCE ORBITER"
    InstrumentHostId = LRO
    InstrumentName = "LUNAR RECONNAISSANCE ORBITER NARROW ANGLE
                      CAMERA LEFT"
    InstrumentId = NACL
    LineExposureDuration = 1.028800 <ms>
    ShapeModel = $base/dems/ldem_128ppd_radius-
                 _pad.cub
    Fiducials = (1.0, 2.5,
                 3) <pixels>
  End_Group
End_Object
End
"""


def test_isis_label_values():
    lab = parse_label(ISIS)
    inst = lab["IsisCube"]["Instrument"]
    assert inst["InstrumentName"] == "LUNAR RECONNAISSANCE ORBITER NARROW ANGLE CAMERA LEFT"
    assert isinstance(inst["LineExposureDuration"], Quantity)
    assert inst["LineExposureDuration"] == 1.0288 and inst["LineExposureDuration"].unit == "ms"
    assert inst["ShapeModel"] == "$base/dems/ldem_128ppd_radius_pad.cub"
    assert inst["Fiducials"] == [1.0, 2.5, 3.0] and inst["Fiducials"][0].unit == "pixels"
    assert lab["isiscube"]["core"]["dimensions"]["lines"] == 400  # case-insensitive
    assert isinstance(driver_for(lab), LroNacDriver)


def test_pds3_label_objects():
    lab = parse_label('PDS_VERSION_ID = PDS3\n/* comment */\nA = (6.5 <ms>)\nOBJECT = IMAGE\n  LINES = 400\n'
                      'END_OBJECT = IMAGE\nEND\n')
    assert lab["IMAGE"]["LINES"] == 400 and lab["A"][0] == 6.5


@pytest.mark.parametrize("text, what", [
    ("Object = IsisCube\n  Group = X\n    A = 1\n  End_Object\nEnd\n", "does not close"),
    ("Object = IsisCube\n  A = 1\n", "never closed"),
    ("A = (1, 2\nEnd\n", "unterminated"),
    ("A 1\nEnd\n", "expected '='"),
    ("", "empty"),
])
def test_malformed_labels_raise_label_error(text, what):
    with pytest.raises(LabelError, match=what):
        parse_label(text, "bad.lbl")


def test_missing_label_file(tmp_path):
    with pytest.raises(LabelError, match="not found"):
        load_label(tmp_path / "none.lbl")


def test_unknown_instrument_has_no_driver():
    lab = parse_label("Object = IsisCube\n Group = Instrument\n  SpacecraftName = VOYAGER\n"
                      "  InstrumentId = ISSNA\n End_Group\nEnd_Object\nEnd\n")
    with pytest.raises(UnknownInstrumentError, match="ISSNA"):
        driver_for(lab, "v.lbl")


def test_generic_driver_claims_labels_with_naif_frame_code():
    lab = parse_label("Object = IsisCube\n Group = Instrument\n  SpacecraftName = X\n End_Group\n"
                      " Group = Kernels\n  NaifFrameCode = -990100\n End_Group\nEnd_Object\nEnd\n")
    assert isinstance(driver_for(lab), GenericDriver)

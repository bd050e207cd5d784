"""ISIS control networks: round trips of every field, the binary structure checked with Google's protobuf
runtime against the public .proto definitions (both directions), bad input."""

from __future__ import annotations

import os
import re
import struct

import numpy as np
import pytest

from isisnet_help import random_network
from lunarmap.errors import IsisNetworkFormatError, NetworkFormatError, UnknownImageError
from lunarmap.io.isis_network import LABEL_BYTES, read_isis_network, write_isis_network
from lunarmap.io.isis_network_pvl import write_pvl_network

POINT_FIELDS_ONLY_IN_BINARY = ("point_log_point", "point_log_type", "point_log_value", "point_log_bool_type",
                               "point_log_bool_value")
CONVENTION_SHIFTED = ("line", "sample", "apriori_line", "apriori_sample")  # ISIS = CSM + 0.5


def differing(a, b, skip=()):
    out = []
    for k in a.variables:
        if k in skip:
            continue
        x, y = a[k].values, b[k].values
        same = np.array_equal(x, y, equal_nan=True) if x.dtype.kind == "f" else np.array_equal(x, y)
        if not same:
            out.append(k)
    return out


@pytest.fixture(scope="module")
def network():
    return random_network(400, seed=1)


@pytest.mark.parametrize("form", ["v5", "v2", "pvl"])
def test_round_trip_every_field(tmp_path, network, form):
    if form == "pvl":  # the PVL parser is pure Python: a smaller network keeps the test fast
        network = random_network(100, seed=5)
    write = {"v5": lambda d, p: write_isis_network(d, p, 5), "v2": lambda d, p: write_isis_network(d, p, 2),
             "pvl": write_pvl_network}[form]
    images = list(network["image_id"].values)
    assert (network["point_type"] == 2).sum() > 0 and (network["isis_point_type"] == 4).sum() > 0
    write(network, tmp_path / "a.net")
    once = read_isis_network(tmp_path / "a.net", images=images)
    skip = POINT_FIELDS_ONLY_IN_BINARY if form == "pvl" else ()
    # the first trip shifts image coordinates by 0.5 px and back: at most one unit in the last place
    assert set(differing(network, once, skip)) <= set(CONVENTION_SHIFTED)
    for k in CONVENTION_SHIFTED:
        np.testing.assert_allclose(once[k].values, network[k].values, rtol=0, atol=1e-10)
    # what comes from a file goes back bit for bit: the same bytes, the same Dataset
    write(once, tmp_path / "b.net")
    assert (tmp_path / "a.net").read_bytes() == (tmp_path / "b.net").read_bytes()
    twice = read_isis_network(tmp_path / "b.net", images=images)
    assert differing(once, twice) == []
    for key in ("body", "isis_network_id", "isis_created", "isis_description", "isis_user_name"):
        assert once.attrs[key] == network.attrs[key]
    if form != "v2":  # the version-2 header has no radii
        np.testing.assert_array_equal(once.attrs["isis_target_radii"], network.attrs["isis_target_radii"])


# --- the public .proto definitions, as Google's runtime sees them -------------------------------------

def _message_classes():
    pb = pytest.importorskip("google.protobuf")
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    F = descriptor_pb2.FieldDescriptorProto
    T = {"string": F.TYPE_STRING, "double": F.TYPE_DOUBLE, "bool": F.TYPE_BOOL, "int32": F.TYPE_INT32,
         "enum": F.TYPE_ENUM, "message": F.TYPE_MESSAGE}
    L = {"required": F.LABEL_REQUIRED, "optional": F.LABEL_OPTIONAL, "repeated": F.LABEL_REPEATED}
    fdp = descriptor_pb2.FileDescriptorProto(name="isis_cnet_test.proto", package="Isis", syntax="proto2")

    def message(parent, name, fields, enums=()):
        msg = (parent.message_type if hasattr(parent, "message_type") else parent.nested_type).add(name=name)
        for ename, values in enums:
            e = msg.enum_type.add(name=ename)
            for vname, number in values:
                e.value.add(name=vname, number=number)
        for label, typ, fname, number, *extra in fields:
            f = msg.field.add(name=fname, number=number, label=L[label], type=T[typ])
            if extra and extra[0] == "packed":
                f.options.packed = True
            elif extra:
                f.type_name = extra[0]
        return msg

    # ControlNetFileHeaderV0002.proto / ControlNetFileHeaderV0005.proto (DOI-USGS/ISIS3)
    head = [("required", "string", "networkId", 1), ("required", "string", "targetName", 2),
            ("optional", "string", "created", 3), ("optional", "string", "lastModified", 4),
            ("optional", "string", "description", 5), ("optional", "string", "userName", 6)]
    message(fdp, "ControlNetFileHeaderV0002", head + [("repeated", "int32", "pointMessageSizes", 7, "packed")])
    message(fdp, "ControlNetFileHeaderV0005", head + [("optional", "int32", "numPoints", 7),
                                                      ("repeated", "double", "targetRadii", 10)])
    # ControlPointFileEntryV0002.proto
    log = [("optional", "int32", "doubleDataType", 1), ("optional", "double", "doubleDataValue", 2),
           ("optional", "int32", "boolDataType", 3), ("optional", "bool", "boolDataValue", 4)]
    point = message(fdp, "ControlPointFileEntryV0002", [
        ("required", "string", "id", 1), ("required", "enum", "type", 2, ".Isis.ControlPointFileEntryV0002.PointType"),
        ("optional", "string", "chooserName", 3), ("optional", "string", "datetime", 4),
        ("optional", "bool", "editLock", 5), ("optional", "bool", "ignore", 6), ("optional", "bool", "jigsawRejected", 7),
        ("optional", "int32", "referenceIndex", 8),
        ("optional", "enum", "aprioriSurfPointSource", 9, ".Isis.ControlPointFileEntryV0002.AprioriSource"),
        ("optional", "string", "aprioriSurfPointSourceFile", 10),
        ("optional", "enum", "aprioriRadiusSource", 11, ".Isis.ControlPointFileEntryV0002.AprioriSource"),
        ("optional", "string", "aprioriRadiusSourceFile", 12), ("optional", "bool", "latitudeConstrained", 13),
        ("optional", "bool", "longitudeConstrained", 14), ("optional", "bool", "radiusConstrained", 15),
        ("optional", "double", "aprioriX", 16), ("optional", "double", "aprioriY", 17),
        ("optional", "double", "aprioriZ", 18), ("repeated", "double", "aprioriCovar", 19, "packed"),
        ("optional", "double", "adjustedX", 20), ("optional", "double", "adjustedY", 21),
        ("optional", "double", "adjustedZ", 22), ("repeated", "double", "adjustedCovar", 23, "packed"),
        ("repeated", "message", "log", 24, ".Isis.ControlPointFileEntryV0002.PointLogData"),
        ("repeated", "message", "measures", 25, ".Isis.ControlPointFileEntryV0002.Measure")],
        enums=[("PointType", [("Free", 2), ("Constrained", 3), ("Fixed", 4), ("obsolete_Tie", 0),
                              ("obsolete_Ground", 1)]),
               ("AprioriSource", [("None", 0), ("User", 1), ("AverageOfMeasures", 2), ("Reference", 3),
                                  ("Ellipsoid", 4), ("DEM", 5), ("Basemap", 6), ("BundleSolution", 7)])])
    message(point, "PointLogData", log)
    measure = message(point, "Measure", [
        ("required", "string", "serialnumber", 1),
        ("required", "enum", "type", 2, ".Isis.ControlPointFileEntryV0002.Measure.MeasureType"),
        ("optional", "double", "sample", 3), ("optional", "double", "line", 4),
        ("optional", "double", "sampleResidual", 5), ("optional", "double", "lineResidual", 6),
        ("optional", "string", "choosername", 7), ("optional", "string", "datetime", 8),
        ("optional", "bool", "editLock", 9), ("optional", "bool", "ignore", 10),
        ("optional", "bool", "jigsawRejected", 11), ("optional", "double", "diameter", 12),
        ("optional", "double", "apriorisample", 13), ("optional", "double", "aprioriline", 14),
        ("optional", "double", "samplesigma", 15), ("optional", "double", "linesigma", 16),
        ("repeated", "message", "log", 17, ".Isis.ControlPointFileEntryV0002.Measure.MeasureLogData")],
        enums=[("MeasureType", [("Candidate", 0), ("Manual", 1), ("RegisteredPixel", 2), ("RegisteredSubPixel", 3)])])
    message(measure, "MeasureLogData", log)
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fdp)
    get = lambda n: message_factory.GetMessageClass(pool.FindMessageTypeByName(f"Isis.{n}"))  # noqa: E731
    del pb
    return get("ControlNetFileHeaderV0002"), get("ControlNetFileHeaderV0005"), get("ControlPointFileEntryV0002")


def _label_numbers(blob: bytes) -> dict[str, int]:
    text = blob[:LABEL_BYTES].split(b"\0", 1)[0].decode()
    return {k: int(v) for k, v in re.findall(r"(\w+)\s*=\s*(\d+)\s*$", text, re.MULTILINE)}


def test_binary_structure_matches_public_proto(tmp_path, network):
    """Google's protobuf runtime decodes our file with ISIS's schema, and re-encodes every point to the same bytes."""
    HeaderV2, HeaderV5, Point = _message_classes()
    path = write_isis_network(network, tmp_path / "n.net")
    blob = path.read_bytes()
    nums = _label_numbers(blob)
    assert nums["Version"] == 5 and nums["HeaderStartByte"] == LABEL_BYTES
    header = HeaderV5.FromString(blob[nums["HeaderStartByte"]:nums["HeaderStartByte"] + nums["HeaderBytes"]])
    assert header.networkId == "test" and header.targetName == "Moon" and list(header.targetRadii) == [1737400.0] * 3
    pos, end = nums["PointsStartByte"], nums["PointsStartByte"] + nums["PointsBytes"]
    assert end == len(blob)
    points = []
    while pos < end:
        (size,) = struct.unpack("<I", blob[pos:pos + 4])
        raw = blob[pos + 4:pos + 4 + size]
        msg = Point.FromString(raw)
        assert msg.SerializeToString() == raw          # canonical encoding, field by field
        points.append(msg)
        pos += 4 + size
    assert len(points) == network.sizes["point"] == nums["NumberOfPoints"]
    order = np.argsort(network["measure_point"].values, kind="stable")
    serials = network["image_id"].values[network["measure_image"].values[order]]
    lines = network["line"].values[order] + 0.5
    k = 0
    for i, msg in enumerate(points):
        assert msg.id == network["point_id"].values[i]
        isis_type = int(network["isis_point_type"].values[i])
        assert msg.type == (2 if network["point_type"].values[i] == 2 else isis_type)
        xyz = network["xyz"].values[i]
        assert msg.HasField("aprioriX") == bool(np.all(np.isfinite(xyz)))
        if msg.HasField("aprioriX"):
            assert (msg.aprioriX, msg.aprioriY, msg.aprioriZ) == tuple(xyz)
        if isis_type == 3:
            cov = network["xyz_cov"].values[i]
            assert list(msg.aprioriCovar) == [cov[0, 0], cov[0, 1], cov[0, 2], cov[1, 1], cov[1, 2], cov[2, 2]]
        for m in msg.measures:
            assert m.serialnumber == serials[k] and m.line == lines[k]
            k += 1
    assert k == network.sizes["measure"] == nums["NumberOfMeasures"]
    # version 2: sizes in the header, points back to back
    blob2 = write_isis_network(network, tmp_path / "n2.net", version=2).read_bytes()
    nums2 = _label_numbers(blob2)
    h2 = HeaderV2.FromString(blob2[nums2["HeaderStartByte"]:nums2["HeaderStartByte"] + nums2["HeaderBytes"]])
    sizes = list(h2.pointMessageSizes)
    start = nums2["HeaderStartByte"] + nums2["HeaderBytes"]
    assert len(sizes) == len(points) and start + sum(sizes) == len(blob2)
    assert Point.FromString(blob2[start:start + sizes[0]]) == points[0]


def test_reads_a_network_written_by_googles_runtime(tmp_path):
    """The other direction: a network encoded by protobuf's own serializer, as ISIS writes it."""
    _, HeaderV5, Point = _message_classes()
    pts = []
    p = Point(id="crater_rim_1", type=3, chooserName="qnet", aprioriX=1.0e6, aprioriY=2.0e5, aprioriZ=1.4e6,
              aprioriSurfPointSource=6, aprioriSurfPointSourceFile="basemap.cub")
    p.aprioriCovar.extend([4.0, 0.1, 0.0, 9.0, 0.2, 16.0])
    m = p.measures.add(serialnumber="LRO/NACL/1", type=3, sample=100.25, line=2000.75, samplesigma=0.4, linesigma=0.5,
                       lineResidual=0.125)
    m.log.add(doubleDataType=2, doubleDataValue=0.93)
    p.measures.add(serialnumber="LRO/NACR/2", type=1, sample=5.5, line=6.5, ignore=True)
    pts.append(p)
    pts.append(Point(id="tie_2", type=2, ignore=True))
    pts[1].measures.add(serialnumber="LRO/NACR/2", type=0, sample=1.0, line=1.0)
    header = HeaderV5(networkId="peer", targetName="MOON", description="by protobuf").SerializeToString()
    body = b"".join(struct.pack("<I", len(x)) + x for x in (q.SerializeToString() for q in pts))
    label = (f"Object = ProtoBuffer\n  Object = Core\n    HeaderStartByte = {LABEL_BYTES}\n    HeaderBytes = {len(header)}\n"
             f"    PointsStartByte = {LABEL_BYTES + len(header)}\n    PointsBytes = {len(body)}\n  End_Object\n"
             "  Group = ControlNetworkInfo\n    Version = 5\n  End_Group\nEnd_Object\nEnd\n").encode()
    path = tmp_path / "peer.net"
    path.write_bytes(label.ljust(LABEL_BYTES, b"\0") + header + body)
    ds = read_isis_network(path)
    assert list(ds["point_id"].values) == ["crater_rim_1", "tie_2"] and ds.attrs["isis_description"] == "by protobuf"
    assert list(ds["point_type"].values) == [1, 0] and list(ds["isis_point_type"].values) == [3, 2]
    np.testing.assert_array_equal(ds["xyz_cov"].values[0], [[4.0, 0.1, 0.0], [0.1, 9.0, 0.2], [0.0, 0.2, 16.0]])
    assert ds["apriori_surface_source"].values[0] == 6 and ds["apriori_surface_source_file"].values[0] == "basemap.cub"
    assert list(ds["image_id"].values) == ["LRO/NACL/1", "LRO/NACR/2"]
    np.testing.assert_array_equal(ds["line"].values, [2000.25, 6.0, 0.5])          # CSM = ISIS - 0.5
    np.testing.assert_array_equal(ds["sigma_line"].values[:1], [0.5])
    assert np.isnan(ds["sigma_line"].values[1]) and ds["measure_ignore"].values[1] and ds["ignore"].values[1]
    assert ds["measure_log_type"].values.tolist() == [2] and ds["measure_log_value"].values.tolist() == [0.93]
    assert ds["chooser_name"].values[0] == "qnet" and ds["measure_type"].values.tolist() == [3, 1, 0]


def test_bad_networks_are_named(tmp_path, network):
    path = write_isis_network(network, tmp_path / "n.net")
    blob = path.read_bytes()
    v3 = tmp_path / "v3.net"
    v3.write_bytes(blob.replace(b"Version          = 5", b"Version          = 3"))
    assert v3.read_bytes() != blob
    with pytest.raises(IsisNetworkFormatError, match="version 3"):
        read_isis_network(v3)
    cut = tmp_path / "cut.net"
    cut.write_bytes(blob[:-100])
    with pytest.raises(IsisNetworkFormatError, match="truncated"):
        read_isis_network(cut)
    garbage = tmp_path / "garbage.net"
    nums = _label_numbers(blob)
    body = bytearray(blob)
    body[nums["PointsStartByte"] + 4:nums["PointsStartByte"] + 12] = b"\xff" * 8   # inside point 0
    garbage.write_bytes(bytes(body))
    with pytest.raises(IsisNetworkFormatError, match="point message 0 is malformed"):
        read_isis_network(garbage)
    images = list(network["image_id"].values)
    with pytest.raises(UnknownImageError, match=r"point 'pt_\d+' has a measure on image 'LRO/NACL/\d+:07208', "
                                                r"which is not in the image list") as err:
        read_isis_network(path, images=images[1:])
    assert isinstance(err.value, NetworkFormatError)
    (tmp_path / "text.net").write_text("Object = Something\nEnd_Object\nEnd\n")
    with pytest.raises(IsisNetworkFormatError, match="not an ISIS control network"):
        read_isis_network(tmp_path / "text.net")
    with pytest.raises(FileNotFoundError):
        read_isis_network(tmp_path / "nope.net")


def test_bad_writes_leave_nothing(tmp_path, network):
    before = set(os.listdir(tmp_path))
    with pytest.raises(IsisNetworkFormatError, match="version 3"):
        write_isis_network(network, tmp_path / "x.net", version=3)
    bad = network.copy()
    bad["measure_image"] = bad["measure_image"] + 1000
    with pytest.raises(IsisNetworkFormatError, match="out of range"):
        write_isis_network(bad, tmp_path / "y.net")
    dup = network.copy()
    dup["point_id"] = ("point", np.array(["same"] * network.sizes["point"], dtype=object))
    with pytest.raises(IsisNetworkFormatError, match="unique"):
        write_isis_network(dup, tmp_path / "z.net")
    assert set(os.listdir(tmp_path)) == before

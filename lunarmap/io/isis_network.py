"""ISIS control networks (``.net``): binary protobuf (versions 2 and 5) and PVL, as an ``xarray.Dataset``.

ISIS (``jigsaw``, ``pointreg``, ``qnet``, ``cnetedit``) and AutoCNet exchange control networks in
this format. A binary network is a PVL label (``Object = ProtoBuffer``: byte offsets and, in
``Group = ControlNetworkInfo``, the ``Version``), a header message at ``HeaderStartByte`` (0-based)
and one ``ControlPointFileEntryV0002`` message per point: in version 5 (what ISIS writes) each
preceded by its size as a little-endian uint32, in version 2 back to back with their sizes listed in
the header (``pointMessageSizes``). The message definitions below are written from ISIS's public
``ControlNetFileHeaderV0002.proto``, ``ControlNetFileHeaderV0005.proto`` and
``ControlPointFileEntryV0002.proto`` (field numbers in brackets); the wire format is coded in
:mod:`lunarmap.io._protowire`.

The network becomes the project's control-network ``Dataset`` (the layout of
:func:`lunarmap.adjust.network.network_to_dataset`: ``point_id``, ``point_type`` 0 tie / 1 control /
2 check, ``xyz``, ``xyz_cov``, ``measure_point``, ``measure_image``, ``line``, ``sample``,
``sigma_line``, ``sigma_sample``, ``image_id``, ``image_name``) plus every ISIS field:

==================================  =====================================================================
variable                            ISIS field
==================================  =====================================================================
``isis_point_type`` (point)         type [2]: 2 Free, 3 Constrained, 4 Fixed (0, 1: obsolete Tie, Ground)
``xyz``, ``xyz_cov``                aprioriX/Y/Z [16-18] (m), aprioriCovar [19] (m^2, upper triangle)
``adjusted_xyz``, ``adjusted_cov``  adjustedX/Y/Z [20-22], adjustedCovar [23]
``ignore``, ``edit_lock``,          ignore [6], editLock [5], jigsawRejected [7]
``jigsaw_rejected``
``reference_index``                 referenceIndex [8] (-1: none)
``chooser_name``, ``datetime``      chooserName [3], datetime [4] ("" when absent)
``apriori_surface_source``,         aprioriSurfPointSource [9], aprioriRadiusSource [11] (enum; -1 absent),
``apriori_radius_source`` (+
``_file``)                          ...SourceFile [10], [12]
``latitude/longitude/radius_        latitudeConstrained [13], longitudeConstrained [14], radiusConstrained [15]
constrained``
``measure_type`` (measure)          type [2]: 0 Candidate, 1 Manual, 2 RegisteredPixel, 3 RegisteredSubPixel
``line``, ``sample``                line [4], sample [3], **converted to the CSM convention** (ISIS - 0.5)
``sigma_line``, ``sigma_sample``    linesigma [16], samplesigma [15] (px; NaN when absent)
``line_residual``,                  lineResidual [6], sampleResidual [5] (px)
``sample_residual``
``apriori_line``, ``apriori_sample`` aprioriline [14], apriorisample [13] (CSM convention)
``diameter``                        diameter [12]
``measure_ignore``, ...             ignore [10], editLock [9], jigsawRejected [11], choosername [7],
                                    datetime [8]
``image_id``                        the measures' serialnumber [1]
``point_log_*``, ``measure_log_*``  log entries [24], [17]: doubleDataType, doubleDataValue, boolDataType,
                                    boolDataValue, one row each, with the point / measure they belong to
==================================  =====================================================================

Absent optional numbers are NaN, absent flags false. ``point_type`` follows from the ISIS type:
Free -> tie, Constrained and Fixed -> control (Fixed with an all-zero ``xyz_cov``); ISIS has no
check points, so lunarmap writes a check point as an *ignored* Free point whose a-priori
coordinates come from a *Reference* (``aprioriSurfPointSource = Reference``): jigsaw leaves it out,
as an adjustment must, and reading turns exactly that combination back into a check point.

Measures come back grouped by point (ISIS stores them inside their point), in file order. Files are
written atomically.
"""

from __future__ import annotations

import os
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ..atomic import atomic_write
from ..errors import IsisNetworkFormatError, LabelError
from ..labels import Label, parse_label
from ..labels.pvl import label_int
from . import _protowire as pw
from .isis_network_data import (
    _COV_INDEX,
    _FIXED,
    _FREE,
    _NAN_BITS,
    _PIXEL,
    _REFERENCE,
    APRIORI_SOURCES,
    ISIS_POINT_TYPES,
    LABEL_BYTES,
    MEASURE_TYPES,
    _columns_for_writing,
    _factorize,
    _get,
    _image_index,
    network_dataset,
)
from .isis_network_pvl import read_pvl_network
from .pvl_write import format_pvl

__all__ = ["read_isis_network", "write_isis_network", "ISIS_POINT_TYPES", "MEASURE_TYPES", "APRIORI_SOURCES",
           "LABEL_BYTES", "network_dataset"]

# -- strings ---------------------------------------------------------------------------------

def _pack_strings(columns: list[Any]) -> tuple[NDArray[np.uint8], list[tuple[NDArray, NDArray]]]:
    """One byte buffer for several string columns: per column ``(offsets, lengths)``, length -1 for ''.

    A column may be given as ``(codes, unique strings)`` already.
    """
    parts: list[bytes] = []
    pos = 0
    out = []
    for col in columns:
        inv, uniq = col if isinstance(col, tuple) else _factorize(col)
        off = np.empty(len(uniq), np.int64)
        ln = np.empty(len(uniq), np.int64)
        for k, text in enumerate(uniq):
            try:
                b = str(text).encode("latin-1")
            except UnicodeEncodeError:
                raise IsisNetworkFormatError(f"ISIS networks store Latin-1 text; {text!r} is not") from None
            off[k], ln[k] = pos, len(b) if b else -1
            parts.append(b)
            pos += len(b)
        out.append((off[inv], ln[inv]))
    buf = np.frombuffer(b"".join(parts) or b"\0", np.uint8)
    return buf, out


def _string_codes(buf: NDArray[np.uint8], off: NDArray, ln: NDArray) -> tuple[NDArray[np.int64], NDArray]:
    """Codes (order of first appearance) and unique strings of ``buf[off:off+ln]``; '' where ``ln < 0``."""
    if off.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, dtype=object)
    if np.all(ln < 0):
        return np.zeros(off.size, np.int64), np.array([""], dtype=object)
    h = pw.hash_strings(buf, off, ln)
    _, first, inv = np.unique(h, return_index=True, return_inverse=True)
    inv = inv.ravel()
    if not pw.same_strings(buf, off, ln, first[inv]):  # a 64-bit hash collision: exact fallback
        texts = np.array([bytes(buf[o:o + max(n, 0)]).decode("latin-1") for o, n in zip(off, ln)], dtype=object)
        return _factorize(texts)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    uniq = np.array([bytes(buf[off[k]:off[k] + max(ln[k], 0)]).decode("latin-1") for k in first[order]], dtype=object)
    return rank[inv].astype(np.int64), uniq


def _unpack_strings(buf: NDArray[np.uint8], off: NDArray, ln: NDArray) -> NDArray:
    """Strings ``buf[off:off+ln]`` (Latin-1) as an object array; '' where ``ln < 0``."""
    codes, uniq = _string_codes(buf, off, ln)
    return uniq[codes]


def _bits(x: NDArray) -> NDArray[np.uint64]:
    a = np.ascontiguousarray(np.asarray(x, dtype="<f8"))
    return np.where(np.isnan(a), _NAN_BITS, a.view(np.uint64))


def _floats(bits: NDArray[np.uint64]) -> NDArray[np.float64]:
    return np.ascontiguousarray(bits).view("<f8").astype(np.float64)


# -- the Dataset ------------------------------------------------------------------------------

# -- reading ----------------------------------------------------------------------------------

def _read_label(path: Path, head: bytes) -> Label:
    text = head.split(b"\0", 1)[0].decode("latin-1")
    try:
        return parse_label(text, str(path))
    except LabelError as err:
        raise IsisNetworkFormatError(f"ISIS control network {path}: unreadable PVL label: {err}") from None


def _header_fields(buf: bytes, path: Path, version: int) -> dict[str, Any]:
    """The header message: strings [1-6], numPoints [7] (v5) or packed pointMessageSizes [7] (v2), radii [10]."""
    names = {1: "networkId", 2: "targetName", 3: "created", 4: "lastModified", 5: "description", 6: "userName"}
    out: dict[str, Any] = {"targetRadii": []}
    arr = np.frombuffer(buf, np.uint8)
    pos, end = 0, len(buf)

    def varint(p: int) -> tuple[int, int]:
        v, shift = 0, 0
        while True:
            if p >= end:
                raise IsisNetworkFormatError(f"ISIS control network {path}: truncated header message")
            b = buf[p]
            v |= (b & 0x7F) << shift
            p += 1
            if b < 0x80:
                return v, p
            shift += 7

    while pos < end:
        key, pos = varint(pos)
        field, wire = key >> 3, key & 7
        if wire == 2:
            n, pos = varint(pos)
            if pos + n > end:
                raise IsisNetworkFormatError(f"ISIS control network {path}: truncated header message")
            if field in names:
                out[names[field]] = buf[pos:pos + n].decode("latin-1")
            elif field == 7 and version == 2:
                sizes, status = pw.decode_varints(arr, pos, pos + n)
                if status < 0:
                    raise IsisNetworkFormatError(f"ISIS control network {path}: malformed pointMessageSizes")
                out["pointMessageSizes"] = sizes
            elif field == 10:
                if n % 8:
                    raise IsisNetworkFormatError(f"ISIS control network {path}: targetRadii of {n} bytes, not a "
                                                 "multiple of 8")
                out["targetRadii"] += list(struct.unpack(f"<{n // 8}d", buf[pos:pos + n]))
            pos += n
        elif wire == 0:
            v, pos = varint(pos)
            if field == 7:
                out["numPoints"] = v
        elif wire == 1:
            if pos + 8 > end:
                raise IsisNetworkFormatError(f"ISIS control network {path}: truncated header message")
            if field == 10:
                out["targetRadii"].append(struct.unpack("<d", buf[pos:pos + 8])[0])
            pos += 8
        elif wire == 5:
            if pos + 4 > end:
                raise IsisNetworkFormatError(f"ISIS control network {path}: truncated header message")
            pos += 4
        else:
            raise IsisNetworkFormatError(f"ISIS control network {path}: malformed header (wire type {wire})")
    for req in ("networkId", "targetName"):
        if req not in out:
            raise IsisNetworkFormatError(f"ISIS control network {path}: the header lacks the required {req}")
    return out


def _dataset_from_points(raw: NDArray[np.uint8], starts: NDArray, ends: NDArray, path: Path,
                         images: list[str] | None, attrs: dict[str, Any]) -> xr.Dataset:
    n_meas, n_plog, n_mlog, bad = pw.count_points(raw, starts, ends)
    if bad >= 0:
        raise IsisNetworkFormatError(f"ISIS control network {path}: point message {bad} is malformed or truncated")
    # first row of each point's measures / point logs / measure logs (all written point by point)
    res = pw.parse_points(raw, starts, ends, _first_rows(n_meas), _first_rows(n_plog), _first_rows(n_mlog),
                          int(n_meas.sum()), int(n_plog.sum()), int(n_mlog.sum()))
    (bad, p_str, p_int, p_flag, p_dbl, p_cov, p_ncov, m_str, m_type, m_flag, m_dbl, m_point,
     pl_owner, pl_dtype, pl_dvalue, pl_btype, pl_bvalue, ml_owner, ml_dtype, ml_dvalue, ml_btype, ml_bvalue) = res
    if bad >= 0:
        raise IsisNetworkFormatError(f"ISIS control network {path}: point message {bad} is malformed or truncated")
    n_pt = starts.size
    missing_id = np.nonzero(p_str[:, 0, 1] < 0)[0]
    if missing_id.size or np.any(p_int[:, 0] < 0):
        k = int(missing_id[0]) if missing_id.size else int(np.nonzero(p_int[:, 0] < 0)[0][0])
        raise IsisNetworkFormatError(f"ISIS control network {path}: point {k} lacks its required id or type")
    strings = [_unpack_strings(raw, p_str[:, k, 0], p_str[:, k, 1]) for k in range(5)]
    point_ids = strings[0]
    if np.any((p_int[:, 0] > 4)):
        k = int(np.nonzero(p_int[:, 0] > 4)[0][0])
        raise IsisNetworkFormatError(f"ISIS control network {path}: point {point_ids[k]!r} has unknown type {p_int[k, 0]}")
    if np.any(m_str[:, 0, 1] < 0) or np.any(m_type < 0) or np.any(m_type > 3):
        j = int(np.nonzero((m_str[:, 0, 1] < 0) | (m_type < 0) | (m_type > 3))[0][0])
        raise IsisNetworkFormatError(f"ISIS control network {path}: a measure of point {point_ids[m_point[j]]!r} "
                                     "lacks its serial number or has no valid measure type")
    isis_type = p_int[:, 0].astype(np.int8)
    isis_type[isis_type == 0] = _FREE   # obsolete Tie -> Free, Ground -> Fixed (as ISIS reads them)
    isis_type[isis_type == 1] = _FIXED
    cov = np.full((2, n_pt, 3, 3), np.nan)
    for c in range(2):
        has = p_ncov[:, c] >= 6
        vals = _floats(p_cov[:, c, :])
        for k, (a, b) in enumerate(_COV_INDEX):
            cov[c, has, a, b] = cov[c, has, b, a] = vals[has, k]
    dbl = _floats(p_dbl)
    ignore = p_flag[:, 1].astype(bool)
    surf = p_int[:, 2].astype(np.int8)
    ptype = np.where(isis_type == _FREE, 0, 1).astype(np.int8)
    ptype[(isis_type == _FREE) & ignore & (surf == _REFERENCE)] = 2
    fixed = isis_type == _FIXED
    cov[0][fixed & np.all(np.isnan(cov[0]), axis=(1, 2))] = 0.0  # a fixed point: exact a-priori coordinates
    codes, serials = _string_codes(raw, m_str[:, 0, 0], m_str[:, 0, 1])
    image_id, m_image = _image_index(codes, serials, images, point_ids, m_point, path)
    md = _floats(m_dbl)
    points = {
        "point_id": point_ids, "point_type": ptype, "isis_point_type": isis_type, "xyz": dbl[:, :3],
        "xyz_cov": cov[0], "adjusted_xyz": dbl[:, 3:], "adjusted_cov": cov[1], "ignore": ignore,
        "edit_lock": p_flag[:, 0].astype(bool), "jigsaw_rejected": p_flag[:, 2].astype(bool),
        "reference_index": p_int[:, 1].astype(np.int32), "chooser_name": strings[1], "datetime": strings[2],
        "apriori_surface_source": surf, "apriori_surface_source_file": strings[3],
        "apriori_radius_source": p_int[:, 3].astype(np.int8), "apriori_radius_source_file": strings[4],
        "latitude_constrained": p_flag[:, 3].astype(bool), "longitude_constrained": p_flag[:, 4].astype(bool),
        "radius_constrained": p_flag[:, 5].astype(bool),
    }
    measures = {
        "measure_point": m_point, "measure_image": m_image, "sample": md[:, 0] - _PIXEL, "line": md[:, 1] - _PIXEL,
        "sample_residual": md[:, 2], "line_residual": md[:, 3], "diameter": md[:, 4],
        "apriori_sample": md[:, 5] - _PIXEL, "apriori_line": md[:, 6] - _PIXEL, "sigma_sample": md[:, 7],
        "sigma_line": md[:, 8], "measure_type": m_type.astype(np.int8),
        "measure_edit_lock": m_flag[:, 0].astype(bool), "measure_ignore": m_flag[:, 1].astype(bool),
        "measure_jigsaw_rejected": m_flag[:, 2].astype(bool),
        "measure_chooser_name": _unpack_strings(raw, m_str[:, 1, 0], m_str[:, 1, 1]),
        "measure_datetime": _unpack_strings(raw, m_str[:, 2, 0], m_str[:, 2, 1]),
    }
    plogs = {"point": pl_owner, "type": pl_dtype, "value": _floats(pl_dvalue), "bool_type": pl_btype,
             "bool_value": pl_bvalue}
    mlogs = {"measure": ml_owner, "type": ml_dtype, "value": _floats(ml_dvalue), "bool_type": ml_btype,
             "bool_value": ml_bvalue}
    return network_dataset(points, measures, image_id, point_logs=plogs, measure_logs=mlogs, attrs=attrs)


def _first_rows(counts: NDArray) -> NDArray:
    return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64) if counts.size else np.zeros(0, np.int64)


def read_isis_network(path: str | os.PathLike[str], images: list[str] | None = None) -> xr.Dataset:
    """Read an ISIS control network (binary version 2 or 5, or PVL) as the control-network Dataset.

    Parameters
    ----------
    path : path-like
        The ``.net`` file.
    images : list of str, optional
        Serial numbers of the images, in the order the Dataset's ``image`` dimension should have
        (e.g. from a cube list); every measure must be on one of them. By default, the images
        are the serial numbers the measures use, in order of first appearance.

    Raises
    ------
    FileNotFoundError
        No such file.
    IsisNetworkFormatError
        Not an ISIS network, an unknown version, a truncated or malformed file.
    UnknownImageError
        A measure on an image not in ``images``; the point and the serial number are named.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ISIS control network {path} does not exist")
    with open(path, "rb") as fh:
        head = fh.read(LABEL_BYTES)
    if b"ProtoBuffer" not in head[:4096] and re.search(rb"Object\s*=\s*ControlNetwork\b", head[:4096]):
        return read_pvl_network(path, images)
    label = _read_label(path, head)
    proto = label.get("ProtoBuffer")
    if not isinstance(proto, Label):
        raise IsisNetworkFormatError(f"{path} is not an ISIS control network (no ProtoBuffer or ControlNetwork object)")
    info = proto.get("ControlNetworkInfo") if isinstance(proto.get("ControlNetworkInfo"), Label) else Label()
    try:
        version = label_int(info.get("Version", 1), f"ISIS control network {path}: Version")
    except LabelError as err:
        raise IsisNetworkFormatError(str(err)) from None
    if version not in (2, 5):
        raise IsisNetworkFormatError(f"ISIS control network {path} is binary version {version}; lunarmap reads "
                                     "versions 2 and 5 (ISIS's since 2011; convert older ones with ISIS cnetbin2pvl)")
    core = proto.get("Core")
    try:
        start = label_int(core["HeaderStartByte"], "HeaderStartByte", 0)
        nbytes = label_int(core["HeaderBytes"], "HeaderBytes", 0)
    except (KeyError, TypeError, ValueError):
        raise IsisNetworkFormatError(f"ISIS control network {path}: ProtoBuffer/Core lacks HeaderStartByte/HeaderBytes") from None
    data = np.fromfile(path, dtype=np.uint8)
    if start + nbytes > data.size:
        raise IsisNetworkFormatError(f"ISIS control network {path} is truncated: header bytes {start}..{start + nbytes} "
                                     f"beyond the file's {data.size}")
    header = _header_fields(data[start:start + nbytes].tobytes(), path, version)
    pstart = start + nbytes
    if version == 2:
        sizes = np.asarray(header.get("pointMessageSizes", np.zeros(0, np.int64)), np.int64)
        starts = pstart + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) if sizes.size else sizes
        ends = starts + sizes
        if sizes.size and ends[-1] > data.size:
            raise IsisNetworkFormatError(f"ISIS control network {path} is truncated: its points need "
                                         f"{int(ends[-1])} bytes, the file has {data.size}")
    else:
        try:
            total = label_int(core.get("PointsBytes", data.size - pstart), f"ISIS control network {path}: "
                              "PointsBytes", 0)
        except LabelError as err:
            raise IsisNetworkFormatError(str(err)) from None
        if pstart + total > data.size:
            raise IsisNetworkFormatError(f"ISIS control network {path} is truncated: points end at byte "
                                         f"{pstart + total}, the file has {data.size}")
        starts, ends = _prefixed_messages(data, pstart, pstart + total, path)
    radii = [float(r) for r in header.get("targetRadii", [])]
    attrs = {"body": header.get("targetName", "") or "MOON", "isis_network_id": header.get("networkId", ""),
             "isis_created": header.get("created", ""), "isis_last_modified": header.get("lastModified", ""),
             "isis_description": header.get("description", ""), "isis_user_name": header.get("userName", ""),
             "isis_version": version, "source": str(path)}
    if radii:
        attrs["isis_target_radii"] = np.asarray(radii)
        attrs["radius"] = radii[0]
    return _dataset_from_points(data, starts, ends, path, images, attrs)


def _prefixed_messages(data: NDArray[np.uint8], start: int, end: int, path: Path) -> tuple[NDArray, NDArray]:
    starts, ends = pw.walk_prefixes(data, start, end)
    if starts.size and ends[-1] < 0:
        raise IsisNetworkFormatError(f"ISIS control network {path}: point {starts.size - 1}'s size prefix runs past "
                                     "the end of the points")
    return starts, ends


# -- writing ----------------------------------------------------------------------------------

def _logs(ds: xr.Dataset, prefix: str, owner: str, n_owner: int, order: NDArray | None) -> tuple[NDArray, ...]:
    key = f"{prefix}_{owner}"
    if key not in ds or ds.sizes.get(prefix, 0) == 0:
        z = np.zeros(0, np.int64)
        return (np.zeros(n_owner, np.int64), np.zeros(n_owner, np.int64), z, np.zeros(0, np.uint64), z, z)
    own = np.asarray(ds[key].values, np.int64)
    if order is not None:  # measure logs follow their measures' new order
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        own = rank[own]
    srt = np.argsort(own, kind="stable")
    counts = np.bincount(own, minlength=n_owner).astype(np.int64)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    return (first, counts, np.asarray(ds[f"{prefix}_type"].values, np.int64)[srt],
            _bits(np.asarray(ds[f"{prefix}_value"].values, float)[srt]),
            np.asarray(ds[f"{prefix}_bool_type"].values, np.int64)[srt],
            np.asarray(ds[f"{prefix}_bool_value"].values, np.int64)[srt])


def encode_network_points(ds: xr.Dataset, prefix: int) -> tuple[NDArray[np.uint8], NDArray, int]:
    """The point messages of a Dataset: ``(bytes, message sizes, number of measures)``."""
    c = _columns_for_writing(ds)
    n_pt, n_m, order = c["n_pt"], c["n_m"], c["order"]

    def m(name: str, default: Any, dtype: Any = None) -> NDArray:
        return _get(ds, name, default, n_m, dtype)[order]

    def p(name: str, default: Any) -> NDArray:
        return _get(ds, name, default, n_pt)

    image_id = np.asarray(ds["image_id"].values, dtype=object)
    strings, packed = _pack_strings([(np.arange(n_pt), c["ids"]), p("chooser_name", ""), p("datetime", ""),
                                     p("apriori_surface_source_file", ""), p("apriori_radius_source_file", ""),
                                     (c["m_image"][order], image_id), m("measure_chooser_name", ""),
                                     m("measure_datetime", "")])
    p_str = np.stack([np.stack(packed[k], axis=-1) for k in range(5)], axis=1) if n_pt else np.zeros((0, 5, 2), np.int64)
    m_str = np.stack([np.stack(packed[k], axis=-1) for k in range(5, 8)], axis=1) if n_m else np.zeros((0, 3, 2), np.int64)
    p_int = np.stack([c["isis_type"].astype(np.int64), _get(ds, "reference_index", -1, n_pt, np.int64),
                      c["surf"].astype(np.int64), _get(ds, "apriori_radius_source", -1, n_pt, np.int64),
                      np.full(n_pt, -1, np.int64)], axis=1)
    p_flag = np.stack([_get(ds, k, False, n_pt, bool) for k in ("edit_lock",)] + [c["ignore"]] +
                      [_get(ds, k, False, n_pt, bool) for k in ("jigsaw_rejected", "latitude_constrained",
                                                                 "longitude_constrained", "radius_constrained")],
                      axis=1).astype(np.int8)
    adj = np.asarray(ds["adjusted_xyz"].values, float).reshape(n_pt, 3) if "adjusted_xyz" in ds else np.full((n_pt, 3), np.nan)
    p_dbl = _bits(np.concatenate([c["xyz"], adj], axis=1))
    adj_cov = np.asarray(ds["adjusted_cov"].values, float).reshape(n_pt, 3, 3) if "adjusted_cov" in ds \
        else np.full((n_pt, 3, 3), np.nan)
    p_cov = np.zeros((n_pt, 2, 6), np.uint64)
    for k_c, cv in enumerate((c["cov"], adj_cov)):
        six = np.stack([cv[:, a, b] for a, b in _COV_INDEX], axis=1)
        # an all-zero a-priori covariance is how a Fixed point says "exact": ISIS writes none
        none = np.any(np.isnan(six), axis=1) | ((c["isis_type"] == _FIXED) & np.all(six == 0.0, axis=1) if k_c == 0
                                                else np.zeros(n_pt, bool))
        six[none] = np.nan
        p_cov[:, k_c, :] = _bits(six)
    m_dbl = _bits(np.stack([m("sample", np.nan, float) + _PIXEL, m("line", np.nan, float) + _PIXEL,
                            m("sample_residual", np.nan, float), m("line_residual", np.nan, float),
                            m("diameter", np.nan, float), m("apriori_sample", np.nan, float) + _PIXEL,
                            m("apriori_line", np.nan, float) + _PIXEL, m("sigma_sample", np.nan, float),
                            m("sigma_line", np.nan, float)], axis=1))
    m_type = m("measure_type", 3, np.int64)
    m_flag = np.stack([m("measure_edit_lock", False, bool), m("measure_ignore", False, bool),
                       m("measure_jigsaw_rejected", False, bool)], axis=1).astype(np.int8)
    pl = _logs(ds, "point_log", "point", n_pt, None)
    ml = _logs(ds, "measure_log", "measure", n_m, order)
    out, sizes = pw.encode_points(strings, p_str, p_int, p_flag, p_dbl, p_cov, c["m_first"], c["counts"], m_str,
                                  m_type, m_flag, m_dbl, *pl, *ml, prefix)
    return out, sizes, n_m


def _header_bytes(attrs: dict[str, Any], version: int, sizes: NDArray | None) -> bytes:
    out = bytearray()

    def varint(v: int) -> None:
        while v >= 0x80:
            out.append((v & 0x7F) | 0x80)
            v >>= 7
        out.append(v)

    fields = [(1, "isis_network_id"), (2, "body"), (3, "isis_created"), (4, "isis_last_modified"),
              (5, "isis_description"), (6, "isis_user_name")]
    for f, key in fields:
        text = str(attrs.get(key, "")).encode("latin-1")
        if f > 2 and not text:
            continue
        varint(f << 3 | 2)
        varint(len(text))
        out += text
    if version == 2 and sizes is not None:
        packed = bytearray()
        for s in np.asarray(sizes, np.int64).tolist():
            while s >= 0x80:
                packed.append((s & 0x7F) | 0x80)
                s >>= 7
            packed.append(s)
        varint(7 << 3 | 2)
        varint(len(packed))
        out += packed
    if version == 5:
        for r in np.atleast_1d(attrs.get("isis_target_radii", [])).tolist():
            varint(10 << 3 | 1)
            out += struct.pack("<d", float(r))
    return bytes(out)


def write_isis_network(ds: xr.Dataset, path: str | os.PathLike[str], version: int = 5) -> Path:
    """Write a control-network Dataset as a binary ISIS control network (version 5 as ISIS writes, or 2).

    Header strings come from the attributes ``isis_network_id``, ``body`` (target name),
    ``isis_created``, ``isis_last_modified``, ``isis_description``, ``isis_user_name`` and
    ``isis_target_radii`` (version 5); image coordinates are converted to ISIS's convention.

    Raises
    ------
    IsisNetworkFormatError
        An unsupported version, or a Dataset that is not a control network (missing variables,
        indices out of range, repeated point ids, non-Latin-1 text). Nothing is written then.
    """
    path = Path(path)
    if version not in (2, 5):
        raise IsisNetworkFormatError(f"cannot write ISIS control network version {version}; use 5 (ISIS's) or 2")
    attrs = dict(ds.attrs)
    attrs.setdefault("isis_network_id", path.stem)
    points, sizes, n_m = encode_network_points(ds, prefix=4 if version == 5 else 0)
    header = _header_bytes(attrs, version, sizes)
    core: list[Any] = [("HeaderStartByte", LABEL_BYTES), ("HeaderBytes", len(header)),
                       ("PointsStartByte", LABEL_BYTES + len(header)), ("PointsBytes", int(points.size))]
    info: list[Any] = [("NetworkId", str(attrs.get("isis_network_id", ""))), ("TargetName", str(attrs.get("body", "")))]
    if version == 5 and np.size(attrs.get("isis_target_radii", [])):
        info.append(("TargetRadii", [float(r) for r in np.atleast_1d(attrs["isis_target_radii"])]))
    info += [("UserName", str(attrs.get("isis_user_name", ""))), ("Created", str(attrs.get("isis_created", ""))),
             ("LastModified", str(attrs.get("isis_last_modified", ""))),
             ("Description", str(attrs.get("isis_description", ""))),
             ("NumberOfPoints", int(ds.sizes.get("point", 0))), ("NumberOfMeasures", int(n_m)), ("Version", version)]
    label = format_pvl([("Object", "ProtoBuffer", [("Object", "Core", core), ("Group", "ControlNetworkInfo", info)])])
    text = label.encode("latin-1")
    if len(text) > LABEL_BYTES:
        raise IsisNetworkFormatError(f"writing {path}: the label needs {len(text)} bytes, more than {LABEL_BYTES}")

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            fh.write(text + b"\0" * (LABEL_BYTES - len(text)))
            fh.write(header)
            points.tofile(fh)

    return atomic_write(path, write)

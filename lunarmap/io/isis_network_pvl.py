"""ISIS control networks in their PVL form (``cnetbin2pvl`` output, version 5 keywords).

Same Dataset as :func:`lunarmap.io.isis_network.read_isis_network`. The PVL form has no point
log entries; measure log entries are keywords named by their ISIS data type
(``GoodnessOfFit = 0.93``), and the reference measure is flagged ``Reference = True``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr

from ..atomic import atomic_write
from ..errors import IsisNetworkFormatError, LabelError
from ..labels import Label, parse_label
from .isis_network_data import (
    _COV_INDEX,
    _FIXED,
    _FREE,
    _PIXEL,
    _REFERENCE,
    APRIORI_SOURCES,
    ISIS_POINT_TYPES,
    MEASURE_TYPES,
    _columns_for_writing,
    _get,
    _image_index,
    network_dataset,
)
from .pvl_write import Unit, format_pvl

__all__ = ["read_pvl_network", "write_pvl_network", "LOG_TYPES"]

#: ISIS ControlMeasureLogData numeric data types.
LOG_TYPES = {1: "Obsolete_Eccentricity", 2: "GoodnessOfFit", 3: "MinimumPixelZScore", 4: "MaximumPixelZScore",
             5: "PixelShift", 6: "WholePixelCorrelation", 7: "SubPixelCorrelation", 8: "Obsolete_AverageResidual"}
_LOG_CODES = {v.lower(): k for k, v in LOG_TYPES.items()}
_PTYPES = {"free": 2, "constrained": 3, "fixed": 4, "tie": 2, "ground": 4}
_MTYPES = {v.lower(): k for k, v in MEASURE_TYPES.items()}
_SOURCES = {v.lower(): k for k, v in APRIORI_SOURCES.items()}


def _true(v: Any) -> bool:
    return str(v).strip().lower() in ("true", "yes", "1")


def _num(v: Any, default: float = np.nan) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return default


def read_pvl_network(path: str | os.PathLike[str], images: list[str] | None = None) -> xr.Dataset:
    """Read a PVL ISIS control network (versions 3 to 5). See :func:`lunarmap.io.isis_network.read_isis_network`."""
    path = Path(path)
    try:
        label = parse_label(path.read_text(encoding="latin-1"), str(path))
    except LabelError as err:
        raise IsisNetworkFormatError(f"ISIS control network {path}: unreadable PVL: {err}") from None
    net = label.get("ControlNetwork")
    if not isinstance(net, Label):
        raise IsisNetworkFormatError(f"{path} is not an ISIS control network (no ControlNetwork object)")
    v = _num(net.get("Version", 1), np.nan)
    if not (np.isfinite(v) and v.is_integer()):
        raise IsisNetworkFormatError(f"ISIS PVL control network {path}: Version {net.get('Version')!r:.40} is not an "
                                     "integer")
    version = int(v)
    if version not in (3, 4, 5):
        raise IsisNetworkFormatError(f"ISIS PVL control network {path} is version {version}; lunarmap reads "
                                     "versions 3 to 5 (convert with ISIS cnetpvl2bin and cnetbin2pvl)")
    pts = net.all("ControlPoint")
    cols: dict[str, list] = {k: [] for k in (
        "point_id", "isis_point_type", "xyz", "xyz_cov", "adjusted_xyz", "adjusted_cov", "ignore", "edit_lock",
        "jigsaw_rejected", "reference_index", "chooser_name", "datetime", "apriori_surface_source",
        "apriori_surface_source_file", "apriori_radius_source", "apriori_radius_source_file",
        "latitude_constrained", "longitude_constrained", "radius_constrained")}
    meas: dict[str, list] = {k: [] for k in (
        "measure_point", "serial", "sample", "line", "sample_residual", "line_residual", "diameter",
        "apriori_sample", "apriori_line", "sigma_sample", "sigma_line", "measure_type", "measure_edit_lock",
        "measure_ignore", "measure_jigsaw_rejected", "measure_chooser_name", "measure_datetime")}
    logs: dict[str, list] = {"measure": [], "type": [], "value": []}
    for i, p in enumerate(pts):
        pid = p.get("PointId")
        ptype = str(p.get("PointType", "")).lower()
        if pid is None or ptype not in _PTYPES:
            raise IsisNetworkFormatError(f"ISIS control network {path}: point {i} lacks PointId or has PointType "
                                         f"{p.get('PointType')!r}")
        cols["point_id"].append(str(pid))
        cols["isis_point_type"].append(_PTYPES[ptype])
        for kind, cov_kind, key in (("xyz", "xyz_cov", "Apriori"), ("adjusted_xyz", "adjusted_cov", "Adjusted")):
            cols[kind].append([_num(p.get(f"{key}{a}")) for a in "XYZ"])
            six = p.get(f"{key}CovarianceMatrix")
            cov = np.full((3, 3), np.nan)
            if isinstance(six, list) and len(six) == 6:
                for k, (a, b) in enumerate(_COV_INDEX):
                    cov[a, b] = cov[b, a] = float(six[k])
            cols[cov_kind].append(cov)
        for col, key in (("ignore", "Ignore"), ("edit_lock", "EditLock"), ("jigsaw_rejected", "JigsawRejected"),
                         ("latitude_constrained", "LatitudeConstrained"),
                         ("longitude_constrained", "LongitudeConstrained"), ("radius_constrained", "RadiusConstrained")):
            cols[col].append(_true(p.get(key, False)))
        cols["chooser_name"].append(str(p.get("ChooserName", "")))
        cols["datetime"].append(str(p.get("DateTime", "")))
        cols["apriori_surface_source"].append(_SOURCES.get(str(p.get("AprioriXYZSource", "")).lower(), -1))
        cols["apriori_surface_source_file"].append(str(p.get("AprioriXYZSourceFile", "")))
        cols["apriori_radius_source"].append(_SOURCES.get(str(p.get("AprioriRadiusSource", "")).lower(), -1))
        cols["apriori_radius_source_file"].append(str(p.get("AprioriRadiusSourceFile", "")))
        ref = -1
        for j, m in enumerate(p.all("ControlMeasure")):
            if m.get("SerialNumber") is None:
                raise IsisNetworkFormatError(f"ISIS control network {path}: a measure of point {pid!r} has no "
                                             "SerialNumber")
            row = len(meas["serial"])
            meas["measure_point"].append(i)
            meas["serial"].append(str(m["SerialNumber"]))
            for col, key, shift in (("sample", "Sample", _PIXEL), ("line", "Line", _PIXEL),
                                    ("sample_residual", "SampleResidual", 0.0), ("line_residual", "LineResidual", 0.0),
                                    ("diameter", "Diameter", 0.0), ("apriori_sample", "AprioriSample", _PIXEL),
                                    ("apriori_line", "AprioriLine", _PIXEL), ("sigma_sample", "SampleSigma", 0.0),
                                    ("sigma_line", "LineSigma", 0.0)):
                meas[col].append(_num(m.get(key)) - shift)
            mtype = str(m.get("MeasureType", "Candidate")).lower()
            if mtype not in _MTYPES:
                raise IsisNetworkFormatError(f"ISIS control network {path}: point {pid!r} has a measure of "
                                             f"unknown MeasureType {m.get('MeasureType')!r}")
            meas["measure_type"].append(_MTYPES[mtype])
            for col, key in (("measure_edit_lock", "EditLock"), ("measure_ignore", "Ignore"),
                             ("measure_jigsaw_rejected", "JigsawRejected")):
                meas[col].append(_true(m.get(key, False)))
            meas["measure_chooser_name"].append(str(m.get("ChooserName", "")))
            meas["measure_datetime"].append(str(m.get("DateTime", "")))
            for key, value in m.items():
                if key.lower() in _LOG_CODES:
                    logs["measure"].append(row)
                    logs["type"].append(_LOG_CODES[key.lower()])
                    logs["value"].append(_num(value))
            if _true(m.get("Reference", False)):
                ref = j
        cols["reference_index"].append(ref)
    n_pt = len(pts)
    isis_type = np.asarray(cols["isis_point_type"], np.int8)
    ignore = np.asarray(cols["ignore"], bool)
    surf = np.asarray(cols["apriori_surface_source"], np.int8)
    type_code = np.where(isis_type == _FREE, 0, 1).astype(np.int8)
    type_code[(isis_type == _FREE) & ignore & (surf == _REFERENCE)] = 2
    xyz_cov = np.asarray(cols["xyz_cov"], float).reshape(n_pt, 3, 3)
    xyz_cov[(isis_type == _FIXED) & np.all(np.isnan(xyz_cov), axis=(1, 2))] = 0.0
    points = {k: np.asarray(v) for k, v in cols.items()}
    points.update(point_type=type_code, xyz_cov=xyz_cov, xyz=np.asarray(cols["xyz"], float).reshape(n_pt, 3),
                  adjusted_xyz=np.asarray(cols["adjusted_xyz"], float).reshape(n_pt, 3),
                  adjusted_cov=np.asarray(cols["adjusted_cov"], float).reshape(n_pt, 3, 3))
    m_point = np.asarray(meas.pop("measure_point"), np.int64)
    codes, uniq = pd.factorize(np.asarray(meas.pop("serial"), dtype=object))
    image_id, m_image = _image_index(codes.astype(np.int64), np.asarray(uniq, dtype=object), images,
                                     points["point_id"], m_point, path)
    measures = {k: np.asarray(v) for k, v in meas.items()}
    measures.update(measure_point=m_point, measure_image=m_image)
    radii = net.get("TargetRadii")
    attrs = {"body": str(net.get("TargetName", "MOON")), "isis_network_id": str(net.get("NetworkId", "")),
             "isis_created": str(net.get("Created", "")), "isis_last_modified": str(net.get("LastModified", "")),
             "isis_description": str(net.get("Description", "")), "isis_user_name": str(net.get("UserName", "")),
             "isis_version": version, "source": str(path)}
    if isinstance(radii, list) and radii:
        values = np.asarray([_num(r) for r in radii], float)
        if not np.all(np.isfinite(values) & (values > 0)):
            raise IsisNetworkFormatError(f"ISIS PVL control network {path}: TargetRadii {radii!r:.80} are not "
                                         "positive numbers")
        attrs["isis_target_radii"] = values
        attrs["radius"] = float(values[0])
    n = len(logs["measure"])
    mlogs = {"measure": logs["measure"], "type": logs["type"], "value": logs["value"], "bool_type": [-1] * n,
             "bool_value": [-1] * n}
    return network_dataset(points, measures, image_id, measure_logs=mlogs, attrs=attrs)


def write_pvl_network(ds: xr.Dataset, path: str | os.PathLike[str]) -> Path:
    """Write a control-network Dataset as a PVL ISIS control network (version 5), atomically."""
    c = _columns_for_writing(ds)
    n_pt, n_m, order = c["n_pt"], c["n_m"], c["order"]
    attrs = dict(ds.attrs)
    image_id = np.asarray(ds["image_id"].values).astype(str)
    g = lambda name, default, n=n_m, dtype=None: _get(ds, name, default, n, dtype)  # noqa: E731
    mcols = {k: g(k, d)[order] for k, d in (
        ("line", np.nan), ("sample", np.nan), ("sample_residual", np.nan), ("line_residual", np.nan),
        ("diameter", np.nan), ("apriori_sample", np.nan), ("apriori_line", np.nan), ("sigma_sample", np.nan),
        ("sigma_line", np.nan), ("measure_type", 3), ("measure_edit_lock", False), ("measure_ignore", False),
        ("measure_jigsaw_rejected", False), ("measure_chooser_name", ""), ("measure_datetime", ""))}
    serial = image_id[c["m_image"][order]]
    logs: dict[int, list] = {}
    if "measure_log_measure" in ds and ds.sizes.get("measure_log", 0):
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        for own, t, v in zip(rank[np.asarray(ds["measure_log_measure"].values, np.int64)],
                             ds["measure_log_type"].values, ds["measure_log_value"].values):
            if int(t) in LOG_TYPES and np.isfinite(v):
                logs.setdefault(int(own), []).append((LOG_TYPES[int(t)], float(v)))
    pcols = {k: g(k, d, n_pt) for k, d in (
        ("edit_lock", False), ("jigsaw_rejected", False), ("reference_index", -1), ("chooser_name", ""),
        ("datetime", ""), ("apriori_surface_source_file", ""), ("apriori_radius_source", -1),
        ("apriori_radius_source_file", ""), ("latitude_constrained", False), ("longitude_constrained", False),
        ("radius_constrained", False))}
    adj = np.asarray(ds["adjusted_xyz"].values, float) if "adjusted_xyz" in ds else np.full((n_pt, 3), np.nan)
    adj_cov = np.asarray(ds["adjusted_cov"].values, float) if "adjusted_cov" in ds else np.full((n_pt, 3, 3), np.nan)
    items: list[Any] = [("NetworkId", str(attrs.get("isis_network_id", Path(path).stem))),
                        ("TargetName", str(attrs.get("body", ""))), ("UserName", str(attrs.get("isis_user_name", ""))),
                        ("Created", str(attrs.get("isis_created", ""))),
                        ("LastModified", str(attrs.get("isis_last_modified", ""))),
                        ("Description", str(attrs.get("isis_description", "")))]
    if np.size(attrs.get("isis_target_radii", [])):
        items.append(("TargetRadii", [float(r) for r in np.atleast_1d(attrs["isis_target_radii"])]))
    items.append(("Version", 5))
    for i in range(n_pt):
        p: list[Any] = [("PointType", ISIS_POINT_TYPES[int(c["isis_type"][i])]), ("PointId", str(c["ids"][i]))]
        for key, col in (("ChooserName", "chooser_name"), ("DateTime", "datetime")):
            if str(pcols[col][i]):
                p.append((key, str(pcols[col][i])))
        for key, flag in (("EditLock", pcols["edit_lock"][i]), ("Ignore", c["ignore"][i]),
                          ("JigsawRejected", pcols["jigsaw_rejected"][i])):
            if flag:
                p.append((key, "True"))
        for key, code, fcol in (("AprioriXYZSource", c["surf"][i], "apriori_surface_source_file"),
                                ("AprioriRadiusSource", pcols["apriori_radius_source"][i], "apriori_radius_source_file")):
            if code >= 0:
                p.append((key, APRIORI_SOURCES[int(code)]))
            if str(pcols[fcol][i]):
                p.append((key + "File", str(pcols[fcol][i])))
        for label, xyz, cov in (("Apriori", c["xyz"][i], c["cov"][i]), ("Adjusted", adj[i], adj_cov[i])):
            if np.all(np.isfinite(xyz)):
                p += [(f"{label}{a}", Unit(float(v), "meters")) for a, v in zip("XYZ", xyz)]
            six = [float(cov[a, b]) for a, b in _COV_INDEX]
            if np.all(np.isfinite(six)) and any(six):
                p.append((f"{label}CovarianceMatrix", six))
        for key, col in (("LatitudeConstrained", "latitude_constrained"), ("LongitudeConstrained", "longitude_constrained"),
                         ("RadiusConstrained", "radius_constrained")):
            if pcols[col][i]:
                p.append((key, "True"))
        for j in range(int(c["m_first"][i]), int(c["m_first"][i] + c["counts"][i])):
            m: list[Any] = [("SerialNumber", str(serial[j])), ("MeasureType", MEASURE_TYPES[int(mcols["measure_type"][j])])]
            for key, col in (("ChooserName", "measure_chooser_name"), ("DateTime", "measure_datetime")):
                if str(mcols[col][j]):
                    m.append((key, str(mcols[col][j])))
            for key, col in (("EditLock", "measure_edit_lock"), ("Ignore", "measure_ignore")):
                if mcols[col][j]:
                    m.append((key, "True"))
            for key, col, shift, unit in (("Sample", "sample", _PIXEL, None), ("Line", "line", _PIXEL, None),
                                          ("Diameter", "diameter", 0.0, None),
                                          ("AprioriSample", "apriori_sample", _PIXEL, None),
                                          ("AprioriLine", "apriori_line", _PIXEL, None),
                                          ("SampleSigma", "sigma_sample", 0.0, "pixels"),
                                          ("LineSigma", "sigma_line", 0.0, "pixels"),
                                          ("SampleResidual", "sample_residual", 0.0, "pixels"),
                                          ("LineResidual", "line_residual", 0.0, "pixels")):
                v = float(mcols[col][j])
                if np.isfinite(v):
                    m.append((key, Unit(v + shift, unit) if unit else v + shift))
            if mcols["measure_jigsaw_rejected"][j]:
                m.append(("JigsawRejected", "True"))
            m += logs.get(j, [])
            if int(pcols["reference_index"][i]) == j - int(c["m_first"][i]):
                m.append(("Reference", "True"))
            p.append(("Group", "ControlMeasure", m))
        items.append(("Object", "ControlPoint", p))
    text = format_pvl([("Object", "ControlNetwork", items)]).encode("latin-1")
    return atomic_write(path, lambda tmp: Path(tmp).write_bytes(text))

"""The control-network Dataset shared by the binary and PVL ISIS network formats.

Its layout and the meaning of every variable are described in :mod:`lunarmap.io.isis_network`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr
from numpy.typing import NDArray

from ..errors import IsisNetworkFormatError, UnknownImageError

__all__ = ["ISIS_POINT_TYPES", "MEASURE_TYPES", "APRIORI_SOURCES", "LABEL_BYTES", "network_dataset"]

#: ISIS point type enum -> name (ControlPointFileEntryV0002.PointType).
ISIS_POINT_TYPES = {0: "Tie", 1: "Ground", 2: "Free", 3: "Constrained", 4: "Fixed"}
#: ISIS measure type enum -> name.
MEASURE_TYPES = {0: "Candidate", 1: "Manual", 2: "RegisteredPixel", 3: "RegisteredSubPixel"}
#: ISIS a-priori source enum -> name.
APRIORI_SOURCES = {0: "None", 1: "User", 2: "AverageOfMeasures", 3: "Reference", 4: "Ellipsoid", 5: "DEM",
                   6: "Basemap", 7: "BundleSolution"}
#: Space ISIS reserves for the label of a binary network.
LABEL_BYTES = 65536
_CONVENTION = "lunarmap_control_network"
_MOON_RADIUS = 1737400.0  # m; the project's default reference sphere (lunarmap.camera.shape.MOON_RADIUS)
_NAN_BITS = np.uint64(0x7FF8000000000000)
_PIXEL = 0.5  # ISIS pixel coordinates = CSM + 0.5
_FREE, _CONSTRAINED, _FIXED, _REFERENCE = 2, 3, 4, 3
_COV_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _factorize(col: Any) -> tuple[NDArray[np.int64], NDArray]:
    """Codes and unique values of a string column (hash-based: fast for a million repeated strings)."""
    codes, uniques = pd.factorize(np.asarray(col, dtype=object))
    return codes.astype(np.int64), np.asarray(uniques, dtype=object)


def _lonlat(xyz: NDArray, radius: float) -> tuple[NDArray, NDArray, NDArray]:
    with np.errstate(invalid="ignore"):
        r = np.linalg.norm(xyz, axis=-1)
        lon = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
        lat = np.degrees(np.arcsin(np.clip(xyz[:, 2] / r, -1, 1)))
    return lon, lat, r - radius


def network_dataset(points: dict[str, Any], measures: dict[str, Any], image_id: NDArray,
                    image_name: NDArray | None = None, point_logs: dict[str, Any] | None = None,
                    measure_logs: dict[str, Any] | None = None, attrs: dict[str, Any] | None = None) -> xr.Dataset:
    """Assemble the control-network Dataset (see :mod:`lunarmap.io.isis_network`) from column dicts; missing ISIS columns get defaults."""
    n_pt = len(points["point_id"])
    n_m = len(measures["measure_point"])
    attrs = dict(attrs or {})
    radius = float(attrs.get("radius", _MOON_RADIUS))
    nan3 = np.full((n_pt, 3), np.nan)
    nan33 = np.full((n_pt, 3, 3), np.nan)

    def pcol(name: str, default: Any, dtype: Any = None) -> NDArray:
        v = points.get(name)
        if v is None:
            return np.full(n_pt, default, dtype=dtype) if np.ndim(default) == 0 else np.array(default)
        return np.asarray(v, dtype=dtype)

    def mcol(name: str, default: Any, dtype: Any = None) -> NDArray:
        v = measures.get(name)
        return np.full(n_m, default, dtype=dtype) if v is None else np.asarray(v, dtype=dtype)

    xyz = pcol("xyz", nan3, float).reshape(n_pt, 3)
    lon, lat, h = _lonlat(xyz, radius)
    obj = lambda a: np.asarray(a).astype(str).astype(object)  # noqa: E731
    data: dict[str, Any] = {
        "point_id": ("point", obj(points["point_id"])),
        "point_type": ("point", pcol("point_type", 0, np.int8),
                       {"flag_values": np.arange(3, dtype=np.int8), "flag_meanings": "tie control check"}),
        "isis_point_type": ("point", pcol("isis_point_type", _FREE, np.int8),
                            {"flag_values": np.arange(5, dtype=np.int8),
                             "flag_meanings": " ".join(ISIS_POINT_TYPES.values())}),
        "xyz": (("point", "axis"), xyz, {"units": "m", "long_name": "a-priori body-fixed coordinates"}),
        "xyz_cov": (("point", "axis", "axis2"), pcol("xyz_cov", nan33, float).reshape(n_pt, 3, 3), {"units": "m2"}),
        "lon": ("point", lon, {"units": "degrees_east"}),
        "lat": ("point", lat, {"units": "degrees_north"}),
        "height": ("point", h, {"units": "m"}),
        "adjusted_xyz": (("point", "axis"), pcol("adjusted_xyz", nan3, float).reshape(n_pt, 3), {"units": "m"}),
        "adjusted_cov": (("point", "axis", "axis2"), pcol("adjusted_cov", nan33, float).reshape(n_pt, 3, 3),
                         {"units": "m2"}),
        "ignore": ("point", pcol("ignore", False, bool)),
        "edit_lock": ("point", pcol("edit_lock", False, bool)),
        "jigsaw_rejected": ("point", pcol("jigsaw_rejected", False, bool)),
        "reference_index": ("point", pcol("reference_index", -1, np.int32)),
        "chooser_name": ("point", obj(pcol("chooser_name", ""))),
        "datetime": ("point", obj(pcol("datetime", ""))),
        "apriori_surface_source": ("point", pcol("apriori_surface_source", -1, np.int8)),
        "apriori_surface_source_file": ("point", obj(pcol("apriori_surface_source_file", ""))),
        "apriori_radius_source": ("point", pcol("apriori_radius_source", -1, np.int8)),
        "apriori_radius_source_file": ("point", obj(pcol("apriori_radius_source_file", ""))),
        "latitude_constrained": ("point", pcol("latitude_constrained", False, bool)),
        "longitude_constrained": ("point", pcol("longitude_constrained", False, bool)),
        "radius_constrained": ("point", pcol("radius_constrained", False, bool)),
        "measure_point": ("measure", mcol("measure_point", 0, np.int64)),
        "measure_image": ("measure", mcol("measure_image", 0, np.int64)),
        "line": ("measure", mcol("line", np.nan, float), {"units": "pixel", "convention": "CSM, first pixel centre 0.5"}),
        "sample": ("measure", mcol("sample", np.nan, float), {"units": "pixel"}),
        "sigma_line": ("measure", mcol("sigma_line", np.nan, float), {"units": "pixel"}),
        "sigma_sample": ("measure", mcol("sigma_sample", np.nan, float), {"units": "pixel"}),
        "measure_type": ("measure", mcol("measure_type", 3, np.int8),
                         {"flag_values": np.arange(4, dtype=np.int8), "flag_meanings": " ".join(MEASURE_TYPES.values())}),
        "line_residual": ("measure", mcol("line_residual", np.nan, float), {"units": "pixel"}),
        "sample_residual": ("measure", mcol("sample_residual", np.nan, float), {"units": "pixel"}),
        "apriori_line": ("measure", mcol("apriori_line", np.nan, float), {"units": "pixel"}),
        "apriori_sample": ("measure", mcol("apriori_sample", np.nan, float), {"units": "pixel"}),
        "diameter": ("measure", mcol("diameter", np.nan, float)),
        "measure_ignore": ("measure", mcol("measure_ignore", False, bool)),
        "measure_edit_lock": ("measure", mcol("measure_edit_lock", False, bool)),
        "measure_jigsaw_rejected": ("measure", mcol("measure_jigsaw_rejected", False, bool)),
        "measure_chooser_name": ("measure", obj(mcol("measure_chooser_name", ""))),
        "measure_datetime": ("measure", obj(mcol("measure_datetime", ""))),
        "image_id": ("image", obj(image_id)),
        "image_name": ("image", obj(image_id if image_name is None else image_name)),
    }
    for prefix, logs, dim in (("point_log", point_logs, "point_log"), ("measure_log", measure_logs, "measure_log")):
        logs = logs or {}
        owner = "point" if prefix == "point_log" else "measure"
        n = len(logs.get(owner, []))
        data[f"{prefix}_{owner}"] = (dim, np.asarray(logs.get(owner, np.zeros(0)), np.int64))
        data[f"{prefix}_type"] = (dim, np.asarray(logs.get("type", np.full(n, -1)), np.int64))
        data[f"{prefix}_value"] = (dim, np.asarray(logs.get("value", np.full(n, np.nan)), float))
        data[f"{prefix}_bool_type"] = (dim, np.asarray(logs.get("bool_type", np.full(n, -1)), np.int64))
        data[f"{prefix}_bool_value"] = (dim, np.asarray(logs.get("bool_value", np.full(n, -1)), np.int8))
    attrs.setdefault("body", "MOON")
    attrs.update(Conventions=_CONVENTION, version=1, radius=radius)
    return xr.Dataset(data, coords={"axis": ["x", "y", "z"], "axis2": ["x", "y", "z"]}, attrs=attrs)


def _image_index(codes: NDArray[np.int64], uniq: NDArray, images: list[str] | None, point_ids: NDArray,
                 m_point: NDArray, path: Path) -> tuple[NDArray, NDArray]:
    """Image ids and each measure's image index from the measures' serial-number codes."""
    if images is None:
        return np.asarray(uniq, dtype=object), codes
    lookup = {str(s): k for k, s in enumerate(images)}
    if len(lookup) != len(images):
        raise IsisNetworkFormatError(f"reading {path}: the image list repeats serial numbers")
    known = np.array([lookup.get(str(s), -1) for s in uniq], dtype=np.int64)
    if np.any(known < 0):
        bad = int(np.nonzero(known < 0)[0][0])
        j = int(np.nonzero(codes == bad)[0][0])
        n_bad = int(np.sum(known[codes] < 0))
        raise UnknownImageError(
            f"ISIS control network {path}: point {point_ids[m_point[j]]!r} has a measure on image {uniq[bad]!r}, "
            f"which is not in the image list ({n_bad} measure(s) on {int(np.sum(known < 0))} unknown image(s))")
    return np.asarray(images, dtype=object), known[codes]


def _require(ds: xr.Dataset, names: tuple[str, ...]) -> None:
    missing = [n for n in names if n not in ds]
    if missing:
        raise IsisNetworkFormatError(f"control-network Dataset lacks {', '.join(missing)}")


def _get(ds: xr.Dataset, name: str, default: Any, n: int, dtype: Any = None) -> NDArray:
    if name in ds:
        return np.asarray(ds[name].values, dtype=dtype)
    return np.full(n, default, dtype=dtype)


def _columns_for_writing(ds: xr.Dataset) -> dict[str, Any]:
    _require(ds, ("point_id", "point_type", "xyz", "measure_point", "measure_image", "line", "sample", "image_id"))
    n_pt, n_m = ds.sizes.get("point", 0), ds.sizes.get("measure", 0)
    ptype = np.asarray(ds["point_type"].values, np.int8)
    xyz = np.asarray(ds["xyz"].values, float).reshape(n_pt, 3)
    cov = np.asarray(ds["xyz_cov"].values, float).reshape(n_pt, 3, 3) if "xyz_cov" in ds else np.full((n_pt, 3, 3), np.nan)
    ignore = _get(ds, "ignore", False, n_pt, bool).copy()
    surf = _get(ds, "apriori_surface_source", -1, n_pt, np.int8).copy()
    if "isis_point_type" in ds:
        isis_type = np.asarray(ds["isis_point_type"].values, np.int8)
    else:
        isis_type = np.where(ptype == 1, np.where(np.all(cov == 0.0, axis=(1, 2)), _FIXED, _CONSTRAINED), _FREE)
    check = ptype == 2
    isis_type = np.where(check, _FREE, isis_type).astype(np.int8)
    ignore[check] = True
    surf[check] = _REFERENCE
    if np.any((ptype == 1) & (isis_type == _FREE)):
        k = int(np.nonzero((ptype == 1) & (isis_type == _FREE))[0][0])
        raise IsisNetworkFormatError(f"control point {ds['point_id'].values[k]!r} has ISIS type Free")
    m_point = np.asarray(ds["measure_point"].values, np.int64)
    m_image = np.asarray(ds["measure_image"].values, np.int64)
    n_img = ds.sizes.get("image", 0)
    if n_m and (m_point.min() < 0 or m_point.max() >= n_pt or m_image.min() < 0 or m_image.max() >= n_img):
        raise IsisNetworkFormatError("control-network Dataset: measure_point or measure_image out of range")
    ids = np.asarray(ds["point_id"].values).astype(str)
    if np.unique(ids).size != ids.size or np.any(ids == ""):
        raise IsisNetworkFormatError("control-network Dataset: point ids must be unique and non-empty")
    order = np.argsort(m_point, kind="stable")  # measures inside their points, in their order
    counts = np.bincount(m_point, minlength=n_pt).astype(np.int64)
    m_first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64) if n_pt else np.zeros(0, np.int64)
    return dict(n_pt=n_pt, n_m=n_m, ptype=ptype, isis_type=isis_type, xyz=xyz, cov=cov, ignore=ignore, surf=surf,
                order=order, counts=counts, m_first=m_first, ids=ids, m_image=m_image)

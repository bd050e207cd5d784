"""ISIS control networks as :class:`~lunarmap.adjust.network.ControlNetwork`, and adjustment results back.

:mod:`lunarmap.io.isis_network` reads and writes the files (every ISIS field, as an
``xarray.Dataset``); this module maps them to the network the adjustment uses and back:

* ISIS *Free* points are tie points, *Constrained* points control points with their a-priori
  covariance, *Fixed* points control points held fixed (an all-zero covariance); an ignored
  Free point whose a-priori coordinates come from a *Reference* is a check point;
* ignored points and ignored measures, and measures without coordinates, are left out of the
  adjustment (``keep_ignored=True`` keeps ignored measures of kept points);
* measures without ``LineSigma`` / ``SampleSigma`` get ``sigma`` pixels;
* image coordinates are already in the CSM convention in the Dataset (ISIS - 0.5).

:func:`isis_dataset` goes the other way, with the adjusted coordinates, their posterior
covariance and the image residuals of a :class:`~lunarmap.adjust.block.BlockResult`, which
:func:`write_isis_network` writes for ``jigsaw``, ``qnet`` or AutoCNet to read.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping

import numpy as np
import xarray as xr

from ..errors import NetworkFormatError
from ..io import isis_network as _files
from .block import BlockResult
from .network import POINT_TYPES, ControlNetwork

__all__ = ["network_from_isis", "read_isis_network", "isis_dataset", "write_isis_network"]


def network_from_isis(ds: xr.Dataset, sigma: float = 1.0, keep_ignored: bool = False) -> ControlNetwork:
    """The :class:`ControlNetwork` of an ISIS control-network Dataset (see the module docstring).

    Parameters
    ----------
    ds : xarray.Dataset
        From :func:`lunarmap.io.isis_network.read_isis_network`.
    sigma : float
        Measurement sigma (pixels) of measures that carry none.
    keep_ignored : bool
        Keep ignored measures (of points that are not ignored).

    Raises
    ------
    NetworkFormatError
        A Constrained point without a-priori coordinates or covariance (the point is named).
    """
    if not (np.isfinite(sigma) and sigma > 0):
        raise NetworkFormatError(f"sigma must be finite and > 0 pixels, got {sigma!r}")
    ptype = np.asarray(ds["point_type"].values, np.int64)
    ignore = np.asarray(ds["ignore"].values, bool) if "ignore" in ds else np.zeros(ptype.size, bool)
    keep_pt = ~ignore | (ptype == POINT_TYPES.index("check"))
    m_point = np.asarray(ds["measure_point"].values, np.int64)
    line, sample = np.asarray(ds["line"].values, float), np.asarray(ds["sample"].values, float)
    keep_m = keep_pt[m_point] & np.isfinite(line) & np.isfinite(sample)
    if not keep_ignored and "measure_ignore" in ds:
        keep_m &= ~np.asarray(ds["measure_ignore"].values, bool)
    new_index = np.cumsum(keep_pt) - 1
    xyz = np.asarray(ds["xyz"].values, float)[keep_pt]
    cov = np.asarray(ds["xyz_cov"].values, float)[keep_pt]
    types = np.array(POINT_TYPES, dtype=object)[ptype[keep_pt]]
    ids = np.asarray(ds["point_id"].values).astype(str)[keep_pt]
    bad = (types == "control") & ~(np.all(np.isfinite(xyz), axis=1) & np.all(np.isfinite(cov), axis=(1, 2)))
    if bad.any():
        raise NetworkFormatError(f"ISIS control point {ids[np.argmax(bad)]!r} is Constrained but has no a-priori "
                                 f"coordinates or covariance ({int(bad.sum())} such point(s))")
    sig = np.column_stack([np.asarray(ds["sigma_line"].values, float), np.asarray(ds["sigma_sample"].values, float)])
    sig = np.where(np.isfinite(sig) & (sig > 0), sig, sigma)[keep_m]
    attrs = {k: v for k, v in ds.attrs.items() if isinstance(v, (str, int, float)) and k not in
             ("Conventions", "version", "radius", "body")}
    return ControlNetwork(
        point_id=ids, point_type=types, xyz=xyz, measure_point=new_index[m_point[keep_m]],
        measure_image=np.asarray(ds["measure_image"].values, np.int64)[keep_m],
        line_sample=np.column_stack([line, sample])[keep_m], measure_sigma=sig,
        image_id=np.asarray(ds["image_id"].values).astype(str),
        image_name=np.asarray(ds["image_name"].values).astype(str) if "image_name" in ds else None,
        xyz_cov=cov, radius=float(ds.attrs.get("radius", 1737400.0)), body=str(ds.attrs.get("body", "MOON")),
        attrs=attrs)


def read_isis_network(path: str | os.PathLike[str], images: list[str] | None = None, sigma: float = 1.0,
                      keep_ignored: bool = False) -> ControlNetwork:
    """Read an ISIS control network (binary or PVL) as a :class:`ControlNetwork` for the adjustment.

    ``images``: serial numbers of the block's images (a measure on another image raises
    :class:`~lunarmap.errors.UnknownImageError`); see :func:`network_from_isis` for the rest.

    Parameters
    ----------
    path : path-like
        The network (``.net`` binary version 2 or 5, or PVL).
    images : list of str, optional
        Serial numbers of the block's images.
    sigma : float
        Measurement sigma (pixels) of measures that carry none.
    keep_ignored : bool
        Keep ignored measures (of points that are not ignored).

    Returns
    -------
    ControlNetwork
        Points, measures (pixels, CSM convention) and images (their serial numbers as ids).
    """
    return network_from_isis(_files.read_isis_network(path, images=images), sigma=sigma, keep_ignored=keep_ignored)


def isis_dataset(net: ControlNetwork, result: BlockResult | None = None,
                 serials: Mapping[str, str] | None = None) -> xr.Dataset:
    """The ISIS control-network Dataset of a :class:`ControlNetwork`, with an adjustment's results.

    Parameters
    ----------
    net : ControlNetwork
        The network (e.g. the one the block was built from).
    result : BlockResult, optional
        A solved block of this network: adjusted coordinates and their posterior covariance
        (m^2) of every point, and the image residuals (``projected - measured``, pixels) of every
        measure are filled in.
    serials : mapping image id -> ISIS serial number, optional
        Default: the image ids are the serial numbers.

    Raises
    ------
    NetworkFormatError
        ``result`` is not a solution of this network (other points or measures).
    """
    n_pt, n_m = net.n_points, net.measure_point.size
    codes = np.array([POINT_TYPES.index(t) for t in net.point_type], dtype=np.int8)
    cov = np.full((n_pt, 3, 3), np.nan) if net.xyz_cov is None else np.array(net.xyz_cov, float)
    isis_type = np.where(codes == 1, np.where(np.all(cov == 0.0, axis=(1, 2)), 4, 3), 2).astype(np.int8)
    points: dict = {"point_id": net.point_id, "point_type": codes, "isis_point_type": isis_type, "xyz": net.xyz,
                    "xyz_cov": np.where(codes[:, None, None] == 0, np.nan, cov)}
    measures: dict = {"measure_point": net.measure_point, "measure_image": net.measure_image,
                      "line": net.line_sample[:, 0], "sample": net.line_sample[:, 1],
                      "sigma_line": net.measure_sigma[:, 0], "sigma_sample": net.measure_sigma[:, 1]}
    if result is not None:
        block_net = result.block.network
        if block_net.n_points != n_pt or np.any(block_net.point_id != net.point_id) or \
                block_net.measure_point.size != n_m or np.any(block_net.measure_point != net.measure_point):
            raise NetworkFormatError("isis_dataset: the result is not a solution of this network "
                                     "(different points or measures)")
        points["adjusted_xyz"] = np.asarray(result.result.points, float)
        points["adjusted_cov"] = np.asarray(result.result.precision().pt_cov, float)
        residual = result.result.image_residuals()
        measures["line_residual"], measures["sample_residual"] = residual[:, 0], residual[:, 1]
    image_id = np.asarray(net.image_id).astype(str)
    serial = np.array([(serials or {}).get(i, i) for i in image_id], dtype=object)
    attrs = {k: v for k, v in net.attrs.items() if isinstance(v, (str, int, float))}
    attrs.update(body=net.body, radius=float(net.radius))
    return _files.network_dataset(points, measures, serial, image_name=net.image_name, attrs=attrs)


def write_isis_network(net: ControlNetwork | xr.Dataset, path: str | os.PathLike[str], result: BlockResult | None = None,
                       serials: Mapping[str, str] | None = None, version: int = 5, pvl: bool = False) -> Path:
    """Write a network (with an adjustment's results) as an ISIS control network, atomically.

    ``pvl=True`` writes the PVL form (``cnetbin2pvl``'s), otherwise binary ``version`` 5 or 2.

    Parameters
    ----------
    net : ControlNetwork or xarray.Dataset
        The network, or its ISIS Dataset (:func:`isis_dataset`).
    path : path-like
        Output file.
    result : BlockResult, optional
        Adjusted coordinates and residuals to write with it.
    serials : mapping image id -> serial number, optional
        ISIS serial numbers of the images (default: the image ids).
    version : int
        Binary format version, 5 or 2.
    pvl : bool
        Write the PVL form instead of binary.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    ds = net if isinstance(net, xr.Dataset) else isis_dataset(net, result=result, serials=serials)
    if pvl:
        from ..io.isis_network_pvl import write_pvl_network

        return write_pvl_network(ds, path)
    return _files.write_isis_network(ds, path, version=version)

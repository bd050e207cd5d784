"""Control networks: points, image measures and images, with a netCDF format.

Format (``lunarmap_control_network`` version 1; netCDF4 via xarray; one group)::

    dimensions: point, measure, image, axis = 3 (x, y, z), axis2 = 3

    point_id        (point)          str    unique point name
    point_type      (point)          int8   0 tie, 1 control, 2 check (flag_values / flag_meanings)
    xyz             (point, axis)    f8     body-fixed coordinates, metres (a-priori / reference values;
                                            NaN allowed for tie points without approximations)
    lon, lat        (point)          f8     planetocentric, degrees (derived from xyz, for reading by eye)
    height          (point)          f8     metres above the sphere of radius ``radius``
    xyz_cov         (point, axis, axis2) f8 covariance of xyz, m^2 (control points; NaN otherwise;
                                            an all-zero matrix holds a control point fixed)
    measure_point   (measure)        i8     index into the point dimension
    measure_image   (measure)        i8     index into the image dimension
    line, sample    (measure)        f8     image coordinates, pixels (CSM convention: centre of the
                                            first pixel at 0.5, 0.5)
    sigma_line, sigma_sample (measure) f8   pixels
    image_id        (image)          str    unique image identifier (product id)
    image_name      (image)          str    file name or description

    attributes: Conventions = "lunarmap_control_network", version = 1, radius (metres), body.

Check points are measured like tie points and carry reference coordinates that the
adjustment does not use (they are for evaluation).  Written atomically (temporary file in the
same folder, then ``os.replace``): a failed write leaves no partial file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ..atomic import atomic_write
from ..camera.geodesy import xyz_to_lonlat_height
from ..camera.shape import MOON_RADIUS
from ..errors import NetworkFormatError
from ..matching.tiepoints import check_tiepoint_table
from ..ncread import load_netcdf
from .problem import BundleProblem, ImageObservations, PointPriors

__all__ = ["POINT_TYPES", "ControlNetwork", "write_network", "read_network", "network_to_dataset",
           "network_from_dataset", "network_from_tiepoints", "merge_networks"]

#: Point types and their codes in the file.
POINT_TYPES = ("tie", "control", "check")
_CONVENTION = "lunarmap_control_network"
_VERSION = 1
# variable -> dimensions of the file layout (module docstring)
_LAYOUT = {"point_id": ("point",), "point_type": ("point",), "xyz": ("point", "axis"),
           "measure_point": ("measure",), "measure_image": ("measure",), "line": ("measure",),
           "sample": ("measure",), "sigma_line": ("measure",), "sigma_sample": ("measure",),
           "image_id": ("image",)}
_OPTIONAL = {"image_name": ("image",), "xyz_cov": ("point", "axis", "axis2")}


def _index_array(values: object, name: str) -> NDArray[np.int64]:
    """Integer indices; refuses NaN and fractions instead of casting them to garbage."""
    a = np.asarray(values)
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
            raise NetworkFormatError(f"control network: {name} holds non-integer indices")
    elif a.size and a.dtype.kind not in "iub":
        raise NetworkFormatError(f"control network: {name} must hold integer indices, got {a.dtype}")
    return a.astype(np.int64)


@dataclass
class ControlNetwork:
    """A control network in memory (see the module docstring for the meaning and units of the fields).

    ``point_type`` holds the names ``"tie"``, ``"control"``, ``"check"``; ``xyz_cov`` is ``None``
    or ``(n_pt, 3, 3)`` (NaN rows for non-control points); ``measure_sigma`` is ``(n_meas, 2)``
    pixels (line, sample).
    """

    point_id: NDArray
    point_type: NDArray
    xyz: NDArray[np.float64]
    measure_point: NDArray[np.int64]
    measure_image: NDArray[np.int64]
    line_sample: NDArray[np.float64]
    measure_sigma: NDArray[np.float64]
    image_id: NDArray
    image_name: NDArray | None = None
    xyz_cov: NDArray[np.float64] | None = None
    radius: float = MOON_RADIUS
    body: str = "MOON"
    attrs: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        try:
            self._convert()
        except (ValueError, TypeError, OverflowError) as err:  # shapes or types numpy cannot use
            raise NetworkFormatError(f"control network: unusable arrays ({err})") from None
        self._check()

    def _convert(self) -> None:
        self.point_id = np.asarray(self.point_id).astype(str)
        self.point_type = np.asarray(self.point_type).astype(str)
        self.xyz = np.asarray(self.xyz, float).reshape(-1, 3)
        self.measure_point = _index_array(self.measure_point, "measure_point")
        self.measure_image = _index_array(self.measure_image, "measure_image")
        self.line_sample = np.asarray(self.line_sample, float).reshape(-1, 2)
        self.image_id = np.asarray(self.image_id).astype(str)
        self.image_name = self.image_id.copy() if self.image_name is None else np.asarray(self.image_name).astype(str)
        n_m = self.measure_point.size
        self.measure_sigma = np.array(np.broadcast_to(np.asarray(self.measure_sigma, float).reshape(-1, 1)
                                                      if np.ndim(self.measure_sigma) == 1
                                                      else np.asarray(self.measure_sigma, float), (n_m, 2)))
        if self.xyz_cov is not None:
            self.xyz_cov = np.asarray(self.xyz_cov, float).reshape(self.point_id.size, 3, 3)

    def _check(self) -> None:
        n_pt, n_m, n_img = self.point_id.size, self.measure_point.size, self.image_id.size
        checks = [
            (self.point_type.shape == (n_pt,), f"point_type has {self.point_type.size} values for {n_pt} points"),
            (self.xyz.shape == (n_pt, 3), f"xyz has {self.xyz.shape[0]} rows for {n_pt} points"),
            (self.measure_image.shape == (n_m,) and self.line_sample.shape == (n_m, 2),
             "measure_point, measure_image and line/sample must have the same length"),
            (self.image_name is not None and self.image_name.shape == (n_img,), "image_name and image_id must have the same length"),
            (np.unique(self.point_id).size == n_pt, "point ids repeat"),
            (np.unique(self.image_id).size == n_img, "image ids repeat"),
            (np.all(np.isin(self.point_type, POINT_TYPES)),
             f"point_type must be one of {POINT_TYPES}, got {sorted(set(self.point_type) - set(POINT_TYPES))}"),
            (n_m == 0 or (self.measure_point.min() >= 0 and self.measure_point.max() < n_pt),
             f"measure_point out of range [0, {n_pt})"),
            (n_m == 0 or (self.measure_image.min() >= 0 and self.measure_image.max() < n_img),
             f"measure_image out of range [0, {n_img})"),
            (np.all(np.isfinite(self.line_sample)), "non-finite (NaN/inf) line/sample in measures"),
            (np.all(np.isfinite(self.measure_sigma) & (self.measure_sigma > 0)), "measure sigma must be finite and > 0"),
        ]
        for ok, msg in checks:
            if not ok:
                raise NetworkFormatError(f"control network: {msg}")
        ref = self.point_type != "tie"
        if not np.all(np.isfinite(self.xyz[ref])):
            raise NetworkFormatError("control network: control/check points need finite xyz")
        ctl = self.point_type == "control"
        if ctl.any() and (self.xyz_cov is None or not np.all(np.isfinite(self.xyz_cov[ctl]))):
            raise NetworkFormatError("control network: control points need a finite xyz_cov")

    @property
    def n_points(self) -> int:
        return int(self.point_id.size)

    @property
    def n_images(self) -> int:
        return int(self.image_id.size)

    def indices(self, kind: str) -> NDArray[np.int64]:
        """Indices of the points of type ``kind`` (``"tie"``, ``"control"``, ``"check"``)."""
        if kind not in POINT_TYPES:
            raise NetworkFormatError(f"point type must be one of {POINT_TYPES}, got {kind!r}")
        return np.nonzero(self.point_type == kind)[0]

    def observations(self, to_model: Callable[[NDArray, NDArray], NDArray] | None = None) -> ImageObservations:
        """Image observations for a :class:`~lunarmap.adjust.problem.BundleProblem`.

        Parameters
        ----------
        to_model : callable, optional
            ``to_model(image_index (n,), line_sample (n, 2)) -> (n, 2)``: converts the measures into the
            image model's coordinates (pixels).  Default: ``(line, sample)`` unchanged, the convention of
            :class:`~lunarmap.adjust.sensors.SensorImageModel`.  The sigmas are passed on in
            (line, sample) order, so the converter must keep that axis order.
        """
        xy = self.line_sample if to_model is None else np.asarray(to_model(self.measure_image, self.line_sample))
        return ImageObservations(self.measure_image.copy(), self.measure_point.copy(), xy, self.measure_sigma.copy())

    def priors(self, representation: str = "covariance") -> PointPriors | None:
        """Priors of the control points, or ``None`` without control points.

        ``representation``: ``"covariance"`` (the full ``xyz_cov``) or ``"isotropic-bound"`` (per-axis
        sigma = square root of the largest eigenvalue: conservative, for per-axis weighting).
        """
        c = self.indices("control")
        if c.size == 0:
            return None
        assert self.xyz_cov is not None, "control points without covariance"     # _check requires it
        cov = self.xyz_cov[c]
        if representation == "covariance":
            return PointPriors(c, self.xyz[c], cov=cov)
        if representation != "isotropic-bound":
            raise NetworkFormatError(f"representation must be 'covariance' or 'isotropic-bound', got {representation!r}")
        bound = np.sqrt(np.maximum(np.linalg.eigvalsh(cov)[:, -1], 0.0))
        return PointPriors(c, self.xyz[c], np.repeat(bound[:, None], 3, axis=1))

    def to_problem(self, model, cam_params: NDArray, points: NDArray | None = None,
                   to_model: Callable[[NDArray, NDArray], NDArray] | None = None, terms: list | None = None,
                   representation: str = "covariance") -> BundleProblem:
        """A :class:`~lunarmap.adjust.problem.BundleProblem` of this network.

        ``points (n_pt, 3)`` metres are the initial values; by default the network's ``xyz`` of tie and
        control points (check-point reference values are not used as start values: pass ``points``,
        e.g. from :func:`lunarmap.adjust.intersection.intersect_points`).
        """
        if points is None:
            points = self.xyz.copy()
            if (self.point_type == "check").any() or not np.all(np.isfinite(points)):
                raise NetworkFormatError("control network: initial points needed (check points or tie points "
                                         "without coordinates); pass points=")
        return BundleProblem(model, cam_params, points, self.observations(to_model), self.priors(representation),
                             terms=list(terms or []))


def network_from_tiepoints(tiepoints: xr.Dataset, prefix: str = "tp", radius: float = MOON_RADIUS) -> ControlNetwork:
    """A control network of tie points from the matcher's tie-point table.

    Parameters
    ----------
    tiepoints : xarray.Dataset
        The table of :func:`lunarmap.matching.find_tiepoints` (``point_id``, ``image_id``, ``line``,
        ``sample``, ``sigma_line``, ``sigma_sample`` per observation; image names in ``image``).
    prefix : str
        Point ids become ``f"{prefix}{point_id}"``.
    radius : float
        Reference radius of the network, metres.

    Returns
    -------
    ControlNetwork
        Tie points without coordinates (NaN ``xyz``), measured with the matching sigmas (pixels).

    Raises
    ------
    NetworkFormatError
        The dataset is not a tie-point table (missing variables, image index out of range).
    """
    check_tiepoint_table(tiepoints, NetworkFormatError)
    ids, inverse = np.unique(tiepoints["point_id"].values.astype(np.int64), return_inverse=True)
    n_pt = ids.size
    return ControlNetwork(
        point_id=np.array([f"{prefix}{i}" for i in ids]), point_type=np.full(n_pt, "tie"),
        xyz=np.full((n_pt, 3), np.nan), measure_point=inverse,
        measure_image=tiepoints["image_id"].values.astype(np.int64),
        line_sample=np.column_stack([tiepoints["line"].values, tiepoints["sample"].values]),
        measure_sigma=np.column_stack([tiepoints["sigma_line"].values, tiepoints["sigma_sample"].values]),
        image_id=np.asarray(tiepoints["image"].values).astype(str), radius=radius,
        attrs={"source": "lunarmap.matching tie points"})


def merge_networks(*networks: ControlNetwork) -> ControlNetwork:
    """One network of several (tie points from matching, control and check points measured elsewhere).

    Images are joined by ``image_id``; point ids must be unique across the networks.

    Raises
    ------
    NetworkFormatError
        Repeated point ids, or networks with different radii or bodies.
    """
    if not networks:
        raise NetworkFormatError("merge_networks needs at least one network")
    first = networks[0]
    for net in networks[1:]:
        if net.radius != first.radius or net.body != first.body:
            raise NetworkFormatError(f"cannot merge networks of different bodies/radii "
                                     f"({first.body} {first.radius} m vs {net.body} {net.radius} m)")
    image_ids: list[str] = []
    names: dict[str, str] = {}
    for net in networks:
        assert net.image_name is not None       # set by __post_init__
        for i, n in zip(net.image_id, net.image_name):
            if i not in names:
                names[i] = n
                image_ids.append(i)
    index = {k: j for j, k in enumerate(image_ids)}
    offset = 0
    parts: dict[str, list] = {k: [] for k in ("pid", "ptype", "xyz", "cov", "mp", "mi", "ls", "sig")}
    for net in networks:
        parts["pid"].append(net.point_id)
        parts["ptype"].append(net.point_type)
        parts["xyz"].append(net.xyz)
        parts["cov"].append(np.full((net.n_points, 3, 3), np.nan) if net.xyz_cov is None else net.xyz_cov)
        parts["mp"].append(net.measure_point + offset)
        parts["mi"].append(np.array([index[i] for i in net.image_id], dtype=np.int64)[net.measure_image]
                           if net.measure_image.size else np.zeros(0, np.int64))
        parts["ls"].append(net.line_sample)
        parts["sig"].append(net.measure_sigma)
        offset += net.n_points
    return ControlNetwork(
        point_id=np.concatenate(parts["pid"]), point_type=np.concatenate(parts["ptype"]),
        xyz=np.concatenate(parts["xyz"]), measure_point=np.concatenate(parts["mp"]),
        measure_image=np.concatenate(parts["mi"]), line_sample=np.concatenate(parts["ls"]),
        measure_sigma=np.concatenate(parts["sig"]), image_id=np.array(image_ids),
        image_name=np.array([names[i] for i in image_ids]), xyz_cov=np.concatenate(parts["cov"]),
        radius=first.radius, body=first.body, attrs=dict(first.attrs))


def network_to_dataset(net: ControlNetwork) -> xr.Dataset:
    """The netCDF layout of the module docstring as an :class:`xarray.Dataset`."""
    lon, lat, h = xyz_to_lonlat_height(np.where(np.isfinite(net.xyz), net.xyz, np.nan), net.radius) \
        if net.n_points else (np.zeros(0), np.zeros(0), np.zeros(0))
    cov = np.full((net.n_points, 3, 3), np.nan) if net.xyz_cov is None else net.xyz_cov
    codes = np.array([POINT_TYPES.index(t) for t in net.point_type], dtype=np.int8)
    ds = xr.Dataset(
        {
            "point_id": ("point", net.point_id.astype(object)),
            "point_type": ("point", codes, {"flag_values": np.arange(3, dtype=np.int8),
                                            "flag_meanings": " ".join(POINT_TYPES)}),
            "xyz": (("point", "axis"), net.xyz, {"units": "m", "long_name": "body-fixed coordinates"}),
            "lon": ("point", lon, {"units": "degrees_east"}),
            "lat": ("point", lat, {"units": "degrees_north", "long_name": "planetocentric latitude"}),
            "height": ("point", h, {"units": "m", "long_name": "height above the reference sphere"}),
            "xyz_cov": (("point", "axis", "axis2"), cov, {"units": "m2"}),
            "measure_point": ("measure", net.measure_point),
            "measure_image": ("measure", net.measure_image),
            "line": ("measure", net.line_sample[:, 0], {"units": "pixel", "convention": "CSM, first pixel centre 0.5"}),
            "sample": ("measure", net.line_sample[:, 1], {"units": "pixel"}),
            "sigma_line": ("measure", net.measure_sigma[:, 0], {"units": "pixel"}),
            "sigma_sample": ("measure", net.measure_sigma[:, 1], {"units": "pixel"}),
            "image_id": ("image", net.image_id.astype(object)),
            "image_name": ("image", np.asarray(net.image_name).astype(object)),
        },
        coords={"axis": ["x", "y", "z"], "axis2": ["x", "y", "z"]},
        attrs={**{k: v for k, v in net.attrs.items() if isinstance(v, (str, int, float))},
               "Conventions": _CONVENTION, "version": _VERSION, "radius": float(net.radius), "body": net.body},
    )
    return ds


def network_from_dataset(ds: xr.Dataset) -> ControlNetwork:
    """Inverse of :func:`network_to_dataset`; raises :class:`~lunarmap.errors.NetworkFormatError`."""
    if ds.attrs.get("Conventions") != _CONVENTION:
        raise NetworkFormatError(f"not a lunarmap control network (Conventions={ds.attrs.get('Conventions')!r})")
    try:
        version = int(ds.attrs.get("version", -1))
    except (TypeError, ValueError):
        raise NetworkFormatError(f"control network version {ds.attrs.get('version')!r} is not an integer") from None
    if version > _VERSION:
        raise NetworkFormatError(f"control network version {ds.attrs.get('version')} is newer than {_VERSION}")
    missing = [v for v in _LAYOUT if v not in ds]
    if missing:
        raise NetworkFormatError(f"control network: missing variable(s) {', '.join(missing)}")
    for name, dims in {**_LAYOUT, **_OPTIONAL}.items():
        if name in ds and ds[name].dims != dims:
            raise NetworkFormatError(f"control network: {name} has dimensions {ds[name].dims}, expected {dims}")
    for name in ("axis", "axis2"):
        if ds.sizes.get(name, 3) != 3:
            raise NetworkFormatError(f"control network: dimension {name} has length {ds.sizes[name]}, expected 3")
    for name in ("xyz", "line", "sample", "sigma_line", "sigma_sample", "xyz_cov"):
        if name in ds and ds[name].dtype.kind not in "iuf":
            raise NetworkFormatError(f"control network: {name} must be numeric, got {ds[name].dtype}")
    codes = _index_array(ds["point_type"].values, "point_type")
    if codes.size and (codes.min() < 0 or codes.max() >= len(POINT_TYPES)):
        raise NetworkFormatError(f"control network: point_type codes must be 0..{len(POINT_TYPES) - 1}")
    try:
        radius = float(ds.attrs.get("radius", MOON_RADIUS))
    except (TypeError, ValueError):
        radius = float("nan")
    if not (np.isfinite(radius) and radius > 0):
        raise NetworkFormatError(f"control network: radius {ds.attrs.get('radius')!r} is not a positive number")
    keep = ("Conventions", "version", "radius", "body")
    return ControlNetwork(
        point_id=ds["point_id"].values, point_type=np.array(POINT_TYPES, dtype=object)[codes],
        xyz=ds["xyz"].values, measure_point=ds["measure_point"].values, measure_image=ds["measure_image"].values,
        line_sample=np.column_stack([ds["line"].values, ds["sample"].values]),
        measure_sigma=np.column_stack([ds["sigma_line"].values, ds["sigma_sample"].values]),
        image_id=ds["image_id"].values,
        image_name=ds["image_name"].values if "image_name" in ds else None,
        xyz_cov=ds["xyz_cov"].values if "xyz_cov" in ds else None,
        radius=radius, body=str(ds.attrs.get("body", "MOON")),
        attrs={k: v for k, v in ds.attrs.items() if k not in keep})


def write_network(net: ControlNetwork, path: str | os.PathLike) -> Path:
    """Write ``net`` to a netCDF file atomically (temporary file beside ``path``, then ``os.replace``).

    Raises
    ------
    NetworkFormatError
        The folder does not exist.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise NetworkFormatError(f"cannot write {path}: folder {folder} does not exist")
    ds = network_to_dataset(net)   # built first: an invalid network never creates a temporary file
    return atomic_write(path, lambda tmp: ds.to_netcdf(tmp, engine="netcdf4"))


def read_network(path: str | os.PathLike) -> ControlNetwork:
    """Read a network written by :func:`write_network` (file closed on return).

    Raises
    ------
    FileNotFoundError
        No such file.
    NetworkFormatError
        Not a lunarmap control network, or an inconsistent one.
    """
    ds = load_netcdf(path, NetworkFormatError, "control network")
    try:
        return network_from_dataset(ds)
    except NetworkFormatError as err:   # name the file: the dataset does not know where it came from
        raise NetworkFormatError(f"{path}: {err}") from None

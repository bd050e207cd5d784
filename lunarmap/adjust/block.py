"""A block adjustment of named images on their own sensor models: from tie points to adjusted sensors.

:func:`build_block` joins the pieces a user has after matching:

* the sensor model of every image (cameras from SPICE, ISDs or cubes; RFMs), by image name;
* a :class:`~lunarmap.adjust.network.ControlNetwork` of measurements: tie points from the matcher
  (:func:`~lunarmap.adjust.network.network_from_tiepoints`), control points (with a-priori
  coordinates and covariance), check points (measured like tie points; their reference coordinates
  are kept for evaluation only);
* optionally navigation observations (:class:`NavigationSpec`): the sensors' own orientation is the
  navigation, observed with sigmas, with per-orbit offsets and drifts (DLR paper, ``seeds/004``,
  Eqs. 2-3);
* optionally reference DTMs (:class:`~lunarmap.adjust.terrain.ReferenceDtm`): the heights of the tie
  points inside each DTM are observed (:mod:`lunarmap.adjust.terrain`), one observation group per DTM;

into a :class:`~lunarmap.adjust.problem.BundleProblem` over a
:class:`~lunarmap.adjust.sensors.SensorImageModel`, with start values of the points from forward
intersection through the sensors. :func:`solve_block` adjusts it and returns a :class:`BlockResult`:
adjusted sensor models (new objects), points with their covariances, and the errors of check
points against their reference coordinates next to the sigma the adjustment predicts for them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ..camera.corrections import FrameCorrections, LineScanCorrections, PushFrameCorrections
from ..camera.geodesy import enu_basis, xyz_to_lonlat_height
from ..camera.sensor import SensorModel
from ..errors import AdjustmentInputError, UnobservedParameterError
from .altimetry import AltimetryObservations, LaserAltimetry, altimetry_observations
from .intersection import intersect_points
from .jitter import JitterSmoothness, JitterSpec
from .navigation import NavigationObservations
from .network import ControlNetwork, network_from_tiepoints
from .problem import BundleProblem
from .result import AdjustmentResult
from .sensors import SensorImageModel
from .solver import SolverOptions, solve
from .start import MAX_RANGE, screen_starts
from .terrain import DtmHeights, ReferenceDtm, dtm_heights

__all__ = ["NavigationSpec", "Block", "BlockResult", "build_block", "solve_block", "navigation_observations"]


@dataclass
class NavigationSpec:
    """Navigation (a-priori orientation) observations of the cameras of a block.

    The reference orientation of every camera *is* its navigation, so each image's
    exterior-orientation corrections are observed as zero with these sigmas; per orbit (or any
    group of images sharing a navigation bias) an offset ``c_o`` and a drift ``d_o`` per parameter
    are ``"fixed"`` (zero), ``"free"`` or ``"observed"`` (zero-mean pseudo-observations with
    ``offset_sigma`` / ``drift_sigma``): ``correction = c_o + s d_o + e`` with ``s`` the image
    time minus the orbit's mean image time, seconds (see
    :class:`~lunarmap.adjust.navigation.NavigationObservations`).

    Parameters
    ----------
    orbit : mapping image name -> orbit label
        The navigation group of every camera image (images not listed are not observed).
    position_sigma : float
        Random (per image) position error of the navigation, metres.
    attitude_sigma : float
        Random (per image) attitude error, radians.
    position_rate_sigma, attitude_rate_sigma : float, optional
        Rate errors within one image (m/s, rad/s): sigma of the higher polynomial coefficients of
        line-scan and push-frame corrections, ``rate * t_half`` (half the image duration). ``None``: those
        coefficients are not observed.
    offset, drift : str or sequence of 6 str
        Modes for ``[w_x, w_y, w_z, c_x, c_y, c_z]`` (attitude radians, position metres).
    offset_sigma, drift_sigma : sequence of 6 float, optional
        Sigmas of ``"observed"`` offsets (rad, m) and drifts (rad/s, m/s).
    """

    orbit: Mapping[str, object]
    position_sigma: float
    attitude_sigma: float
    position_rate_sigma: float | None = None
    attitude_rate_sigma: float | None = None
    offset: str | Sequence[str] = "fixed"
    drift: str | Sequence[str] = "fixed"
    offset_sigma: Sequence[float] | None = None
    drift_sigma: Sequence[float] | None = None


def _image_time(sensor: SensorModel) -> float:
    t = getattr(sensor, "center_time", None)
    if t is None:
        raise AdjustmentInputError(f"{sensor!r} has no exposure time: navigation observations need cameras")
    return float(t)


def navigation_observations(model: SensorImageModel, spec: NavigationSpec, names: Sequence[str],
                            times: Mapping[str, float] | None = None) -> NavigationObservations:
    """The navigation term of a block (see :class:`NavigationSpec`).

    Parameters
    ----------
    model : SensorImageModel
    spec : NavigationSpec
    names : sequence of str
        Image names in model order.
    times : mapping name -> ET seconds, optional
        Image times for the drifts; by default each camera's ``center_time``.
    """
    n, p = model.n_images, model.n_params
    sigma = np.full((n, p), np.inf)
    groups: dict[object, int] = {}
    orbit = np.zeros(n, dtype=np.int64)
    t = np.zeros(n)
    for i, (name, corr) in enumerate(zip(names, model.corrections)):
        if name not in spec.orbit:
            continue
        if isinstance(corr, FrameCorrections):
            sigma[i, :6] = [spec.attitude_sigma] * 3 + [spec.position_sigma] * 3
        elif isinstance(corr, (LineScanCorrections, PushFrameCorrections)):   # time polynomials alike
            sigma[i, :6] = [spec.attitude_sigma] * 3 + [spec.position_sigma] * 3
            for k in range(1, corr.degree + 1):
                if spec.attitude_rate_sigma is not None:
                    sigma[i, 6 * k:6 * k + 3] = spec.attitude_rate_sigma * corr.t_half
                if spec.position_rate_sigma is not None:
                    sigma[i, 6 * k + 3:6 * k + 6] = spec.position_rate_sigma * corr.t_half
        else:
            raise AdjustmentInputError(f"{name}: navigation observations apply to cameras, not to "
                                       f"{type(corr.sensor).__name__}")
        orbit[i] = groups.setdefault(spec.orbit[name], len(groups))
        t[i] = float(times[name]) if times is not None and name in times else _image_time(model.sensors[i])
    if not groups:
        raise AdjustmentInputError("navigation: no image of the block is listed in NavigationSpec.orbit")
    for g in range(len(groups)):
        m = (orbit == g) & np.isfinite(sigma[:, 0])
        t[m] -= t[m].mean()

    def modes(m: str | Sequence[str]) -> list[str]:
        six = [m] * 6 if isinstance(m, str) else list(m)
        if len(six) != 6:
            raise AdjustmentInputError(f"navigation offset/drift modes need 1 or 6 values, got {m!r}")
        return six + ["fixed"] * (p - 6)

    def pad(v: Sequence[float] | None) -> NDArray | None:
        return None if v is None else np.concatenate([np.asarray(v, float).reshape(6), np.ones(p - 6)])

    return NavigationObservations(np.zeros((n, p)), sigma, orbit, t, offset=modes(spec.offset),
                                  drift=modes(spec.drift), offset_sigma=pad(spec.offset_sigma),
                                  drift_sigma=pad(spec.drift_sigma), name="navigation", orbit_names=list(groups))


@dataclass
class Block:
    """An adjustment block of named images (built by :func:`build_block`).

    Attributes
    ----------
    names : list of str
        Image names, in model order.
    model : SensorImageModel
        The images' sensor models and correction parameters.
    network : ControlNetwork
        The measurements (its images reordered to ``names``).
    problem : BundleProblem
    navigation : NavigationObservations or None
    terrain : list of DtmHeights
        The reference-DTM terms (one per DTM), in the order given.
    altimetry : list of AltimetryObservations
        The laser-altimetry terms (one per instrument), in the order given.
    starts : xarray.Dataset or None
        The start-value decisions of :func:`build_block` (points started from a best guess, and why).
    jitter : JitterSmoothness or None
        The smoothness prior of the line-scan jitter splines (``build_block(jitter=...)``).
    """

    names: list[str]
    model: SensorImageModel
    network: ControlNetwork
    problem: BundleProblem
    navigation: NavigationObservations | None
    terrain: list[DtmHeights] = field(default_factory=list)
    #: points whose intersection failed its bounds and were started from a best guess, with why
    #: (:func:`~lunarmap.adjust.start.screen_starts`); None for a block not built by :func:`build_block`
    starts: xr.Dataset | None = None
    jitter: JitterSmoothness | None = None
    altimetry: list[AltimetryObservations] = field(default_factory=list)

    @property
    def sensors(self) -> dict[str, SensorModel]:
        return dict(zip(self.names, self.model.sensors))


def build_block(sensors: Mapping[str, SensorModel], network: ControlNetwork | xr.Dataset, *, degree: int = 1,
                navigation: NavigationSpec | None = None, times: Mapping[str, float] | None = None,
                representation: str = "covariance", terrain: Sequence[ReferenceDtm] = (),
                unintersectable: str = "raise", max_range: float = MAX_RANGE,
                jitter: JitterSpec | None = None, altimetry: Sequence[LaserAltimetry] = ()) -> Block:
    """Build an adjustment block (see the module docstring).

    Parameters
    ----------
    sensors : mapping image name -> SensorModel
        The sensor model of every image of the block (its orientation is the reference).
    network : ControlNetwork or xarray.Dataset
        Measurements (a tie-point table from :func:`~lunarmap.matching.find_tiepoints` is converted
        with :func:`~lunarmap.adjust.network.network_from_tiepoints`).
    degree : int
        Polynomial degree of line-scan corrections (0-2).
    navigation : NavigationSpec, optional
        Navigation observations of the cameras.
    times : mapping name -> ET seconds, optional
        Image times for navigation drifts (default: the cameras' ``center_time``).
    representation : str
        Control-point weighting, see :meth:`ControlNetwork.priors`.
    terrain : sequence of ReferenceDtm
        Reference DTMs whose heights observe the tie points inside them (:mod:`lunarmap.adjust.terrain`);
        points outside a DTM or on its NaN nodes are skipped (``block.terrain[k].skipped``).
    unintersectable : {"raise", "best_guess"}
        A free point whose intersection is not finite, behind one of its cameras, farther than ``max_range``
        times a camera's height above the reference sphere or farther from the reference sphere than the cameras' median
        height is refused (``"raise"``), or started from its robust
        intersection or the model's prediction (``"best_guess"``; recorded in ``Block.starts``), for quality
        control to judge its rays (:func:`~lunarmap.adjust.start.screen_starts`).
    max_range : float
        The distance bound of an intersection, times its camera's height above the reference sphere.
    jitter : JitterSpec, optional
        A cubic B-spline attitude correction (knots every ``jitter.knot_lines`` lines) on top of the
        polynomial of the line-scan images (all, or ``jitter.images``), with its smoothness prior as an
        observation group of its own (``Block.jitter``, :mod:`lunarmap.adjust.jitter`).
    altimetry : sequence of LaserAltimetry
        Laser-altimetry shots observing the surface the tie points span (:mod:`lunarmap.adjust.altimetry`),
        with an offset (and drift) per track; shots outside the points' triangulation are skipped
        (``block.altimetry[k].skipped``). The block is then solved on its whole normal equations.

    Returns
    -------
    Block
        The block: ``names``, the sensor ``model``, the ``network``, the ``problem`` to solve and the
        ``navigation`` observations; adjust it with :func:`lunarmap.solve`.

    Raises
    ------
    AdjustmentInputError
        Measurements on images that have no sensor model (named), points that cannot be
        intersected within the bounds (with ``unintersectable="raise"``; the count, the first and why).
    UnobservedParameterError
        An image without measurements (named), a free point with fewer than two rays.
    DistortionPartialsError
        A camera whose distortion has no partial derivatives.
    DtmCrsError, DtmCoverageError, TerrainInputError
        A reference DTM without a Moon CRS, covering no tie point, or unreadable.
    JitterKnotSpacingError
        A jitter knot spacing below one line.
    AltimetryInputError, AltimetryCoverageError
        A bad shot table, or no shot inside the tie points' triangulation.
    """
    net = network_from_tiepoints(network) if isinstance(network, xr.Dataset) else network
    if not isinstance(net, ControlNetwork):
        raise AdjustmentInputError(f"network must be a ControlNetwork or a tie-point Dataset, got {type(net).__name__}")
    names = [str(k) for k in sensors]
    measured = sorted(set(net.image_id[np.unique(net.measure_image)].tolist()))
    unknown = [i for i in measured if i not in sensors]
    if unknown:
        raise AdjustmentInputError(f"the measurements name {len(unknown)} image(s) without a sensor model: "
                                   f"{', '.join(unknown[:5])}{' ...' if len(unknown) > 5 else ''}")
    lonely = [k for k in names if k not in measured]
    if lonely:
        raise UnobservedParameterError(f"{len(lonely)} image(s) have no measurements: {', '.join(lonely[:5])}"
                                       f"{' ...' if len(lonely) > 5 else ''}; remove them from the block")
    order = {k: i for i, k in enumerate(names)}
    net = ControlNetwork(point_id=net.point_id, point_type=net.point_type, xyz=net.xyz,
                         measure_point=net.measure_point,
                         measure_image=np.array([order[k] for k in net.image_id], np.int64)[net.measure_image],
                         line_sample=net.line_sample, measure_sigma=net.measure_sigma, image_id=np.array(names),
                         xyz_cov=net.xyz_cov, radius=net.radius, body=net.body, attrs=net.attrs)
    spacing = None
    if jitter is not None:
        if not isinstance(jitter, JitterSpec):
            raise AdjustmentInputError(f"jitter must be a JitterSpec, got {type(jitter).__name__}")
        wanted = set(names) if jitter.images is None else {str(k) for k in jitter.images}
        missing = sorted(wanted - set(names))
        if missing:
            raise AdjustmentInputError(f"jitter: {len(missing)} image(s) not in the block: {', '.join(missing[:5])}")
        spacing = [jitter.knot_lines if k in wanted else None for k in names]
    model = SensorImageModel([sensors[k] for k in names], degree=degree, names=names, jitter_lines=spacing)
    params0 = model.initial_params()
    obs = net.observations()
    X0 = model.initial_points(params0, obs.cam_idx, obs.pt_idx, obs.xy, net.n_points)
    control = net.point_type == "control"
    X0[control] = net.xyz[control]
    rays = np.bincount(obs.pt_idx, minlength=net.n_points)
    multi = (rays >= 2) & ~control
    if multi.any():
        use = multi[obs.pt_idx]
        remap = -np.ones(net.n_points, np.int64)
        remap[multi] = np.arange(int(multi.sum()))
        with np.errstate(all="ignore"):
            refined = intersect_points(model, params0, obs.cam_idx[use], remap[obs.pt_idx[use]], obs.xy[use],
                                       obs.sigma[use], n_pt=int(multi.sum()), x0=X0[multi])
        X0[multi] = refined.xyz
    X0, starts = screen_starts(model, params0, obs, X0, multi, net.point_id, unintersectable, max_range,
                               net.radius)
    bad = ~np.all(np.isfinite(X0), axis=1)
    if bad.any():
        first = net.point_id[np.argmax(bad)]
        raise AdjustmentInputError(f"{int(bad.sum())} point(s) could not be intersected from their rays "
                                   f"(first: {first}); check their measurements")
    terms: list = []
    nav = None
    if navigation is not None:
        nav = navigation_observations(model, navigation, names, times)
        terms.append(nav)
    dtms = []
    for ref in terrain:
        if not isinstance(ref, ReferenceDtm):
            raise AdjustmentInputError(f"terrain must be ReferenceDtm objects, got {type(ref).__name__}")
        cand = np.isin(net.point_type, list(ref.point_types))
        dtms.append(dtm_heights(ref, X0, model.n_images * model.n_params, model.n_images, cand, net.point_id))
    terms += dtms
    smooth = None
    if jitter is not None:
        smooth = JitterSmoothness(model, jitter.sigma, jitter.zero_sigma)
        terms.append(smooth)
    alts = []
    for alt in altimetry:
        if not isinstance(alt, LaserAltimetry):
            raise AdjustmentInputError(f"altimetry must be LaserAltimetry objects, got {type(alt).__name__}")
        cand = np.isin(net.point_type, list(alt.point_types))
        alts.append(altimetry_observations(alt, X0, model.n_images * model.n_params, model.n_images, cand))
    terms += alts
    problem = net.to_problem(model, params0, points=X0, terms=terms, representation=representation)
    return Block(names, model, net, problem, nav, dtms, starts, jitter=smooth, altimetry=alts)


@dataclass
class BlockResult:
    """A solved :class:`Block`: adjusted sensors, points with precision, check-point errors.

    Attributes
    ----------
    block : Block
    result : AdjustmentResult
        The solver's result (parameters, sigma0, residuals, precision).
    """

    block: Block
    result: AdjustmentResult

    @property
    def sigma0(self) -> float:
        """A-posteriori standard deviation of unit weight (dimensionless)."""
        return self.result.sigma0

    @property
    def converged(self) -> bool:
        return self.result.converged

    def adjusted_sensors(self) -> dict[str, SensorModel]:
        """The adjusted sensor models by image name (new objects; the block's sensors are untouched)."""
        return dict(zip(self.block.names, self.block.model.adjusted(self.result.cam_params)))

    def corrections(self) -> xr.Dataset:
        """Estimated correction parameters per image with their posterior sigma (padding is NaN)."""
        m = self.block.model
        mask = m.param_mask
        prec = self.result.precision()
        values = np.where(mask, self.result.cam_params, np.nan)
        sigma = np.where(mask, np.sqrt(np.diagonal(prec.cam_cov, axis1=1, axis2=2)), np.nan)
        return xr.Dataset({"value": (("image", "param"), values), "sigma": (("image", "param"), sigma)},
                          coords={"image": self.block.names, "param": list(m.param_names)},
                          attrs={"units": "rad for w*, m for c*, px or 1 for affine a*/b*",
                                 "sigma0": self.sigma0})

    def points(self) -> xr.Dataset:
        """Adjusted points: ids, types, body-fixed metres, lon/lat/height, posterior covariance (m^2)."""
        net = self.block.network
        X = self.result.points
        cov = self.result.precision().pt_cov
        lon, lat, h = xyz_to_lonlat_height(X, net.radius)
        return xr.Dataset(
            {"point_type": ("point", net.point_type.astype(object)),
             "xyz": (("point", "axis"), X, {"units": "m"}),
             "covariance": (("point", "axis", "axis2"), cov, {"units": "m2"}),
             "lon": ("point", lon, {"units": "degrees_east"}), "lat": ("point", lat, {"units": "degrees_north"}),
             "height": ("point", h, {"units": "m"}),
             "reference_xyz": (("point", "axis"), net.xyz, {"units": "m"})},
            coords={"point": net.point_id.astype(object), "axis": ["x", "y", "z"], "axis2": ["x", "y", "z"]},
            attrs={"sigma0": self.sigma0, "radius_m": float(net.radius)})

    def check_points(self, points: NDArray | None = None) -> xr.Dataset:
        """Errors of check points against their reference coordinates, east/north/up (metres).

        Parameters
        ----------
        points : ndarray (n_pt, 3), optional
            Coordinates to evaluate (default: the adjusted points; pass e.g. the start values for
            the errors before the adjustment).

        Returns
        -------
        xarray.Dataset
            ``error (check, enu)`` metres, ``sigma (check, enu)`` the posterior sigma of the adjusted
            points, ``normalized`` = error / sigma; attributes ``rms_m`` (east, north, up) and
            ``normalized_rms``.
        """
        net = self.block.network
        c = np.flatnonzero(net.point_type == "check")
        if c.size == 0:
            raise AdjustmentInputError("the block has no check points")
        X = self.result.points if points is None else np.asarray(points, float)
        E = enu_basis(*xyz_to_lonlat_height(net.xyz[c], net.radius)[:2])   # (k, 3, 3) rows east, north, up
        err = np.einsum("kij,kj->ki", E, X[c] - net.xyz[c])
        C = np.einsum("kij,kjl,kml->kim", E, self.result.precision().pt_cov[c], E)
        sig = np.sqrt(np.diagonal(C, axis1=1, axis2=2))
        z = err / sig
        return xr.Dataset({"error": (("check", "enu"), err, {"units": "m"}),
                           "sigma": (("check", "enu"), sig, {"units": "m"}),
                           "normalized": (("check", "enu"), z)},
                          coords={"check": net.point_id[c].astype(object), "enu": ["east", "north", "up"]},
                          attrs={"rms_m": np.sqrt(np.mean(err ** 2, axis=0)),
                                 "normalized_rms": float(np.sqrt(np.mean(z ** 2)))})


def solve_block(block: Block, options: SolverOptions | None = None, **kwargs: object) -> BlockResult:
    """Adjust a block; see :func:`lunarmap.adjust.solve` for the options."""
    return BlockResult(block, solve(block.problem, options, **kwargs))  # type: ignore[arg-type]

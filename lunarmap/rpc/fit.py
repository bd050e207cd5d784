"""Terrain-independent fitting of the cubic RFM from a virtual control grid.

Method (LROC multi-image study, ``seeds/001``, Eqs. 11-12 and the text
after them; linearisation and iterative weighting after Tao & Hu 2001):

1. Normalise the grid's image and ground coordinates (offsets at the centre,
   scales to the half ranges; the line and sample scales are half the image).
2. Linearised least squares for each image axis: ``r * (1 + b . t') - a . t
   = 0`` in the 39 unknowns ``a`` (numerator, 20) and ``b`` (denominator
   without its constant term, 19), so 78 coefficients in all; the rows are
   re-weighted by ``1 / D`` (the current denominator) a few times, which
   turns the linearised residual into the image residual.
3. Gauss-Newton refinement on the true residual ``r - N / D``.

Regularisation: a ridge ``lambda * n * |b|^2`` on the denominator
coefficients pulls ``D`` towards 1. It starts tiny (it then only steers
directions the grid does not determine) and is raised tenfold until the
denominators stay above ``min_denominator`` on the fit domain extended
beyond the height range; if no weight achieves that, :class:`RpcFitError`.

The fit is checked on an independent, denser grid (:func:`check_fit`):
image points between the fit nodes, heights between the layers and 10 %
beyond the fit range, ground coordinates from the rigorous model, and the
RFM's ``ground_to_image`` compared with the grid's pixels.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..blas import single_threaded_blas
from ..camera.sensor import SensorModel
from ..errors import RpcFitError, RpcInputError
from .grid import (
    DEFAULT_HEIGHT_RANGE,
    GridNodes,
    GroundGrid,
    check_grid_nodes,
    fit_grid_nodes,
    height_layers,
    rigorous_grid,
)
from .model import RationalFunctionModel
from .terms import N_TERMS, rpc_terms

__all__ = ["FitOptions", "FitReport", "RpcFit", "fit_rfm", "fit_rpc", "fit_from_grid", "check_fit",
           "normalization_from_grid"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class FitOptions:
    """Settings of :func:`fit_rpc` (all have working defaults).

    Attributes
    ----------
    height_range : (float, float)
        Terrain heights the RFM must serve, metres above the reference sphere.
    n_layers : int
        Elevation layers of the fit grid.
    margin : float
        Fraction of the height range added at both ends of the layers.
    short_axis, long_axis_max : int
        Fit-grid nodes along the shorter image axis / at most along the longer.
    check_density : int
        Check-grid cells per fit-grid cell and axis.
    check_outside : float
        Check heights reach this fraction of the fit span beyond it.
    regularization : float
        Initial ridge weight on the denominator coefficients (dimensionless,
        per grid point).
    min_denominator : float
        Smallest denominator accepted on the extended domain (``D = 1`` at
        the centre).
    linear_iterations, gauss_newton_iterations : int
        Iteration limits of steps 2 and 3.
    max_emission : float
        Largest emission angle (degrees) of a grid point; beyond, the limb.
    """

    height_range: tuple[float, float] = DEFAULT_HEIGHT_RANGE
    n_layers: int = 7
    margin: float = 0.05
    short_axis: int = 21
    long_axis_max: int = 161
    check_density: int = 2
    check_outside: float = 0.10
    regularization: float = 1e-14
    min_denominator: float = 0.1
    linear_iterations: int = 4
    gauss_newton_iterations: int = 3
    max_emission: float = 85.0


@dataclass(frozen=True)
class FitReport:
    """Agreement of an RFM with the rigorous model on a grid, pixels.

    ``rms`` is ``sqrt(rms_line^2 + rms_sample^2)`` and ``max`` the largest
    image-plane distance; ``layer_*`` are per check height (``heights``, m).
    """

    n_points: int
    rms_line: float
    rms_sample: float
    rms: float
    max: float
    heights: tuple[float, ...] = ()
    layer_rms: tuple[float, ...] = ()
    layer_max: tuple[float, ...] = ()

    def as_attrs(self, prefix: str) -> dict[str, Any]:
        """Flat attributes (for the dataset), names prefixed."""
        return {f"{prefix}_{k}": (np.asarray(v, dtype=float) if isinstance(v, tuple) else v)
                for k, v in asdict(self).items()}


@dataclass(frozen=True)
class RpcFit:
    """Result of :func:`fit_rpc`: the model, the fit residuals and the independent check."""

    model: RationalFunctionModel
    fit: FitReport
    check: FitReport | None
    regularization: float
    min_denominator: float
    options: FitOptions = field(default_factory=FitOptions)

    def summary(self) -> str:
        c = self.check
        chk = f"check RMS {c.rms:.2e} px, max {c.max:.2e} px on {c.n_points} pts" if c else "no check"
        return f"{self.model!r}: fit RMS {self.fit.rms:.2e} px; {chk}"


def _residual_report(model: RationalFunctionModel, grid: GroundGrid) -> FitReport:
    line, sample = model.lonlat_to_image(grid.lon, grid.lat, grid.height)
    dl = line - grid.line
    ds = sample - grid.sample
    d = np.hypot(dl, ds)
    heights, inverse = np.unique(np.round(grid.height, 3), return_inverse=True)
    layers = heights.size <= 64
    layer_rms = tuple(float(np.sqrt(np.mean(d[inverse == k] ** 2))) for k in range(heights.size)) if layers else ()
    layer_max = tuple(float(d[inverse == k].max()) for k in range(heights.size)) if layers else ()
    rl, rs = float(np.sqrt(np.mean(dl * dl))), float(np.sqrt(np.mean(ds * ds)))
    return FitReport(int(d.size), rl, rs, float(np.hypot(rl, rs)), float(d.max()),
                     tuple(float(h) for h in heights) if layers else (), layer_rms, layer_max)


def normalization_from_grid(grid: GroundGrid, n_lines: int, n_samples: int,
                            height_range: tuple[float, float]) -> tuple[Array, Array]:
    """Offsets and scales (:data:`~lunarmap.rpc.model.COORDINATES` order) of a grid.

    Line and sample: centre and half size of the image. Latitude and
    longitude: centre and half range of the grid (longitudes unwrapped about
    the grid's first point). Height: centre and half of ``height_range``.

    Raises
    ------
    RpcFitError
        The footprint spans more than 90 degrees of longitude (it contains
        or nearly contains a pole), where a latitude/longitude RFM fails.
    """
    lon_ref = grid.lon[grid.lon.size // 2]
    dlon = np.remainder(grid.lon - lon_ref + 180.0, 360.0) - 180.0
    lon_lo, lon_hi = float(dlon.min()), float(dlon.max())
    if lon_hi - lon_lo > 90.0:
        raise RpcFitError(f"the footprint spans {lon_hi - lon_lo:.1f} degrees of longitude (it contains or "
                          f"nearly contains a pole): a latitude/longitude RFM cannot represent it")
    lon_off = float(np.remainder(lon_ref + 0.5 * (lon_lo + lon_hi) + 180.0, 360.0) - 180.0)
    lat_lo, lat_hi = float(grid.lat.min()), float(grid.lat.max())
    h_lo, h_hi = height_range
    # a tiny floor keeps a degenerate (single-line) footprint from dividing by zero
    offsets = np.array([n_lines / 2.0, n_samples / 2.0, 0.5 * (lat_lo + lat_hi), lon_off, 0.5 * (h_lo + h_hi)])
    scales = np.array([n_lines / 2.0, n_samples / 2.0, max(0.5 * (lat_hi - lat_lo), 1e-9),
                       max(0.5 * (lon_hi - lon_lo), 1e-9), 0.5 * (h_hi - h_lo)])
    return offsets, scales


def _solve_axis(t: Array, r: Array, lam: float, n_linear: int, n_gn: int) -> Array:
    """Numerator and denominator (20 + 20, denominator constant 1) of one image axis."""
    n = r.size
    tp = t[:, 1:]
    reg = np.sqrt(lam * n)
    # ridge rows act on b only (the last 19 unknowns)
    ridge = np.zeros((N_TERMS - 1, 2 * N_TERMS - 1))
    ridge[:, N_TERMS:] = reg * np.eye(N_TERMS - 1)
    w = np.ones(n)
    sol = np.zeros(2 * N_TERMS - 1)
    # Step 2 (Tao & Hu 2001): linearised r*D - N = 0, rows weighted by 1/D.
    for _ in range(n_linear):
        a_mat = np.concatenate([t, -r[:, None] * tp], axis=1) * w[:, None]
        a_mat = np.concatenate([a_mat, ridge])
        rhs = np.concatenate([r * w, np.zeros(N_TERMS - 1)])
        new = np.linalg.lstsq(a_mat, rhs, rcond=None)[0]
        d = 1.0 + tp @ new[N_TERMS:]
        done = np.max(np.abs(new - sol)) < 1e-15 * max(1.0, np.max(np.abs(new)))
        sol = new
        if done or np.any(d <= 0.0):
            break
        w = 1.0 / d
    # Step 3: Gauss-Newton on the image residual r - N/D (the same ridge on b).
    for _ in range(n_gn):
        num = t @ sol[:N_TERMS]
        den = 1.0 + tp @ sol[N_TERMS:]
        e = r - num / den
        jac = np.concatenate([t / den[:, None], -(num / (den * den))[:, None] * tp], axis=1)
        a_mat = np.concatenate([jac, ridge])
        rhs = np.concatenate([e, -reg * sol[N_TERMS:]])
        delta = np.linalg.lstsq(a_mat, rhs, rcond=None)[0]
        sol = sol + delta
        if np.max(np.abs(delta)) < 1e-14 * max(1.0, np.max(np.abs(sol))):
            break
    return np.concatenate([sol[:N_TERMS], [1.0], sol[N_TERMS:]])


def _extended_domain(x: Array, y: Array, z: Array, outside: float) -> tuple[Array, Array, Array]:
    """Fit points plus their copies pushed beyond the height range (where checks extrapolate)."""
    f = 1.0 + 2.0 * outside + 0.05
    return np.concatenate([x, x]), np.concatenate([y, y]), np.concatenate([z, z * f])


def fit_rfm(grid: GroundGrid, n_lines: int, n_samples: int, height_range: tuple[float, float],
            radius: float, options: FitOptions = FitOptions(),
            attrs: dict[str, Any] | None = None) -> tuple[RationalFunctionModel, float, float]:
    """Fit the 78 free RPC coefficients to a ground grid (steps 1-3 of the module notes).

    Parameters
    ----------
    grid : GroundGrid
        Virtual control points: pixels and their ground coordinates.
    n_lines, n_samples : int
        Image size, pixels.
    height_range : (float, float)
        Heights the normalisation spans (the layers' range), metres.
    radius : float
        Reference sphere radius of the heights, metres.
    options : FitOptions
        Regularisation and iteration settings.
    attrs : dict, optional
        Provenance stored with the model.

    Returns
    -------
    model : RationalFunctionModel
    regularization : float
        The ridge weight finally used.
    min_denominator : float
        Smallest denominator on the extended domain.

    Raises
    ------
    RpcInputError
        Non-finite grid values or too few points.
    RpcFitError
        No regularisation weight keeps the denominators above
        ``options.min_denominator``.
    """
    for k in ("line", "sample", "lon", "lat", "height"):
        if not np.all(np.isfinite(getattr(grid, k))):
            raise RpcInputError(f"virtual grid {k} values hold NaN or infinite values")
    if grid.line.size < 4 * N_TERMS:
        raise RpcInputError(f"a cubic RFM needs at least {4 * N_TERMS} grid points, got {grid.line.size}")
    offsets, scales = normalization_from_grid(grid, n_lines, n_samples, height_range)
    probe = RationalFunctionModel(np.tile(np.eye(1, N_TERMS), (4, 1)), offsets, scales, radius)
    x, y, z = probe.normalize_ground(grid.lon, grid.lat, grid.height)
    t = rpc_terms(x, y, z)
    rn = (grid.line - offsets[0]) / scales[0]
    cn = (grid.sample - offsets[1]) / scales[1]
    # flush denormal products of tiny coordinates (they slow LAPACK down)
    t[np.abs(t) < 1e-150] = 0.0
    te = rpc_terms(*_extended_domain(x, y, z, options.check_outside))
    lam = options.regularization
    min_den = -np.inf
    while lam <= 1.0:
        with single_threaded_blas():
            line_c = _solve_axis(t, rn, lam, options.linear_iterations, options.gauss_newton_iterations)
            samp_c = _solve_axis(t, cn, lam, options.linear_iterations, options.gauss_newton_iterations)
        min_den = float(min((te @ line_c[N_TERMS:]).min(), (te @ samp_c[N_TERMS:]).min()))
        if min_den >= options.min_denominator:
            coeffs = np.stack([line_c[:N_TERMS], line_c[N_TERMS:], samp_c[:N_TERMS], samp_c[N_TERMS:]])
            model = RationalFunctionModel(coeffs, offsets, scales, radius, n_lines, n_samples, attrs or {})
            return model, lam, min_den
        lam *= 10.0
    raise RpcFitError(f"no regularisation keeps the RFM denominators above {options.min_denominator} "
                      f"(smallest {min_den:.3g}); the grid does not constrain the model")


def check_fit(model: RationalFunctionModel, camera: SensorModel, nodes: GridNodes | None = None,
              options: FitOptions = FitOptions()) -> FitReport:
    """RMS and maximum RFM error (pixels) on an independent check grid of the rigorous model.

    The check grid (:func:`~lunarmap.rpc.grid.check_grid_nodes`) is denser
    than the fit grid, off its nodes, at heights between its layers and up
    to ``options.check_outside`` beyond its height range; each node's
    ground point comes from ``camera.image_to_ground`` and the RFM must map
    it back to the node's pixel.
    """
    if nodes is None:
        fit_h = height_layers(options.height_range, options.n_layers, options.margin)
        nodes = check_grid_nodes(model.n_lines, model.n_samples, fit_h, options.short_axis,
                                 options.long_axis_max, options.check_density, options.check_outside)
    grid = rigorous_grid(camera, nodes, max_emission=90.0)
    return _residual_report(model, grid)


def _provenance(camera: SensorModel, options: FitOptions, layers: Array, nodes: GridNodes) -> dict[str, Any]:
    from .. import __version__ as version  # noqa: PLC0415 (avoid an import cycle at package import)

    return {
        "source_camera": repr(camera),
        "fit_method": "virtual control grid in height layers, linearised LSQ with 1/D weights, "
                      "Gauss-Newton refinement, ridge on denominators (seeds/001 Eqs. 11-12)",
        "fit_height_layers_m": layers,
        "fit_grid_shape": np.array([nodes.lines.size, nodes.samples.size, nodes.heights.size]),
        "height_range_m": np.array(options.height_range, dtype=float),
        "lunarmap_version": str(version),
    }


def fit_rpc(camera: SensorModel, height_range: tuple[float, float] | None = None, *, check: bool = True,
            options: FitOptions | None = None, **option_overrides: Any) -> RpcFit:
    """Fit a cubic RFM to a rigorous camera model and check it on an independent grid.

    Parameters
    ----------
    camera : SensorModel (FrameCamera, LineScanCamera)
        The rigorous sensor model (``lunarmap.camera``).
    height_range : (float, float), optional
        Terrain heights to serve, metres above the camera shape's reference
        radius; by default the lunar extremes (:data:`DEFAULT_HEIGHT_RANGE`).
    check : bool
        Compute the independent check report (a few times the fit's rigorous
        evaluations; off for speed when the caller checks otherwise).
    options : FitOptions, optional
        Grid, regularisation and check settings; keyword overrides of its
        fields are accepted too (``n_layers=9``).

    Returns
    -------
    RpcFit
        ``.model`` (the RFM, fit statistics in ``.model.attrs``), ``.fit``
        (residuals on the fit grid) and ``.check`` (independent check grid).

    Raises
    ------
    RpcInputError
        Zero, reversed or non-finite height range; bad options.
    RpcGridError, RpcLimbError
        The grid misses the body or the footprint crosses the limb.
    RpcFitError
        Footprint over a pole or denominators that cannot be kept positive.
    """
    opts = options or FitOptions()
    if height_range is not None:
        option_overrides["height_range"] = tuple(height_range)
    if option_overrides:
        unknown = set(option_overrides) - set(FitOptions.__dataclass_fields__)
        if unknown:
            raise RpcInputError(f"unknown fit option(s): {', '.join(sorted(unknown))}")
        opts = FitOptions(**{**asdict(opts), **option_overrides})
    layers = height_layers(opts.height_range, opts.n_layers, opts.margin)
    nodes = fit_grid_nodes(camera.n_lines, camera.n_samples, layers, opts.short_axis, opts.long_axis_max)
    # One BLAS thread for the whole fit: see lunarmap.blas (and dask
    # workers run one, so serial and distributed results are bitwise equal).
    with single_threaded_blas():
        grid = rigorous_grid(camera, nodes, opts.max_emission)
        return fit_from_grid(camera, grid, nodes, layers, opts, check)


def fit_from_grid(camera: SensorModel, grid: GroundGrid, nodes: GridNodes, layers: Array, opts: FitOptions,
                  check: bool = True, check_grid: GroundGrid | None = None) -> RpcFit:
    """:func:`fit_rpc` after the rigorous grid is computed (the dask path computes it in tiles)."""
    with single_threaded_blas():
        return _fit_from_grid(camera, grid, nodes, layers, opts, check, check_grid)


def _fit_from_grid(camera: SensorModel, grid: GroundGrid, nodes: GridNodes, layers: Array, opts: FitOptions,
                   check: bool, check_grid: GroundGrid | None) -> RpcFit:
    model, lam, min_den = fit_rfm(grid, camera.n_lines, camera.n_samples, (float(layers[0]), float(layers[-1])),
                                  camera.reference_radius, opts, _provenance(camera, opts, layers, nodes))
    fit_report = _residual_report(model, grid)
    report = None
    if check_grid is not None:
        report = _residual_report(model, check_grid)
    elif check:
        report = check_fit(model, camera, options=opts)
    attrs: dict[str, Any] = {"regularization": lam, "min_denominator": min_den, **fit_report.as_attrs("fit")}
    if report is not None:
        attrs.update(report.as_attrs("check"))
    return RpcFit(model.with_attrs(**attrs), fit_report, report, lam, min_den, opts)

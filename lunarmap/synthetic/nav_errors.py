"""Navigation errors of the synthetic block: per-orbit offset + drift in time, plus a smooth random part.

The NAVIGATION kernels of :func:`lunarmap.synthetic.write_block_mission` are
the TRUTH kernels with these errors added. For an epoch ``t`` in the pass of
orbit ``o`` (reference epoch ``t_o``, the NAC's view of the site):

* position, body-fixed (IAU_MOON) axes, metres::

      dp(t) = c_o + (t - t_o) d_o + n_p(t),      p_nav = p_true + dp

* attitude, a small rotation of the bus, bus axes, radians::

      th(t) = a_o + (t - t_o) b_o + n_a(t)

  The navigation bus axes are the true ones turned by the rotation vector
  ``th``: ``C_nav = Rv(th)^T C_true`` for the J2000 -> bus matrices, where
  ``Rv(v) = exp([v]x)`` rotates vectors by ``|v|`` about ``v``. Every look
  vector therefore turns by ``th`` in bus axes, which in the body-fixed frame
  is ``w = B C_true^T th`` (``B``: J2000 -> IAU_MOON): the sensor-to-body
  rotation of every camera becomes ``R_nav = Rv(w) R_true``.

The per-orbit offsets (``c_o``, ``a_o``) and drifts (``d_o``, ``b_o``) have
uniformly random directions and magnitudes drawn uniformly from the ranges of
:class:`NavigationErrorSpec`. The random parts ``n_p``, ``n_a`` are, per
axis, sums of three sinusoids with periods in ``noise_periods_s`` and random
phases whose amplitudes make their RMS ``position_noise_m`` /
``attitude_noise_rad``: smooth over seconds, so images of one orbit (a few
seconds apart) do not share exactly the same error.

An orbit may hold several pass windows (a block of several sites: one window
per site, the spacecraft slewing between them outside the kernels'
coverage); the orbit's offset and drift then hold over all of its windows,
about the orbit's single reference epoch ``t_o``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidInputError

__all__ = ["NavigationErrorSpec", "SmoothNoise", "NavigationErrors", "draw_navigation_errors"]

Array = NDArray[np.float64]

#: Sinusoids per axis of the random part.
_N_WAVES = 3
#: The model holds this far (s) beyond each pass window, so that derivatives at the window ends exist.
_EDGE = 1.0


def _range(name: str, value: Any) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a (min, max) pair of numbers, got {value!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo <= hi):
        raise InvalidInputError(f"{name} must satisfy 0 <= min <= max (finite), got {value!r}")
    return lo, hi


@dataclass(frozen=True)
class NavigationErrorSpec:
    """Magnitudes of the navigation errors (defaults: tens of metres on the ground).

    Parameters
    ----------
    position_offset_m : (float, float)
        Range of the magnitude of each orbit's position offset ``c_o``, m.
    position_drift_m_per_s : (float, float)
        Range of the magnitude of each orbit's position drift ``d_o``, m/s.
    attitude_offset_rad : (float, float)
        Range of the angle of each orbit's attitude offset ``a_o``, rad.
    attitude_drift_rad_per_s : (float, float)
        Range of the magnitude of each orbit's attitude drift ``b_o``, rad/s.
    position_noise_m : float
        RMS per axis of the smooth random position part, m.
    attitude_noise_rad : float
        RMS per axis of the smooth random attitude part, rad.
    noise_periods_s : (float, float)
        Range of the periods of the random part's sinusoids, s (the kernels'
        sampling, 1 s for the SPK and 0.25 s for the CK, reproduces periods
        of 20 s and more to below 1 mm and 1 nrad).
    """

    position_offset_m: tuple[float, float] = (20.0, 50.0)
    position_drift_m_per_s: tuple[float, float] = (0.2, 1.0)
    attitude_offset_rad: tuple[float, float] = (20e-6, 50e-6)
    attitude_drift_rad_per_s: tuple[float, float] = (0.2e-6, 1.0e-6)
    position_noise_m: float = 0.5
    attitude_noise_rad: float = 1e-6
    noise_periods_s: tuple[float, float] = (20.0, 90.0)

    def __post_init__(self) -> None:
        for name in ("position_offset_m", "position_drift_m_per_s", "attitude_offset_rad",
                     "attitude_drift_rad_per_s", "noise_periods_s"):
            object.__setattr__(self, name, _range(name, getattr(self, name)))
        for name in ("position_noise_m", "attitude_noise_rad"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating)) or not np.isfinite(v) or v < 0:
                raise InvalidInputError(f"{name} must be a finite number >= 0, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.noise_periods_s[0] < 20.0:
            raise InvalidInputError(f"noise_periods_s must be >= 20 s (the kernels' sampling resolves no faster "
                                    f"variation), got {self.noise_periods_s}")
        if self.position_offset_m[1] > 1000.0 or self.attitude_offset_rad[1] > 1e-3:
            raise InvalidInputError("navigation offsets must stay below 1 km and 1 mrad (small-error model)")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready parameters."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class SmoothNoise:
    """Per-axis sums of sinusoids: ``n_k(t) = sum_j A_kj sin(2 pi (t - t0) / P_kj + phi_kj)``.

    Parameters
    ----------
    amplitude, period, phase : ndarray, shape (3, n_waves)
        Units of the quantity, seconds, radians.
    epoch : float
        ``t0``, ET (keeps the phase arguments small).
    """

    amplitude: Array
    period: Array
    phase: Array
    epoch: float = 0.0

    def _arg(self, et: ArrayLike) -> Array:
        dt = np.asarray(et, dtype=float) - self.epoch
        return 2.0 * np.pi * dt[..., None, None] / self.period + self.phase

    def value(self, et: ArrayLike) -> Array:
        """Shape ``et.shape + (3,)``."""
        return np.sum(self.amplitude * np.sin(self._arg(et)), axis=-1)

    def rate(self, et: ArrayLike) -> Array:
        """Time derivative, per second; shape ``et.shape + (3,)``."""
        w = 2.0 * np.pi / self.period
        return np.sum(self.amplitude * w * np.cos(self._arg(et)), axis=-1)

    @classmethod
    def draw(cls, rng: np.random.Generator, rms: float, periods: tuple[float, float],
             epoch: float = 0.0) -> "SmoothNoise":
        """Random periods and phases; amplitudes equal per axis, scaled to an RMS of ``rms`` per axis."""
        period = rng.uniform(periods[0], periods[1], (3, _N_WAVES))
        phase = rng.uniform(0.0, 2.0 * np.pi, (3, _N_WAVES))
        # each sinusoid has mean square A^2 / 2
        amplitude = np.full((3, _N_WAVES), rms * np.sqrt(2.0 / _N_WAVES))
        return cls(amplitude, period, phase, float(epoch))


@dataclass(frozen=True)
class NavigationErrors:
    """The navigation errors of every orbit pass (see the module docstring for the model).

    Parameters
    ----------
    epochs : ndarray (n_orbits,)
        Reference epochs ``t_o`` of the orbits, ET.
    windows : ndarray (n_windows, 2)
        ET intervals of the passes (the kernels' coverage), one or more per orbit.
    position_offset : ndarray (n_orbits, 3)
        ``c_o``, body-fixed, m.
    position_drift : ndarray (n_orbits, 3)
        ``d_o``, body-fixed, m/s.
    attitude_offset : ndarray (n_orbits, 3)
        ``a_o``, bus axes, rad.
    attitude_drift : ndarray (n_orbits, 3)
        ``b_o``, bus axes, rad/s.
    position_noise, attitude_noise : SmoothNoise
        ``n_p`` (m, body-fixed) and ``n_a`` (rad, bus axes).
    window_orbit : ndarray of int (n_windows,), optional
        0-based orbit of each window (default: window ``k`` is orbit ``k``).
    """

    epochs: Array
    windows: Array
    position_offset: Array
    position_drift: Array
    attitude_offset: Array
    attitude_drift: Array
    position_noise: SmoothNoise
    attitude_noise: SmoothNoise
    window_orbit: NDArray[np.intp] | None = None

    def __post_init__(self) -> None:
        n_win = self.windows.shape[0]
        wo = np.arange(n_win) if self.window_orbit is None else np.asarray(self.window_orbit, dtype=np.intp)
        if wo.shape != (n_win,) or (n_win and (wo.min() < 0 or wo.max() >= self.epochs.size)):
            raise InvalidInputError(f"window_orbit must give an orbit in [0, {self.epochs.size}) for each of the "
                                    f"{n_win} windows, got {wo.tolist()}")
        object.__setattr__(self, "window_orbit", wo)

    def orbit_index(self, et: ArrayLike) -> NDArray[np.intp]:
        """0-based orbit of each epoch; raises outside every pass window (widened by 1 s for derivatives)."""
        et = np.asarray(et, dtype=float)
        inside = (et[..., None] >= self.windows[:, 0] - _EDGE) & (et[..., None] <= self.windows[:, 1] + _EDGE)
        if not np.all(inside.any(axis=-1)):
            bad = et[~inside.any(axis=-1)]
            raise InvalidInputError(f"ET {bad.ravel()[:3]} is outside every orbit pass of the block "
                                    f"({self.windows.tolist()})")
        return self.window_orbit[np.argmax(inside, axis=-1)]  # type: ignore[index]

    def _linear(self, et: ArrayLike, offset: Array, drift: Array) -> Array:
        et = np.asarray(et, dtype=float)
        k = self.orbit_index(et)
        return offset[k] + (et - self.epochs[k])[..., None] * drift[k]

    def position(self, et: ArrayLike) -> Array:
        """``dp(t)``, body-fixed, m; shape ``et.shape + (3,)``."""
        return self._linear(et, self.position_offset, self.position_drift) + self.position_noise.value(et)

    def position_rate(self, et: ArrayLike) -> Array:
        """``d dp / dt``, body-fixed, m/s."""
        k = self.orbit_index(et)
        return self.position_drift[k] + self.position_noise.rate(et)

    def attitude(self, et: ArrayLike) -> Array:
        """``th(t)``, bus axes, rad; shape ``et.shape + (3,)``."""
        return self._linear(et, self.attitude_offset, self.attitude_drift) + self.attitude_noise.value(et)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready per-orbit values (the random parts' sinusoids included)."""
        out: dict[str, Any] = {"orbits": []}
        several = np.bincount(self.window_orbit, minlength=self.epochs.size).max() > 1  # type: ignore[arg-type]
        for k in range(self.epochs.size):
            win = self.windows[self.window_orbit == k]
            rec: dict[str, Any] = {
                "orbit": k + 1, "reference_et": float(self.epochs[k]),
                # one window: that window; several (one per site): from the first one's start to the last one's end
                "window_et": [float(win[:, 0].min()), float(win[:, 1].max())],
            }
            if several:
                rec["pass_windows_et"] = [[float(a), float(b)] for a, b in win]
            rec.update({
                "position_offset_m": self.position_offset[k].tolist(),
                "position_drift_m_per_s": self.position_drift[k].tolist(),
                "attitude_offset_rad": self.attitude_offset[k].tolist(),
                "attitude_drift_rad_per_s": self.attitude_drift[k].tolist(),
            })
            out["orbits"].append(rec)
        for name, noise in (("position_noise", self.position_noise), ("attitude_noise", self.attitude_noise)):
            out[name] = {"amplitude": noise.amplitude.tolist(), "period_s": noise.period.tolist(),
                         "phase_rad": noise.phase.tolist(), "epoch_et": noise.epoch}
        return out


def _random_vectors(rng: np.random.Generator, n: int, magnitude: tuple[float, float]) -> Array:
    """``n`` vectors of uniformly random direction and magnitude uniform in ``magnitude``."""
    v = rng.standard_normal((n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v * rng.uniform(magnitude[0], magnitude[1], (n, 1))


def draw_navigation_errors(rng: np.random.Generator, epochs: ArrayLike, windows: ArrayLike,
                           spec: NavigationErrorSpec, window_orbit: ArrayLike | None = None) -> NavigationErrors:
    """Draw the navigation errors of the orbits from ``rng`` (the draw order is fixed, so seeds are stable).

    ``epochs``: one reference epoch per orbit; ``windows``: the pass windows, ``window_orbit`` the
    0-based orbit of each (default: one window per orbit, in order). The draws depend only on the
    number of orbits, so adding windows to an orbit does not change its errors.
    """
    epochs = np.asarray(epochs, dtype=float)
    n = epochs.size
    return NavigationErrors(
        epochs=epochs, windows=np.asarray(windows, dtype=float).reshape(-1, 2),
        position_offset=_random_vectors(rng, n, spec.position_offset_m),
        position_drift=_random_vectors(rng, n, spec.position_drift_m_per_s),
        attitude_offset=_random_vectors(rng, n, spec.attitude_offset_rad),
        attitude_drift=_random_vectors(rng, n, spec.attitude_drift_rad_per_s),
        position_noise=SmoothNoise.draw(rng, spec.position_noise_m, spec.noise_periods_s, float(epochs[0])),
        attitude_noise=SmoothNoise.draw(rng, spec.attitude_noise_rad, spec.noise_periods_s, float(epochs[0])),
        window_orbit=None if window_orbit is None else np.asarray(window_orbit, dtype=np.intp),
    )

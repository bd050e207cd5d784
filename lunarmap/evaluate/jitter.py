"""Amplitude spectra of line-scan attitude jitter (issue 30, item 5): the run report's jitter section.

:func:`amplitude_spectrum` is the one-sided amplitude spectrum of a series sampled every ``dt`` seconds
(mean removed, rectangular window, zero-padded ``pad`` times so that a sinusoid's peak is found between the
record's own frequencies ``k / T``): a sinusoid of amplitude ``A`` with a whole number of periods over the
record has a peak of height ``A`` exactly; between, its negative-frequency image leaks in (a few % for a
few periods). An image of a few periods spreads a sinusoid over ``1 / T``, so read the peak's frequency to
about ``1 / (2 T)``.

:func:`jitter_spectra` evaluates the adjusted jitter splines of a block
(:class:`~lunarmap.camera.corrections.LineScanCorrections` with ``jitter_lines``) at every image line and
gives, per image and sensor axis, their RMS, the RMS of their posterior sigma and their spectrum's peak,
with the spectrum up to the knots' Nyquist frequency. Nothing here calls SPICE.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidInputError

__all__ = ["amplitude_spectrum", "jitter_spectra", "spectrum_peak"]

AXES = ("x", "y", "z")


def amplitude_spectrum(x: ArrayLike, dt: float, pad: int = 4) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One-sided amplitude spectrum of ``x`` (``(n,)`` or ``(n, k)`` columns) sampled every ``dt`` seconds.

    Returns
    -------
    frequency : (m,) Hz
    amplitude : (m,) or (m, k), in the units of ``x``

    Raises
    ------
    InvalidInputError
        Fewer than 4 samples, a non-positive ``dt`` or ``pad`` < 1.
    """
    a = np.asarray(x, float)
    if a.shape[0] < 4 or not (np.isfinite(dt) and dt > 0) or int(pad) < 1:
        raise InvalidInputError(f"amplitude_spectrum: need >= 4 samples, dt > 0 and pad >= 1 (got {a.shape[0]}, "
                                f"{dt!r}, {pad!r})")
    n = a.shape[0]
    spec = np.asarray(np.abs(np.fft.rfft(a - a.mean(axis=0), n=n * int(pad), axis=0)) * (2.0 / n), np.float64)
    return np.asarray(np.fft.rfftfreq(n * int(pad), dt), np.float64), spec


def spectrum_peak(frequency: ArrayLike, amplitude: ArrayLike, min_hz: float = 0.0) -> tuple[float, float]:
    """The frequency (Hz) and amplitude of the largest value of a spectrum at frequencies >= ``min_hz``."""
    f, a = np.asarray(frequency, float), np.asarray(amplitude, float)
    ok = f >= min_hz
    if not ok.any():
        return float("nan"), float("nan")
    k = int(np.argmax(np.where(ok, a, -np.inf)))
    return float(f[k]), float(a[k])


def jitter_spectra(model: Any, cam_params: ArrayLike, cam_cov: ArrayLike | None, names: Any,
                   truth: Any = None) -> dict[str, Any]:
    """Per image with a jitter spline: its adjusted attitude correction's RMS, sigma and spectrum.

    Parameters
    ----------
    model : SensorImageModel
        The block's image model (``model.corrections``).
    cam_params : (n_images, n_params)
        Adjusted correction parameters (padded).
    cam_cov : (n_images, n_params, n_params), optional
        Their posterior covariance (the sigma column then is NaN when absent).
    names : sequence of str
        Image names, in the model's order.
    truth : callable, optional
        ``truth(name, et) -> (n, 3)`` the true jitter in the sensor frame (radians) at ET ``et``; the
        section then has the truth's spectrum and the error's (truth - estimate, both high-passed by the
        correction polynomial's degree over the lines: the part a spline can take).

    Returns
    -------
    dict
        Image name -> ``line_time_s``, ``lines``, ``knot_lines``, ``rms_rad`` (3), ``sigma_rms_rad`` (3),
        ``peak_hz`` (3), ``peak_amplitude_rad`` (3), ``frequency_hz`` (m), ``amplitude_rad`` (3 x m); with
        ``truth`` also ``truth_rms_rad``, ``error_rms_rad``, ``truth_peak_hz``, ``truth_peak_amplitude_rad``,
        ``error_peak_amplitude_rad``, ``truth_amplitude_rad`` and ``error_amplitude_rad``.
    """
    P = np.asarray(cam_params, float)
    out: dict[str, Any] = {}
    for i, (name, corr) in enumerate(zip(names, model.corrections)):
        if getattr(corr, "jitter_lines", None) is None:
            continue
        p = P[i, :corr.n_params]
        n = int(corr.sensor.n_lines)
        lines = np.arange(n) + 0.5
        t = np.asarray(corr.sensor.image_time(lines), float)
        dt = float(np.median(np.diff(t)))
        j = corr.jitter(p, t)                                   # (n, 3) rad, sensor frame
        sig = np.full(3, np.nan)
        if cam_cov is not None:
            C = np.asarray(cam_cov, float)[i][corr.n_poly:corr.n_params, corr.n_poly:corr.n_params]
            rows = corr._jitter_rows(t)                          # (n, n_jitter)
            for ax in range(3):
                c = C[ax::3, ax::3]
                sig[ax] = float(np.sqrt(np.mean(np.clip(np.einsum("nj,jk,nk->n", rows, c, rows), 0.0, None))))
        f, amp = amplitude_spectrum(j, dt)
        nyq = 0.5 / (dt * float(corr.knot_spacing))
        keep = f <= nyq
        peaks = [spectrum_peak(f, amp[:, ax], min_hz=0.5 / (n * dt)) for ax in range(3)]
        rec: dict[str, Any] = {
            "line_time_s": dt, "lines": n, "knot_lines": float(corr.knot_spacing),
            "rms_rad": np.sqrt(np.mean(j ** 2, axis=0)).tolist(), "sigma_rms_rad": sig.tolist(),
            "peak_hz": [pk[0] for pk in peaks], "peak_amplitude_rad": [pk[1] for pk in peaks],
            "frequency_hz": f[keep].tolist(), "amplitude_rad": amp[keep].T.tolist(), "axes": list(AXES)}
        if truth is not None:
            et = t + float(corr.sensor.eo.epoch)
            tj = np.asarray(truth(name, et), float)
            # the polynomial's part of the truth is the polynomial's to take: high-pass it the same way
            tau = np.asarray(corr.tau(t), float)
            V = tau[:, None] ** np.arange(corr.degree + 1)[None, :]
            tj = tj - V @ np.linalg.lstsq(V, tj, rcond=None)[0]
            err = tj - j
            _, tamp = amplitude_spectrum(tj, dt)
            _, eamp = amplitude_spectrum(err, dt)
            tpk = [spectrum_peak(f, tamp[:, ax], min_hz=0.5 / (n * dt)) for ax in range(3)]
            rec.update({
                "truth_rms_rad": np.sqrt(np.mean(tj ** 2, axis=0)).tolist(),
                "error_rms_rad": np.sqrt(np.mean(err ** 2, axis=0)).tolist(),
                "truth_peak_hz": [pk[0] for pk in tpk], "truth_peak_amplitude_rad": [pk[1] for pk in tpk],
                "error_peak_amplitude_rad": [float(eamp[keep, ax].max()) for ax in range(3)],
                "truth_amplitude_rad": tamp[keep].T.tolist(), "error_amplitude_rad": eamp[keep].T.tolist()})
        out[str(name)] = rec
    return out

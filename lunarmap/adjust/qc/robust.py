"""Robust reweighting of image observations inside the adjustment (the "Robust" / Danish method).

The DLR paper (``seeds/004``, section 4.1) eliminates gross errors of image observations with the
robust method of Klein and Förstner (1984): the weight of every observation is recomputed during
the iteration from its normalised residual ``u``, so that large residuals lose their weight and
the solution moves towards the good observations. Weight functions (:data:`WEIGHT_FUNCTIONS`,
``c`` the tuning constant, in units of ``u``):

* ``"danish"`` (Krarup's Danish method, the paper's): ``w = 1`` for ``|u| <= c``,
  ``w = exp(1 - (u / c)^2)`` beyond -- continuous at ``c``, redescending fast (``w = 0.05`` at
  ``2c``); the paper gives no formula, this is the common exponential form;
* ``"huber"``: ``w = min(1, c / |u|)`` (ISIS jigsaw and ASP offer it; never rejects);
* ``"cauchy"``: ``w = 1 / (1 + (u / c)^2)`` (jigsaw's and ASP's Cauchy loss).

The normalised residual of an image observation is the larger of its two coordinates'
``|v| / (s sigma)`` (``normalise="sigma"``) or ``|v| / (s sigma sqrt(r))`` with redundancy
numbers ``r`` (``"redundancy"``, the standardised residual: fairer where redundancies vary, but
each round costs a posterior precision), ``s`` the a-priori ``sigma0 = 1`` (``scale="apriori"``)
or a robust estimate ``1.4826 median |v / sigma|`` (``"mad"``) over the observations subject to it.

``mode="iteration"`` reweights after every accepted step of the solver (its ``reweight`` hook);
``"rounds"`` adjusts to convergence with fixed weights, then reweights, until the weights settle.
Observations whose final weight is below ``min_weight`` are removed (weight 0), the others get
their a-priori weight back: the robust step decides, the adjustments after it are plain least squares.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numpy.typing import NDArray

from ...errors import QualityControlInputError
from ..normal import AdjustmentState
from ..solver import SolverOptions
from .ledger import Ledger, _last_result

__all__ = ["WEIGHT_FUNCTIONS", "weight_function", "robust_step"]


def _danish(u: NDArray, c: float) -> NDArray:
    a = np.abs(u) / c
    return np.where(a <= 1.0, 1.0, np.exp(1.0 - a * a))


def _huber(u: NDArray, c: float) -> NDArray:
    a = np.abs(u)
    return np.where(a <= c, 1.0, c / np.maximum(a, 1e-300))


def _cauchy(u: NDArray, c: float) -> NDArray:
    return 1.0 / (1.0 + (u / c) ** 2)


#: weight functions by name: ``w(u, c)`` and a default tuning constant ``c``
WEIGHT_FUNCTIONS: dict[str, tuple[Callable[[NDArray, float], NDArray], float]] = {
    "danish": (_danish, 3.0),
    "huber": (_huber, 1.5),
    "cauchy": (_cauchy, 2.385),
}


def weight_function(name: str) -> tuple[Callable[[NDArray, float], NDArray], float]:
    """The weight function ``w(u, c)`` and its default ``c`` (:data:`WEIGHT_FUNCTIONS`).

    Raises
    ------
    QualityControlInputError
        An unknown name (the message lists the known ones).
    """
    try:
        return WEIGHT_FUNCTIONS[name]
    except KeyError:
        raise QualityControlInputError(f"unknown robust weight function {name!r}; known: "
                                       f"{', '.join(sorted(WEIGHT_FUNCTIONS))}") from None


def _normalised(ledger: Ledger, state: AdjustmentState, scale: str, red: NDArray | None,
                subject: NDArray[np.bool_] | None = None) -> NDArray:
    """``(n_obs,)`` normalised residual of every image observation (larger coordinate); the robust scale
    (``"mad"``) from the ``subject`` observations."""
    pb = ledger.base
    o = pb.obs
    x = pb.model.project(state.cam_params, o.cam_idx, state.points[o.pt_idx])
    z = (x - o.xy) / (o.sigma * ledger.weights.image_sigma[:, None])
    if red is not None:
        z = z / np.sqrt(np.clip(red, 1e-3, None))
    act = ledger.active if subject is None else ledger.active & subject
    s = 1.0
    if scale == "mad":
        s = 1.4826 * float(np.median(np.abs(z[act]))) if act.any() else 1.0
        s = max(s, 1e-12)
    return np.max(np.abs(z), axis=1) / s


def robust_step(ledger: Ledger, function: str = "danish", c: float | None = None, mode: str = "iteration",
                normalise: str = "sigma", scale: str = "apriori", min_weight: float = 0.1, max_rounds: int = 30,
                warmup: int = 3, observations: NDArray[np.bool_] | None = None,
                options: SolverOptions | None = None) -> dict:
    """Robust adjustment of the ledger's problem (module docstring); removes what it rejects.

    ``observations`` (``(n_obs,)`` bool, default all): the image observations the robust weights apply to,
    e.g. the matcher's tie points; the others (measured control and check points) keep their weights
    and are left to the data snooping. The ``"mad"`` scale comes from them alone.

    Returns
    -------
    dict
        ``weights`` (n_obs,) the final robust weights, ``u`` the final normalised residuals,
        ``rounds`` adjustments made, ``removed`` observation indices, ``sigma0`` the a-posteriori sigma0
        of the robust adjustment (with its final weights, before the removals).

    Raises
    ------
    QualityControlInputError
        Unknown function / mode / normalisation / scale, ``c <= 0``, ``min_weight`` outside (0, 1).
    """
    fn, c0 = weight_function(function)
    c = c0 if c is None else float(c)
    if not (np.isfinite(c) and c > 0):
        raise QualityControlInputError(f"the robust tuning constant must be > 0, got {c!r}")
    if mode not in ("iteration", "rounds"):
        raise QualityControlInputError(f"robust mode must be 'iteration' or 'rounds', got {mode!r}")
    if normalise not in ("sigma", "redundancy"):
        raise QualityControlInputError(f"normalise must be 'sigma' or 'redundancy', got {normalise!r}")
    if scale not in ("apriori", "mad"):
        raise QualityControlInputError(f"scale must be 'apriori' or 'mad', got {scale!r}")
    if not (0.0 < min_weight < 1.0):
        raise QualityControlInputError(f"min_weight must be in (0, 1), got {min_weight!r}")
    base_w = ledger.weights.image_weight.copy()
    subject = None
    if observations is not None:
        subject = np.asarray(observations, bool)
        if subject.shape != base_w.shape:
            raise QualityControlInputError(f"observations needs one flag per image observation ({base_w.size}), "
                                           f"got shape {subject.shape}")
    still = ledger.active
    active = still if subject is None else still & subject
    robust = np.ones_like(base_w)
    red = None
    rounds = 0

    calls = {"n": 0}

    def weights_for(state: AdjustmentState) -> NDArray:
        # the MAD scale of all observations subject to the step: one of only those the current weights accept
        # shrinks round by round where the sigmas are uneven (a matcher's), and takes good observations with it
        # (measured: 90 % of the good ones out at 50 % mismatches)
        u = _normalised(ledger, state, scale, red, active)
        # the first reweightings with Huber's convex function: a redescending one applied to the residuals
        # of a solution that large errors still distort cuts good observations off for good
        f = _huber if calls["n"] < warmup else fn
        calls["n"] += 1
        # never exactly 0: a point keeps its rays; observations not subject to it keep theirs
        w = np.where(active, np.maximum(f(u, c), 1e-10), np.where(still, 1.0, 0.0))
        return w

    if mode == "iteration":
        if normalise == "redundancy":   # redundancy numbers of a plain adjustment, held for the iteration
            red = ledger.adjust(options).precision().redundancy_numbers
        last = {"w": robust}

        def hook(state: AdjustmentState):
            w = weights_for(state)
            if np.max(np.abs(w - last["w"])) < 1e-3:
                return None
            last["w"] = w
            return base_w * w

        result = ledger.adjust(options, reweight=hook)
        robust = last["w"]
        rounds = 1
    else:
        result = ledger.adjust(options)
        for rounds in range(1, max_rounds + 1):  # noqa: B007 (the count is reported after the loop)
            if normalise == "redundancy":
                red = result.precision().redundancy_numbers
            w = weights_for(result.state)
            change = float(np.max(np.abs(w - robust)))
            robust = w
            ledger.weights.image_weight = base_w * robust
            if change < 1e-3 or ledger.budget.exhausted():
                break
            result = ledger.adjust(options)
    u = _normalised(ledger, _last_result(ledger).state, scale, red, active)
    reject = np.flatnonzero(active & (robust < min_weight))
    ledger.weights.image_weight = base_w.copy()
    ledger.remove_image(reject, "robust", rounds, value=robust[reject])
    return {"weights": robust, "u": u, "rounds": rounds, "removed": reject, "sigma0": float(result.sigma0)}

"""How a quality-control run ends: its budget, and whether the block it leaves is clean (issue 27, item 3).

A run has a budget (:class:`Budget`: adjustments after the first one, wall-clock seconds); the iterative
steps check it between rounds (an adjustment already started is not interrupted) and a step that would
start after it is spent is skipped.

At the end :func:`assess` says whether the block is clean. It is not (a flag each) when

* the budget was spent, or a step's own round limit reached, before its tests passed;
* a step failed on the data (its exception is recorded, the run goes on with what it had);
* the block has no redundancy left (nothing can be tested);
* ``sigma0`` is outside the two-sided ``1 - alpha`` interval of a block whose a-priori sigmas are right:
  ``r sigma0^2`` is chi-square distributed with the block's redundancy ``r`` degrees of freedom, so the
  bounds on ``sigma0`` are ``sqrt(chi2_{alpha/2}(r) / r)`` and ``sqrt(chi2_{1-alpha/2}(r) / r)``
  (default ``alpha = 0.001``: a clean block is flagged once in a thousand runs);
* the data snooping's last round left a w-test above its limit;
* without data snooping, an active image observation's whitened residual ``|v| / sigma`` exceeds the
  w-test limit (its w-test ``|v| / (sigma sqrt(r))`` could only be larger, ``r <= 1``);
* observations too weakly checked to be tested (redundancy number below the snooping's
  ``min_redundancy``) have whitened residuals above the limit: an error there is invisible to any test.

A run that is not clean issues a :class:`~lunarmap.errors.QualityControlWarning` naming the flags, and
its report says so (``QCReport.clean``, ``summary["flags"]``): never a silent success.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from ...errors import QualityControlInputError
from ..result import AdjustmentResult

__all__ = ["Budget", "assess", "SIGMA0_ALPHA"]

#: two-sided significance of the chi-square test of sigma0 at the end of a run
SIGMA0_ALPHA = 1e-3


@dataclass
class Budget:
    """The cost a quality-control run may take.

    Attributes
    ----------
    max_rounds : int or None
        Adjustments after the first one (every round of every step counts one; ``None``: no limit;
        0: the first adjustment only, every step skipped).
    max_seconds : float or None
        Wall-clock seconds from the start of the run (checked between rounds).
    """

    max_rounds: int | None = None
    max_seconds: float | None = None
    start: float = field(default_factory=time.perf_counter)
    rounds: int = 0
    spent_in: str = ""

    def __post_init__(self) -> None:
        if self.max_rounds is not None and not (int(self.max_rounds) == self.max_rounds and self.max_rounds >= 0):
            raise QualityControlInputError(f"the QC budget's max_rounds must be an integer >= 0 or None, "
                                           f"got {self.max_rounds!r}")
        if self.max_seconds is not None and not (np.isfinite(self.max_seconds) and self.max_seconds >= 0):
            raise QualityControlInputError(f"the QC budget's max_seconds must be >= 0 or None, got {self.max_seconds!r}")

    def exhausted(self) -> str:
        """Why the budget is spent (``""`` while it is not)."""
        if self.max_rounds is not None and self.rounds >= self.max_rounds:
            return f"budget of {self.max_rounds} adjustment round(s) spent"
        if self.max_seconds is not None and time.perf_counter() - self.start >= self.max_seconds:
            return f"budget of {self.max_seconds:g} s spent ({time.perf_counter() - self.start:.1f} s)"
        return ""


def sigma0_bounds(redundancy: int, alpha: float = SIGMA0_ALPHA) -> tuple[float, float]:
    """Two-sided ``1 - alpha`` bounds of ``sigma0`` of a block with ``redundancy`` degrees of freedom whose
    a-priori sigmas are right (``r sigma0^2 ~ chi2(r)``)."""
    r = float(redundancy)
    return float(np.sqrt(chi2.ppf(alpha / 2, r) / r)), float(np.sqrt(chi2.ppf(1 - alpha / 2, r) / r))


def assess(res: AdjustmentResult, summary: dict, limit: float, alpha: float = SIGMA0_ALPHA,
           active: NDArray[np.bool_] | None = None) -> list[str]:
    """Flags of a run that did not end with a clean block (module docstring); empty if it did.

    Parameters
    ----------
    res : AdjustmentResult
        The run's last adjustment.
    summary : dict
        The report's summary so far (``budget``, ``step_errors``, ``baarda_*`` entries).
    limit : float
        The w-test limit (the data snooping's).
    alpha : float
        Significance of the two-sided chi-square test of ``sigma0``.
    active : (n_obs,) bool, optional
        The image observations in the final block (default those with a weight in ``res``; a robust
        adjustment's result still weighs what the robust step then removed).
    """
    flags: list[str] = []
    if summary.get("budget_spent"):
        flags.append(f"{summary['budget_spent']}; steps not finished: {', '.join(summary.get('steps_unfinished', []))}")
    if summary.get("baarda_round_limit"):
        flags.append(f"data snooping stopped at its round limit ({summary['baarda_rounds']} rounds) with tests failing")
    for err in summary.get("step_errors", []):
        flags.append(f"a step failed on the data: {err}")
    r = res.redundancy
    if r <= 0:
        flags.append(f"no redundancy left (r = {r}): nothing could be tested")
        return flags
    lo, hi = sigma0_bounds(r, alpha)
    s0 = res.sigma0
    if not (lo <= s0 <= hi):
        flags.append(f"sigma0 {s0:.3f} outside [{lo:.3f}, {hi:.3f}], the {100 * (1 - alpha):g} % chi-square bounds "
                     f"at redundancy {r}")
    if "max_w" in summary:
        mw = float(summary["max_w"])
        if np.isfinite(mw) and mw > limit:
            flags.append(f"largest |w| {mw:.2f} left above the limit {limit:g}")
        n_large = int(summary.get("untestable_large", 0))
        if n_large:
            flags.append(f"{n_large} untestable observation(s) (redundancy number below the testable minimum) with "
                         f"|v|/sigma above {limit:g}")
    else:
        pb = res.problem
        act = res.state.obs_weight > 0 if active is None else np.asarray(active, bool)
        if act.any():
            z = np.max(np.abs(res.image_residuals()[act]) / pb.obs.sigma[act], axis=1)
            n = int(np.sum(~(z <= limit)))
            if n:
                flags.append(f"{n} image observation(s) with |v|/sigma above {limit:g} left (their |w| is larger)")
    return flags

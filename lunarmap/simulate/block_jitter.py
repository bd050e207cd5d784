"""CK attitude jitter on the synthetic block's TRUTH kernels (issue 30, item 4), with its truth.

:func:`add_block_jitter` rewrites the TRUTH bus CK of a block written by
:func:`lunarmap.synthetic.write_block_mission`: the true J2000 -> bus matrix becomes

    C(t) = R(j(t)) C_smooth(t),        j_axis(t) = sum_k a_k sin(2 pi f_k (t - t_0) + phi_(k, axis))

(``R`` = :func:`lunarmap.orientation.rotation.rotvec_to_matrix`, ``j`` in the bus frame, radians; random
phases per wave and axis; ``t_0`` the block's start). The jitter is the spacecraft's, so every camera of
the bus carries it; a frame image (5 ms) sees it as a constant attitude offset, a line-scan image as an
attitude that changes from line to line. Each pass's CK segment gets records every ``step`` seconds
from ``margin`` before to ``margin`` after every image (elsewhere the block's 0.5-s records): CK type 3
interpolates linearly, so the records must resolve the highest frequency. The NAVIGATION kernels are
untouched: their attitude stays the smooth one with its errors, as a reconstructed CK misses the jitter.

``jitter_truth.json`` beside the kernels records the waves and phases; :func:`block_jitter_truth`
reads it back and evaluates the jitter of one image in its sensor frame (``mounting @ j``, the frame
of :meth:`lunarmap.camera.corrections.LineScanCorrections.jitter`). Nothing here calls SPICE.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..atomic import atomic_write
from ..errors import InvalidInputError

__all__ = ["BlockJitter", "add_block_jitter", "block_jitter_truth", "JITTER_TRUTH"]

#: The jitter's truth, beside the block's kernels.
JITTER_TRUTH = "jitter_truth.json"


@dataclass(frozen=True)
class BlockJitter:
    """The bus jitter of a block (module docstring).

    Attributes
    ----------
    waves : (n, 2)
        Amplitude (rad) and frequency (Hz) of every sinusoid.
    phases : (n, 3)
        Phase of every wave on each bus axis, radians.
    t0 : float
        Epoch of zero phase, ET seconds.
    mountings : dict
        NAIF instrument id -> bus -> sensor matrix (3, 3).
    instruments : dict
        Image name -> NAIF instrument id.
    """

    waves: NDArray[np.float64]
    phases: NDArray[np.float64]
    t0: float
    mountings: dict[int, NDArray[np.float64]]
    instruments: dict[str, int]

    def bus(self, et: ArrayLike) -> NDArray[np.float64]:
        """The jitter rotation vector ``(n, 3)`` in the bus frame at ``et`` (ET seconds), radians."""
        t = np.atleast_1d(np.asarray(et, float)) - self.t0
        out = np.zeros((t.size, 3))
        for (a, f), ph in zip(self.waves, self.phases):
            out += a * np.sin(2.0 * np.pi * f * t[:, None] + ph[None, :])
        return out

    def sensor(self, image: str, et: ArrayLike) -> NDArray[np.float64]:
        """The jitter ``(n, 3)`` of image ``image`` in its sensor frame at ``et``, radians."""
        if image not in self.instruments:
            raise InvalidInputError(f"no image {image!r} in the jitter truth; have {sorted(self.instruments)}")
        return self.bus(et) @ self.mountings[self.instruments[image]].T


def add_block_jitter(bm: Any, waves: Sequence[tuple[float, float]], seed: int = 0, step: float = 0.002,
                     margin: float = 0.25) -> BlockJitter:
    """Put the bus jitter ``waves`` into the TRUTH CK of block ``bm`` (module docstring); returns its truth.

    Parameters
    ----------
    bm : BlockMission
        A block of :func:`lunarmap.synthetic.write_block_mission` (its TRUTH CK is rewritten).
    waves : sequence of (amplitude, frequency)
        Radians and Hz (LRO NAC-like: 1-3 urad at 1-10 Hz).
    seed : int
        Seed of the phases.
    step : float
        Record spacing around the images, s (at most a tenth of the shortest period).
    margin : float
        Dense records this long before and after every image, s.

    Raises
    ------
    InvalidInputError
        No waves, a non-positive frequency or amplitude, or records too sparse for a wave.
    """
    from ..orientation.rotation import align_quaternion_signs, matrix_to_quat, rotvec_to_matrix
    from ..spice.writer import CkSegment, write_ck
    from ..synthetic import ids
    from ..synthetic.block import TRUTH_CK_STEP
    from ..synthetic.block_writing import TRUTH_KERNELS, shared_kernels

    w = np.asarray(waves, float).reshape(-1, 2)
    if w.shape[0] == 0 or not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise InvalidInputError(f"add_block_jitter: waves must be (amplitude > 0 rad, frequency > 0 Hz), got {waves!r}")
    if not (np.isfinite(step) and 0 < step <= 0.1 / float(w[:, 1].max())):
        raise InvalidInputError(f"add_block_jitter: step {step!r} s does not resolve {w[:, 1].max():g} Hz "
                                "(at most a tenth of its period)")
    model = bm.model
    rng = np.random.default_rng([int(seed), 30])
    jit = BlockJitter(w, rng.uniform(0.0, 2.0 * np.pi, (w.shape[0], 3)), float(model.start_et),
                      {int(c.naif_id): model.mounting(c.naif_id) for c in model.cameras},
                      {im.name: int(im.camera.naif_id) for im in model.images})

    def matrix(et: NDArray[np.float64]) -> NDArray[np.float64]:
        return rotvec_to_matrix(jit.bus(et)) @ model.bus_matrix(et)

    segs = []
    for p in model.passes:
        n = int(round((p.end_et - p.start_et) / TRUTH_CK_STEP))
        grids = [p.start_et + TRUTH_CK_STEP * np.arange(n + 1)]
        for im in model.images:
            a = max(im.planned_start_et - margin, p.start_et)
            b = min(im.planned_start_et + im.duration + margin, p.end_et)
            if b > a:
                grids.append(np.arange(a, b, step))
        t = np.unique(np.concatenate(grids))
        t = t[np.r_[True, np.diff(t) > 1e-4]]          # no two records closer than the clock resolves
        c = matrix(t)
        h = 1e-4        # s: central differences of the jitter's rate (1e-4 of its period at 10 Hz)
        dc = (matrix(t + h) - matrix(t - h)) / (2.0 * h)
        s = -np.swapaxes(c, -1, -2) @ dc
        av = 0.5 * np.stack([s[..., 2, 1] - s[..., 1, 2], s[..., 0, 2] - s[..., 2, 0],
                             s[..., 1, 0] - s[..., 0, 1]], axis=-1)
        q = align_quaternion_signs(matrix_to_quat(c))
        name = f"ORBIT {p.orbit}" if model.n_sites == 1 else f"ORBIT {p.orbit} SITE {p.site}"
        segs.append(CkSegment(ids.BUS_FRAME_ID, "J2000", t, q, av, f"SIM BLOCK BUS TRUTH {name}"))
    d = Path(bm.folder)
    lsk, sclk = (d / f for f in shared_kernels(model.layout)[:2])
    comments = ["True bus attitude CK of the LUNARMAP-SIM imaging block (fictional; not real data), with "
                "attitude jitter: " + ", ".join(f"{a * 1e6:g} urad at {f:g} Hz" for a, f in w)]
    target = d / TRUTH_KERNELS[1]
    atomic_write(target, lambda tmp: write_ck(tmp, segs, time_kernels=[lsk, sclk], sclk_id=ids.SCLK_ID,
                                              internal_name="LUNARMAP-SIM BLOCK BUS", comments=comments))
    doc = {"format": 1, "frame": "bus", "waves_rad_hz": w.tolist(), "phases_rad": jit.phases.tolist(),
           "t0_et": jit.t0, "mountings": {str(k): v.tolist() for k, v in jit.mountings.items()},
           "instruments": jit.instruments, "record_step_s": float(step)}
    atomic_write(d / JITTER_TRUTH, lambda tmp: tmp.write_text(json.dumps(doc, indent=1)))
    return jit


def block_jitter_truth(folder: str | Path) -> BlockJitter | None:
    """The jitter truth of a block folder (``jitter_truth.json``), or None when its CK has none."""
    p = Path(folder) / JITTER_TRUTH
    if not p.exists():
        return None
    doc = json.loads(p.read_text())
    return BlockJitter(np.asarray(doc["waves_rad_hz"], float).reshape(-1, 2), np.asarray(doc["phases_rad"], float),
                       float(doc["t0_et"]), {int(k): np.asarray(v, float) for k, v in doc["mountings"].items()},
                       {str(k): int(v) for k, v in doc["instruments"].items()})

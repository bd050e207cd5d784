"""Adjusted orientation as SPICE kernels layered over the original kernel set.

:func:`write_orientation_kernels` takes adjusted image support data (from
:func:`~lunarmap.orientation.update.updated_image_support`) and writes, into
one folder,

* ``<name>.bsp``: an SPK of type 13 (Hermite, degree 3) with the spacecraft
  relative to the target body in J2000, one segment per group of images;
* ``<name>.bc``: a CK of type 3 with angular velocities for the first
  time-dependent frame of each image's pointing chain, relative to J2000,
  encoded with the spacecraft clock SPICE itself would use for that frame
  (``ckmeta``), one segment (one interpolation interval) per group;
* ``<name>.tm``: a meta-kernel listing the original kernels followed by the
  two new ones. Kernels loaded later take priority, so wherever the new
  segments have data they replace the original trajectory and attitude, and
  everywhere else the original set answers unchanged.

``image_support(label, "<name>.tm")`` with the unchanged driver then returns the
adjusted geometry at the driver's epochs (which come from the labels and the
unchanged clock kernels). Before anything is written to the folder, the CK is
read back through SPICE at every epoch (measured <= 4e-16 rad).

Aberration correction
---------------------
Drivers ask SPICE for the *corrected* spacecraft position (``LT+S``, or ISIS's
light time to the surface, ``SURFACE``, for Kaguya; ``NONE`` for LRO NAC,
Clementine and the synthetic mission). An SPK holds the *geometric*
trajectory, so its records are found by fixed-point iteration: write, query
exactly as the driver does, add each epoch's residual to its record, repeat.
The records sit where SPICE evaluates the spacecraft for that query: at the
epoch for ``NONE`` and ``SURFACE`` (which moves the body, not the spacecraft),
one geometric light time (about 6 ms) earlier for ``LT``/``LT+S``. Each
corrected state then depends on one record only and the iteration contracts
by ~1e-4 per pass (the light-time and aberration terms barely depend on the
trajectory); with records on the driver's epochs instead, the query would read
the trajectory between records and the per-record update would amplify
alternating errors about twofold per pass. ``NONE`` is exact after one pass
(1e-9 m); ``LT+S`` and ``SURFACE`` stop after 3 or 4 passes at SPICE's own
floor: a corrected position is a difference of barycentric ones near 1.5e8 km,
whose float64 spacing is 30 micrometres (measured 3e-5 m), well inside
:data:`FIT_POSITION_TOLERANCE`.

Extension beyond the sampled epochs
-----------------------------------
Each segment starts ``margin`` seconds (default 1 s) before its first epoch
and ends ``margin`` after its last, cut to half the gap to the neighbouring
segment of the same spacecraft or frame. There the trajectory is continued on
the straight line of the end record's position and velocity, and the attitude
rotates at the end record's angular velocity (a constant-rate rotation, which
is also how CK type 3 interpolates). This is how a frame image, whose ISD has
a single epoch, gets the three records a segment needs. It is exact where the
driver samples: SPK type 13 and CK type 3 return a record's own values at its
epoch, and the light-time iteration makes the *corrected* query there equal
the adjusted value however the trajectory is continued. Off the
sampled epochs the straight line leaves a lunar orbit by ``g dt^2 / 2``
(0.8 m after 1 s, 2e-5 m after 5 ms, half a frame exposure), which only a
caller sampling the margins would see.

Several images
--------------
Images are grouped per spacecraft (SPK) and per CK frame. Images whose
sampled intervals overlap must agree on that object where they overlap
(positions within :data:`MERGE_POSITION_TOLERANCE`, velocities within
:data:`MERGE_VELOCITY_TOLERANCE`, attitude within
:data:`MERGE_ROTATION_TOLERANCE`, each image's EO evaluated at the other's
epochs); their records are then merged into one segment, so each image's
epochs are still records of its own (e.g. a frame taken during a pushbroom
image, both corrected by one trajectory and attitude correction). Otherwise :class:`~lunarmap.errors.OrientationConflictError` is
raised: one SPK holds one trajectory per spacecraft and one CK one attitude per
frame. This matters when two instruments hang off one bus: their first
time-dependent frame is the bus (the synthetic mission's pushbroom and framing
camera, each on a TK mounting), so simultaneous images of both, adjusted
independently, would need two attitudes of one bus. LRO's NAC-L and NAC-R are
CK frames of their own and never conflict in the CK, but they share the
spacecraft's SPK. Write such images into separate kernel sets, or adjust them
with a shared correction.
"""

from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from ..atomic import atomic_path
from ..errors import (
    InvalidInputError,
    KernelCoverageError,
    LunarmapError,
    MissingClockError,
    OrientationConflictError,
    OrientationKernelError,
    TrajectoryFitError,
)
from ..spice import SPICE_LOCK, KernelSet, kernels
from ..spice import queries as q
from ..spice.writer import CkSegment, SpkSegment, loaded_temporarily, write_ck, write_spk, write_text_kernel
from .isd import ImageSupport
from .rotation import align_quaternion_signs, matrix_to_quat, quat_to_matrix
from .update import _image_name

__all__ = ["write_orientation_kernels", "MERGE_POSITION_TOLERANCE", "MERGE_VELOCITY_TOLERANCE",
           "MERGE_ROTATION_TOLERANCE",
           "FIT_POSITION_TOLERANCE", "FIT_VELOCITY_TOLERANCE", "MAX_FIT_ITERATIONS"]

#: Overlapping images may share a trajectory if they agree within this, m.
MERGE_POSITION_TOLERANCE = 1e-4
#: ... and their velocities within this, m/s. An EO's velocity between its samples (the derivative
#: of its Hermite spline) is only good to ~1e-4 m/s; velocities reach the cameras through the
#: interpolation between records, where 1e-3 m/s over a few milliseconds is below a micrometre.
MERGE_VELOCITY_TOLERANCE = 1e-3
#: Overlapping images may share a CK frame's attitude if they agree within this, rad.
MERGE_ROTATION_TOLERANCE = 1e-9
#: The corrected positions the driver will read back must match within this, m. SPICE forms an
#: aberration-corrected position as the difference of two solar-system-barycentric ones near
#: 1.5e8 km, whose float64 spacing is 30 micrometres: that is the noise floor of the driver's own
#: LT+S and SURFACE positions (NONE positions come back exact to 1e-9 m).
FIT_POSITION_TOLERANCE = 1e-4
#: ... and the corrected velocities within this, m/s (noise floor about 2e-7 m/s).
FIT_VELOCITY_TOLERANCE = 1e-5
#: Passes of the light-time iteration before giving up.
MAX_FIT_ITERATIONS = 8
#: Largest pointing difference (rad) between the written CK and the ISDs; anything above is a bug.
_CK_CHECK_TOLERANCE = 1e-12
#: Margins shorter than this (s) are dropped rather than written as records crowding the neighbour.
_MIN_MARGIN = 1e-3
#: SPK and CK records closer than this (s) are merged into one (only merged images produce them).
_MIN_RECORD_GAP = 1e-6
#: Aberration corrections that evaluate the spacecraft a light time before / after the epoch.
_BACKWARD = ("LT", "LT+S", "CN", "CN+S")
_FORWARD = ("XLT", "XLT+S", "XCN", "XCN+S")

_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")
_J2000 = 1


def _rotation_about(w: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """``expm([w]x dt)``: rotation about ``w`` by ``|w| dt`` (Rodrigues)."""
    angle = float(np.linalg.norm(w)) * dt
    if angle == 0.0:
        return np.eye(3)
    k = w / np.linalg.norm(w)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * (kx @ kx)


def _state_inverse(xf: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverses of state transformations ``[[R, 0], [dR, R]]``: ``[[R^T, 0], [dR^T, R^T]]``."""
    out = np.zeros_like(xf)
    out[:, :3, :3] = out[:, 3:, 3:] = np.swapaxes(xf[:, :3, :3], 1, 2)
    out[:, 3:, :3] = np.swapaxes(xf[:, 3:, :3], 1, 2)
    return out


def _rotation_angle(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angles (rad) of the rotations ``a b^T`` between matrix stacks."""
    qd = matrix_to_quat(a @ np.swapaxes(b, -1, -2))
    return 2.0 * np.arcsin(np.clip(np.linalg.norm(qd[..., 1:], axis=-1), 0.0, 1.0))


@dataclass
class _Image:
    """One adjusted image, resolved to the SPICE objects its kernels hold."""

    name: str
    isd: ImageSupport
    spacecraft: int
    target: int
    correction: str
    radius_km: float
    frame: int
    ck_id: int
    clock: int
    times: NDArray[np.float64] = field(init=False)
    states: NDArray[np.float64] = field(init=False)  # J2000, km and km/s, as the driver reads them
    quats: NDArray[np.float64] = field(init=False)  # J2000 -> frame
    rates: NDArray[np.float64] = field(init=False)  # rad/s, xf2rav convention

    def __post_init__(self) -> None:
        self.times = np.asarray(self.isd.times, dtype=float)
        self.states = np.hstack([self.isd.positions, self.isd.velocities])
        self.quats = np.asarray(self.isd.pointing.quaternions, dtype=float)
        self.rates = np.asarray(self.isd.pointing.angular_velocities, dtype=float)

    @property
    def t0(self) -> float:
        return float(self.times[0])

    @property
    def t1(self) -> float:
        return float(self.times[-1])

    def state_at(self, t: NDArray[np.float64], other: "_Image") -> NDArray[np.float64]:
        """This image's adjusted J2000 state (km, km/s) at ``other``'s epochs ``t``.

        The body rotation comes from ``other``'s ISD (same body, same kernels).
        """
        eo = self.isd.exterior_orientation()
        xf = other.isd.body_state_rotations[np.searchsorted(other.times, t)]
        bf = np.hstack([eo.position_at(t - eo.epoch), eo.velocity_at(t - eo.epoch)]) / 1000.0
        return np.einsum("nij,nj->ni", _state_inverse(xf), bf)

    def pointing_at(self, t: NDArray[np.float64], other: "_Image") -> NDArray[np.float64]:
        """This image's adjusted J2000 -> frame matrices at ``other``'s epochs ``t``."""
        eo = self.isd.exterior_orientation()
        rot = other.isd.body_state_rotations[np.searchsorted(other.times, t), :3, :3]
        k = self.isd.pointing.constant_rotation
        return k.T @ np.swapaxes(eo.rotation_at(t - eo.epoch), 1, 2) @ rot


def _resolve(isd: ImageSupport) -> _Image:
    """Spacecraft, target, correction, CK frame and clock of an ISD; the base kernels are loaded."""
    name = _image_name(isd)
    prov = isd.provenance
    if "position_correction" not in prov:
        raise InvalidInputError(f"image {name}: provenance['position_correction'] is missing; the aberration "
                                "correction the driver applies must be known to write its trajectory")
    if "spacecraft_id" in prov:
        spacecraft = int(prov["spacecraft_id"])
    else:
        try:
            spacecraft = q.body_code(isd.name_platform)
        except LunarmapError as err:
            raise InvalidInputError(f"image {name}: no provenance['spacecraft_id'] and platform "
                                    f"{isd.name_platform!r} is no NAIF body name") from err
    target = prov.get("target_id", isd.naif_keywords.get("BODY_CODE"))
    if target is None:
        raise InvalidInputError(f"image {name}: neither provenance['target_id'] nor naif_keywords['BODY_CODE']")
    chain = list(isd.pointing.time_dependent_frames)
    if not chain or chain[-1] != _J2000:
        raise InvalidInputError(f"image {name}: pointing chain {chain} does not end in J2000 (1)")
    frame = int(chain[0])
    _, cls, ck_id = q.frame_info(frame)
    if cls != 3:
        raise InvalidInputError(f"image {name}: the first time-dependent frame {frame} is of class {cls}, "
                                "not a CK frame (class 3); its attitude cannot be written as a CK")
    clock = q.ck_clock(ck_id)
    try:
        q.sclk_ticks(clock, isd.times[:1])
    except KernelCoverageError as err:
        raise MissingClockError(f"image {name}: CK frame {frame} is encoded with spacecraft clock {clock}, "
                                f"which the kernel set does not define (no SCLK kernel for it): {err}") from err
    radii = np.asarray(isd.radii, dtype=float)
    return _Image(name, isd, spacecraft, int(target), str(prov["position_correction"]).upper(),
                  float(radii[0] + radii[2]) / 2.0, frame, int(ck_id), int(clock))


def _clusters(images: list[_Image]) -> list[list[_Image]]:
    """Images sorted by start and grouped where their closed sampled intervals overlap."""
    out: list[list[_Image]] = []
    end = -np.inf
    for im in sorted(images, key=lambda i: (i.t0, i.t1)):
        if out and im.t0 <= end:
            out[-1].append(im)
            end = max(end, im.t1)
        else:
            out.append([im])
            end = im.t1
    return out


def _margins(groups: list[list[_Image]], margin: float) -> list[tuple[float, float]]:
    """Extension (s) before and after each group: ``margin``, cut to half the gap to a neighbour."""
    out = []
    for i, g in enumerate(groups):
        t0, t1 = g[0].t0, max(im.t1 for im in g)
        before = margin if i == 0 else min(margin, (t0 - max(im.t1 for im in groups[i - 1])) / 2.0)
        after = margin if i == len(groups) - 1 else min(margin, (groups[i + 1][0].t0 - t1) / 2.0)
        out.append((before if before >= _MIN_MARGIN else 0.0, after if after >= _MIN_MARGIN else 0.0))
    return out


def _overlap(a: _Image, b: _Image) -> NDArray[np.float64]:
    """``b``'s epochs inside ``a``'s sampled interval."""
    return b.times[(b.times >= a.t0) & (b.times <= a.t1)]


def _check_trajectories_agree(group: list[_Image]) -> None:
    for i, a in enumerate(group):
        for b in group[i + 1:]:
            if a.correction != b.correction:
                raise OrientationConflictError(
                    f"images {a.name} and {b.name} overlap in time on spacecraft {a.spacecraft} but their "
                    f"positions are aberration-corrected differently ({a.correction} vs {b.correction}); "
                    "write them into separate kernel sets")
            worst_p = worst_v = 0.0
            for x, y in ((a, b), (b, a)):
                t = _overlap(x, y)
                if t.size:
                    state = x.state_at(t, y)
                    idx = np.searchsorted(y.times, t)
                    diff = (state - y.states[idx]) * 1000.0
                    worst_p = max(worst_p, float(np.max(np.linalg.norm(diff[:, :3], axis=1))))
                    worst_v = max(worst_v, float(np.max(np.linalg.norm(diff[:, 3:], axis=1))))
            if worst_p > MERGE_POSITION_TOLERANCE or worst_v > MERGE_VELOCITY_TOLERANCE:
                lo, hi = max(a.t0, b.t0), min(a.t1, b.t1)
                raise OrientationConflictError(
                    f"images {a.name} and {b.name} overlap in time (ET {lo:.6f} .. {hi:.6f}) and put spacecraft "
                    f"{a.spacecraft} up to {worst_p:.6g} m / {worst_v:.3g} m/s apart (> {MERGE_POSITION_TOLERANCE} "
                    f"m / {MERGE_VELOCITY_TOLERANCE} m/s); one SPK holds one trajectory per spacecraft: write them "
                    "into separate kernel sets or adjust them with a shared trajectory correction")


def _check_attitudes_agree(group: list[_Image]) -> None:
    for i, a in enumerate(group):
        for b in group[i + 1:]:
            worst = 0.0
            for x, y in ((a, b), (b, a)):
                t = _overlap(x, y)
                if t.size:
                    quat = x.pointing_at(t, y)
                    idx = np.searchsorted(y.times, t)
                    worst = max(worst, float(np.max(_rotation_angle(quat, quat_to_matrix(y.quats[idx])))))
            if worst > MERGE_ROTATION_TOLERANCE:
                lo, hi = max(a.t0, b.t0), min(a.t1, b.t1)
                raise OrientationConflictError(
                    f"images {a.name} and {b.name} overlap in time (ET {lo:.6f} .. {hi:.6f}) and give CK frame "
                    f"{a.frame} attitudes up to {worst:.3g} rad apart (> {MERGE_ROTATION_TOLERANCE} rad); both "
                    "instruments hang off that frame (e.g. one bus) and one CK holds one attitude per frame: "
                    "write them into separate kernel sets or adjust them with a shared attitude correction")


def _merged(group: list[_Image], columns: str) -> tuple[NDArray[np.float64], list[NDArray[np.float64]], list[int]]:
    """Epochs and data of a group's images in time order; exact duplicate epochs kept once.

    Returns the epochs, the data columns (``"spk"``: states; ``"ck"``: quaternions,
    rates) and, per epoch, the index of the image it came from.
    """
    t = np.concatenate([im.times for im in group])
    owner = np.concatenate([np.full(im.times.size, k) for k, im in enumerate(group)])
    if columns == "spk":
        data = [np.concatenate([im.states for im in group])]
    else:
        data = [np.concatenate([im.quats for im in group]), np.concatenate([im.rates for im in group])]
    order = np.argsort(t, kind="stable")
    t, owner, data = t[order], owner[order], [d[order] for d in data]
    keep = np.concatenate([[True], np.diff(t) > 0.0])
    return t[keep], [d[keep] for d in data], owner[keep].tolist()


@dataclass
class _SpkGroup:
    """One SPK segment: a spacecraft's merged records plus straight-line margins.

    Records sit where SPICE evaluates the spacecraft for the driver's query:
    at the driver's epoch for ``NONE`` and ``SURFACE`` (which moves the body,
    not the spacecraft), a light time earlier for ``LT``/``CN`` corrections and
    a light time later for the ``X`` (transmission) ones. The corrected state at
    an epoch then depends on one record only, so adding each epoch's residual to
    its own record converges (a record at the driver's epoch would not: the
    query would read the trajectory between records, and the per-record update
    amplifies alternating errors there by up to 2 per pass).
    """

    images: list[_Image]
    before: float
    after: float
    times: NDArray[np.float64] = field(init=False)  # the driver's epochs
    target: NDArray[np.float64] = field(init=False)  # corrected states the driver must read (km, km/s)
    corrections: list[str] = field(init=False)
    radii: NDArray[np.float64] = field(init=False)
    direction: NDArray[np.float64] = field(init=False)  # record epoch = time + direction * light time
    owner: NDArray[np.bool_] = field(init=False)  # which epochs own a record (the others are within 1 us of one)

    def __post_init__(self) -> None:
        self.times, (self.target,), owner = _merged(self.images, "spk")
        self.corrections = [self.images[k].correction for k in owner]
        self.radii = np.array([self.images[k].radius_km for k in owner])
        self.direction = np.array([-1.0 if c in _BACKWARD else 1.0 if c in _FORWARD else 0.0
                                   for c in self.corrections])
        self.owner = np.ones(self.times.size, bool)

    @property
    def spacecraft(self) -> int:
        return self.images[0].spacecraft

    @property
    def center(self) -> int:
        return self.images[0].target

    def light_times(self) -> NDArray[np.float64]:
        """One-way light times (s) of the corrected queries with the kernels now loaded (0 where unused)."""
        lt = np.zeros(self.times.size)
        corr = np.array(self.corrections)
        for c in sorted(set(self.corrections)):
            sel = (corr == c) & (self.direction != 0.0)
            if np.any(sel):
                # 'LT' corrections evaluate the spacecraft at the epoch minus the *geometric* light time
                # (SPICE's one-iteration solution starts from it); 'CN' ones at the converged light time
                lt[sel] = q.light_times(self.spacecraft, self.times[sel], "J2000",
                                        "NONE" if c.lstrip("X").startswith("LT") else c, self.center)
        return lt

    def segment(self, geometric: NDArray[np.float64], light_times: NDArray[np.float64]) -> SpkSegment:
        epochs = self.times + self.direction * light_times
        order = np.argsort(epochs, kind="stable")
        # merged images may ask for (nearly) the same record twice; they agree, so one serves both
        keep = np.ones(order.size, bool)
        last = epochs[order[0]]
        for i in range(1, order.size):
            keep[i] = epochs[order[i]] - last >= _MIN_RECORD_GAP
            last = epochs[order[i]] if keep[i] else last
        self.owner = np.zeros(self.times.size, bool)
        self.owner[order[keep]] = True
        t, st = epochs[order[keep]], geometric[order[keep]]
        if self.before > 0.0:
            t = np.concatenate([[t[0] - self.before], t])
            st = np.vstack([np.hstack([st[0, :3] - self.before * st[0, 3:], st[0, 3:]]), st])
        if self.after > 0.0:
            t = np.concatenate([t, [t[-1] + self.after]])
            st = np.vstack([st, np.hstack([st[-1, :3] + self.after * st[-1, 3:], st[-1, 3:]])])
        segid = ("ADJ " + " ".join(Path(im.name).stem for im in self.images))[:40]
        return SpkSegment(self.spacecraft, self.center, "J2000", t, st[:, :3], st[:, 3:], segid, degree=3)

    def corrected(self) -> NDArray[np.float64]:
        """The states the driver reads at its epochs with the kernels now loaded."""
        out = np.empty_like(self.target)
        corr = np.array(self.corrections)
        for c in sorted(set(self.corrections)):
            sel = corr == c
            if c == "SURFACE":
                for r in np.unique(self.radii[sel]):
                    sub = sel & (self.radii == r)
                    out[sub] = q.surface_lt_states(self.spacecraft, self.center, self.times[sub], "J2000", float(r))
            else:
                out[sel] = q.states(self.spacecraft, self.times[sel], "J2000", c, self.center)
        return out


@dataclass
class _CkGroup:
    """One CK segment: a frame's merged records plus constant-rate margins."""

    images: list[_Image]
    before: float
    after: float

    def segment(self) -> CkSegment:
        t, (quats, rates), _ = _merged(self.images, "ck")
        mats = quat_to_matrix(quats)
        ticks = q.sclk_ticks(self.clock, t)
        # records of merged images (nearly) on one epoch: keep the first (they agree, see
        # _check_attitudes_agree). Ticks may be coarse (Kaguya's are 1 s); SPICE takes fractional
        # ones but needs them strictly increasing.
        keep = np.ones(t.size, bool)
        last = 0
        for i in range(1, t.size):
            keep[i] = t[i] - t[last] >= _MIN_RECORD_GAP and ticks[i] > ticks[last]
            last = i if keep[i] else last
        t, mats, rates = t[keep], mats[keep], rates[keep]
        if self.before > 0.0:
            first = mats[0] @ _rotation_about(rates[0], self.before)  # Q(t0 - m) = Q0 expm(+[w]x m)
            t, mats, rates = (np.concatenate([[t[0] - self.before], t]), np.concatenate([first[None], mats]),
                              np.vstack([rates[:1], rates]))
        if self.after > 0.0:
            last_m = mats[-1] @ _rotation_about(rates[-1], -self.after)  # Q(t1 + m) = Q1 expm(-[w]x m)
            t, mats, rates = (np.concatenate([t, [t[-1] + self.after]]), np.concatenate([mats, last_m[None]]),
                              np.vstack([rates, rates[-1:]]))
        segid = ("ADJ " + " ".join(Path(im.name).stem for im in self.images))[:40]
        return CkSegment(self.ck_id, "J2000", t, align_quaternion_signs(matrix_to_quat(mats)), rates, segid,
                         sclk_id=self.clock)

    @property
    def ck_id(self) -> int:
        return self.images[0].ck_id

    @property
    def clock(self) -> int:
        return self.images[0].clock

    @property
    def frame(self) -> int:
        return self.images[0].frame


def _groups(images: list[_Image], margin: float) -> tuple[list[_SpkGroup], list[_CkGroup]]:
    spk: list[_SpkGroup] = []
    ck: list[_CkGroup] = []
    for key in sorted({(im.spacecraft, im.target) for im in images}):
        clusters = _clusters([im for im in images if (im.spacecraft, im.target) == key])
        for c, (before, after) in zip(clusters, _margins(clusters, margin)):
            _check_trajectories_agree(c)
            spk.append(_SpkGroup(c, before, after))
    for ck_id in sorted({im.ck_id for im in images}):
        members = [im for im in images if im.ck_id == ck_id]
        if len({im.clock for im in members}) > 1:
            raise OrientationConflictError(f"CK id {ck_id}: images disagree on its clock")
        clusters = _clusters(members)
        for c, (before, after) in zip(clusters, _margins(clusters, margin)):
            _check_attitudes_agree(c)
            ck.append(_CkGroup(c, before, after))
    return spk, ck


def _fit_trajectories(groups: list[_SpkGroup], tmp: Path) -> tuple[list[SpkSegment], int, float, float]:
    """Geometric records whose corrected states equal the targets; the base kernels are loaded.

    Returns the segments, the number of passes and the final position (m) and
    velocity (m/s) residuals.
    """
    geometric = [g.target.copy() for g in groups]
    light = [g.light_times() for g in groups]  # first guess: the original trajectory's
    worst_p = worst_v = np.inf
    for it in range(1, MAX_FIT_ITERATIONS + 1):
        segments = [g.segment(x, lt) for g, x, lt in zip(groups, geometric, light)]
        path = tmp / f"fit{it}.bsp"
        write_spk(path, segments, internal_name="LUNARMAP ADJUSTED SPK FIT")
        with SPICE_LOCK, loaded_temporarily([path]):
            residuals = [g.target - g.corrected() for g in groups]
            moved = [g.light_times() for g in groups]
        worst_p = worst_v = 0.0
        for g, r in zip(groups, residuals):
            # an epoch served by another image's record may differ by what the merge allowed
            slack_p = np.where(g.owner, 0.0, MERGE_POSITION_TOLERANCE)
            slack_v = np.where(g.owner, 0.0, MERGE_VELOCITY_TOLERANCE)
            worst_p = max(worst_p, float(np.max(np.linalg.norm(r[:, :3], axis=1) * 1000.0 - slack_p)))
            worst_v = max(worst_v, float(np.max(np.linalg.norm(r[:, 3:], axis=1) * 1000.0 - slack_v)))
        if worst_p <= FIT_POSITION_TOLERANCE and worst_v <= FIT_VELOCITY_TOLERANCE:
            return segments, it, worst_p, worst_v
        # a record that follows its (changed) light time slides along the trajectory with it
        geometric = [x + r + np.hstack([(g.direction * (lt_new - lt))[:, None] * x[:, 3:], np.zeros_like(x[:, 3:])])
                     for g, x, r, lt, lt_new in zip(groups, geometric, residuals, light, moved)]
        light = moved
    names = ", ".join(im.name for g in groups for im in g.images)
    raise TrajectoryFitError(
        f"after {MAX_FIT_ITERATIONS} passes the aberration-corrected states of {names} still differ from the "
        f"adjusted ones by {worst_p:.3g} m / {worst_v:.3g} m/s (tolerance {FIT_POSITION_TOLERANCE} m, "
        f"{FIT_VELOCITY_TOLERANCE} m/s)")


def _check_pointing(groups: list[_CkGroup], spk: Path, ck: Path) -> float:
    """Largest angle (rad) between what SPICE reads from the new CK and the ISDs; the base is loaded."""
    worst = 0.0
    with SPICE_LOCK, loaded_temporarily([spk, ck]):
        for g in groups:
            for im in g.images:
                got = q.rotations("J2000", g.frame, im.times)
                worst = max(worst, float(np.max(_rotation_angle(got, quat_to_matrix(im.quats)))))
    if worst > _CK_CHECK_TOLERANCE:
        raise OrientationKernelError(f"the CK written for {', '.join(im.name for g in groups for im in g.images)} "
                                     f"reads back {worst:.3g} rad off the adjusted pointing")
    return worst


def _comments(images: list[_Image], base: KernelSet, passes: int, res_p: float, res_v: float,
              ck_error: float) -> list[str]:
    lines = ["Adjusted exterior orientation written by lunarmap.orientation.kernels.write_orientation_kernels.",
             f"Layered over the kernel set {base.source or '(explicit file list)'}: load the original",
             "kernels first and these after them (the companion meta-kernel does).",
             f"Aberration-correction fit: {passes} pass(es); corrected positions within {res_p:.3g} m,",
             f"velocities within {res_v:.3g} m/s; CK read back within {ck_error:.3g} rad.",
             "Images (label or sensor, first and last ET, position correction, spacecraft, CK frame):"]
    for im in images:
        lines.append(f"  {im.name}  {im.t0:.6f} {im.t1:.6f}  {im.correction}  {im.spacecraft}  {im.frame}")
    return lines


def write_orientation_kernels(isds: Sequence[ImageSupport], folder: str | os.PathLike[str],
                              base: KernelSet | str | os.PathLike[str], name: str = "adjusted",
                              *, margin: float = 1.0) -> Path:
    """Write adjusted ISDs as an SPK, a CK and a meta-kernel layered over the original set.

    Parameters
    ----------
    isds : sequence of ImageSupport
        Adjusted image support data (:func:`~lunarmap.orientation.update.updated_image_support`),
        made by lunarmap's drivers from ``base`` (their provenance names the
        spacecraft, target and aberration correction).
    folder : path-like
        Existing folder for ``<name>.bsp``, ``<name>.bc`` and ``<name>.tm``.
    base : KernelSet or path-like
        The original kernel set (or its meta-kernel); never modified.
    name : str
        Base name of the three files (letters, digits, ``_ . -``).
    margin : float
        Extension of each segment beyond its first and last epoch, s (cut to
        half the gap to a neighbouring segment of the same object).

    Returns
    -------
    pathlib.Path
        The new meta-kernel: the original kernels followed by the new SPK and CK.

    Raises
    ------
    InvalidInputError
        No ISDs, a bad name, margin or folder, a name that would overwrite a
        kernel of ``base``, an ISD without the provenance needed or whose
        first time-dependent frame is not a CK frame.
    MissingClockError
        A CK frame's spacecraft clock is not defined by ``base``.
    OrientationConflictError
        Images overlapping in time disagree on one spacecraft's position or
        one CK frame's attitude.
    TrajectoryFitError
        The light-time iteration did not converge.
    KernelCoverageError, SpiceError
        SPICE could not evaluate the original set where needed.

    Nothing is written unless everything succeeds: the three files are
    composed under temporary names and renamed into place together.
    """
    isds = list(isds)
    if not isds:
        raise InvalidInputError("write_orientation_kernels: no image support data given")
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise InvalidInputError(f"kernel base name {name!r}: use letters, digits, '_', '.' and '-' only")
    if not np.isfinite(margin) or margin < 0.0:
        raise InvalidInputError(f"margin must be a finite number of seconds >= 0, got {margin!r}")
    out = Path(folder).expanduser()
    if not out.is_dir():
        raise InvalidInputError(f"cannot write adjusted kernels: folder {out} does not exist")
    kset = base if isinstance(base, KernelSet) else KernelSet.from_metakernel(base)
    spk_path, ck_path, mk_path = (out / f"{name}{ext}" for ext in (".bsp", ".bc", ".tm"))
    originals = {os.path.realpath(p) for p in kset.paths} | ({os.path.realpath(kset.source)} if kset.source else set())
    for p in (spk_path, ck_path, mk_path):
        if os.path.realpath(p) in originals:
            raise InvalidInputError(f"{p} is part of the original kernel set; choose another name or folder")

    with kernels(kset), tempfile.TemporaryDirectory(prefix="lunarmap-adjusted-") as tmp_name:
        tmp = Path(tmp_name)
        images = [_resolve(isd) for isd in isds]
        spk_groups, ck_groups = _groups(images, float(margin))
        spk_segments, passes, res_p, res_v = _fit_trajectories(spk_groups, tmp)
        ck_segments = [g.segment() for g in ck_groups]
        write_spk(tmp / "check.bsp", spk_segments, internal_name="LUNARMAP ADJUSTED SPK")
        write_ck(tmp / "check.bc", ck_segments, time_kernels=[], internal_name="LUNARMAP ADJUSTED CK")
        ck_error = _check_pointing(ck_groups, tmp / "check.bsp", tmp / "check.bc")
        comments = _comments(images, kset, passes, res_p, res_v, ck_error)
        listed = [*kset.paths, str(spk_path.resolve()), str(ck_path.resolve())]
        mk_comments = "\n".join(["Meta-kernel of adjusted orientation (lunarmap).", "",
                                 "The original kernels come first; the adjusted SPK and CK after them",
                                 "take priority where they have data.", "", *comments])
        with atomic_path(spk_path) as t_spk, atomic_path(ck_path) as t_ck, atomic_path(mk_path) as t_mk:
            write_spk(t_spk, spk_segments, internal_name="LUNARMAP ADJUSTED SPK", comments=comments)
            write_ck(t_ck, ck_segments, time_kernels=[], internal_name="LUNARMAP ADJUSTED CK", comments=comments)
            write_text_kernel(t_mk, "MK", {"KERNELS_TO_LOAD": listed}, mk_comments)
    return mk_path

"""The final status of every observation of a quality-controlled adjustment (issue 27, item 5).

Every image observation, every weighted control point and every row of every term of the base problem
(navigation observations, reference DTM heights) ends in exactly one of :data:`STATUSES`:

* ``"in"`` -- in the final adjustment at its a-priori weight (or given back after a removal);
* ``"removed"`` -- judged wrong by a test of its own (Sequent, a robust weight below the limit, a
  w-test): weight 0;
* ``"down-weighted"`` -- a navigation, terrain or control observation kept with a reduced weight (``P / factor``,
  or flagged);
* ``"withdrawn"`` -- out with all the rays of its point: the data cannot tell which of them is wrong;
* ``"set-aside"`` -- out for a reason that is not a test of its own: its point was left with fewer than
  two rays, dragged onto a projection centre, or could not be started in front of its cameras.

The table is built from the ledger's final weights (what is in or out) and its decisions (which step,
round and test value decided): :func:`final_status`. What counts as "out" is the ledger's own
``active`` flags, so the table and :attr:`~lunarmap.adjust.qc.QCResult.removed_image_observations`
cannot disagree.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from .ledger import Decision, Ledger

__all__ = ["STATUSES", "final_status"]

#: the final statuses of an observation
STATUSES = ("in", "removed", "down-weighted", "withdrawn", "set-aside")

_IMAGE_OUT = {"removed": "removed", "withdrawn": "withdrawn", "dropped": "set-aside"}


def final_status(ledger: Ledger) -> xr.Dataset:
    """One row per observation of the ledger's base problem: its final status and what decided it.

    Parameters
    ----------
    ledger : Ledger
        The ledger of a finished quality-control run.

    Returns
    -------
    xarray.Dataset
        Dimension ``observation`` (image observations first, in their base order, then weighted control
        points in ``priors`` order, then every row of every term); variables ``kind`` (``"image"``,
        ``"control"``, and for a term's rows :meth:`~.ledger.Ledger.term_kind`: ``"navigation"`` or
        ``"terrain"``, a reference DTM height), ``index`` (observation, control point or term row), ``term``
        (term of a term's row, -1 otherwise), ``image`` and ``point`` (-1 if none; a terrain row's point),
        ``status`` (one of :data:`STATUSES`), ``step`` and ``round`` of the deciding decision (``""`` /
        -1 for an observation nothing acted on), ``value`` (its test value: ``|w|`` of a w-test, a
        robust weight, Sequent's intersection sigma in the block's length unit; NaN if none),
        ``reason`` (the decision's group or why it was set aside). A terrain row whose point is out of the
        adjustment (:meth:`~.ledger.Ledger.term_rows_out`) is out with it, not tested: ``"withdrawn"`` or
        ``"set-aside"`` with its point's deciding step.
    """
    base = ledger.base
    o = base.obs
    active = ledger.active
    n = o.n
    status = np.where(active, "in", "set-aside").astype(object)
    step = np.full(n, "", dtype=object)
    rnd = np.full(n, -1, np.int64)
    value = np.full(n, np.nan)
    reason = np.full(n, "", dtype=object)
    # the last decision on each image observation and on each point decides (decisions are chronological)
    last_img: dict[int, Decision] = {}
    last_pt: dict[int, Decision] = {}
    term_last: dict[tuple[int, int], Decision] = {}     # (term, row)
    ctl_last: dict[int, Decision] = {}
    for d in ledger.decisions:
        if d.kind == "image":
            last_img[d.index] = d
        elif d.kind == "point" and d.action in ("dropped", "withdrawn"):
            last_pt[d.index] = d
        elif d.kind in ("navigation", "terrain") and d.term >= 0:
            term_last[(d.term, d.index)] = d
        elif d.kind == "control":
            ctl_last[d.index] = d
    for i in range(n):
        di = last_img.get(i)
        if active[i]:
            if di is not None and di.action == "reinstated":
                step[i], rnd[i], reason[i] = di.step, di.round, "given back"
            continue
        if di is not None and di.action in _IMAGE_OUT:
            status[i] = _IMAGE_OUT[di.action]
            step[i], rnd[i], value[i] = di.step, di.round, di.value
            reason[i] = di.group if di.action != "dropped" else "its point was left with fewer than 2 rays"
            continue
        dp = last_pt.get(int(o.pt_idx[i]))
        if dp is not None:
            status[i] = "withdrawn" if dp.action == "withdrawn" else "set-aside"
            step[i], rnd[i], value[i], reason[i] = dp.step, dp.round, dp.value, dp.group
        else:
            reason[i] = "out of the adjustment (no decision recorded)"
    if n:
        # a robust weight and a w-test are told apart by the step; |w| is what the report promises
        img = np.array([s == "baarda" for s in step]) & np.isfinite(value)
        value[img] = np.abs(value[img])
    kind = np.full(n, "image", dtype=object)
    index = np.arange(n, dtype=np.int64)
    term = np.full(n, -1, np.int64)
    image = o.cam_idx.astype(np.int64).copy()
    point = o.pt_idx.astype(np.int64).copy()
    rows: list[tuple] = []
    pri = base.priors
    if pri is not None:
        for k in np.flatnonzero(~pri.fixed):
            ctl_down = bool(ledger.weights.control_downweighted()[k])
            rows.append(("control", int(k), -1, -1, int(pri.idx[k]), "down-weighted" if ctl_down else "in",
                         ctl_last.get(int(k))))
    # rows of a term out with their point (a DTM height of a dropped point): the point's status and decision
    aside: list[tuple[int, str, Decision | None]] = []
    for t, fac in enumerate(ledger.weights.term_sigma):
        term_obj = ledger.terms[t]
        kind_t = ledger.term_kind(t)
        table = getattr(term_obj, "row_table", None)
        img_of = table()["image"] if table is not None else np.full(fac.size, -1)
        pt_of = np.asarray(term_obj.point_index, np.int64) if kind_t == "terrain" else np.full(fac.size, -1)
        if pt_of.ndim == 2:                  # an altimetry shot's triangle: its nearest point (first) names it
            pt_of = pt_of[:, 0]
        down = ledger.weights.term_downweighted(t)
        out = ledger.term_rows_out(t)
        for r in range(fac.size):
            if out[r]:
                dp = last_pt.get(int(pt_of[r]))
                aside.append((len(rows), "withdrawn" if dp is not None and dp.action == "withdrawn" else "set-aside",
                              dp))
            rows.append((kind_t, r, t, int(img_of[r]), int(pt_of[r]), "down-weighted" if down[r] else "in",
                         term_last.get((t, r))))
    if rows:
        kind = np.concatenate([kind, np.array([r[0] for r in rows], dtype=object)])
        index = np.concatenate([index, np.array([r[1] for r in rows], np.int64)])
        term = np.concatenate([term, np.array([r[2] for r in rows], np.int64)])
        image = np.concatenate([image, np.array([r[3] for r in rows], np.int64)])
        point = np.concatenate([point, np.array([r[4] for r in rows], np.int64)])
        st = np.array([r[5] for r in rows], dtype=object)
        ds = [r[6] if (r[6] is not None and (r[5] != "in" or r[6].action == "reinstated")) else None for r in rows]
        status = np.concatenate([status, st])
        step = np.concatenate([step, np.array([d.step if d is not None else "" for d in ds], dtype=object)])
        rnd = np.concatenate([rnd, np.array([d.round if d is not None else -1 for d in ds], np.int64)])
        value = np.concatenate([value, np.array([abs(d.value) if d is not None else np.nan for d in ds])])
        reason = np.concatenate([reason, np.array([("given back" if d.action == "reinstated" else
                                                    f"{d.action} ({d.group})" if d.action == "flagged" else d.group)
                                                   if d is not None else "" for d in ds], dtype=object)])
        for pos, st_k, dp in aside:
            at = n + pos
            status[at] = st_k
            if dp is None:
                step[at], rnd[at], value[at], reason[at] = "", -1, np.nan, "its point is out (no decision recorded)"
            else:
                step[at], rnd[at], value[at], reason[at] = dp.step, dp.round, dp.value, f"its point is out ({dp.group})"
    return xr.Dataset({"kind": ("observation", kind), "index": ("observation", index), "term": ("observation", term),
                       "image": ("observation", image), "point": ("observation", point),
                       "status": ("observation", status), "step": ("observation", step),
                       "round": ("observation", rnd), "value": ("observation", value),
                       "reason": ("observation", reason)},
                      coords={"observation": np.arange(kind.size)})

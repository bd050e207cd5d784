"""The run report: one self-contained HTML page (PNG plots embedded, and written beside it).

Sections: the block (images, pairs matched and skipped, tie points), the adjustment (sigma0, the tie
points' estimated variance factor, iterations, group statistics), footprints and tie-point coverage
on a map, image residuals per image and per group of points, check-point errors before and after
against the posterior sigma, and the stage timings. Plots are made with matplotlib's Agg backend
(no display needed).
"""

from __future__ import annotations

import base64
import html
import io
import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

_log = logging.getLogger(__name__)

__all__ = ["write_report", "qc_text", "verdict", "QC_COLUMNS", "CHECK_FRAME"]


def qc_text(summary: dict[str, Any], sigma0: bool = True) -> str:
    """One line on the run's quality control (``""`` if it had none): steps, observations removed, and
    (``sigma0``) the first and last adjustments' sigma0."""
    q = summary.get("qc")
    if not q:
        return ""
    by = ", ".join(f"{k} {v}" for k, v in q["removed_by_point_type"].items() if v)
    acted = ", ".join(f"{k}: {v}" for k, v in q["actions"].items()) or "nothing acted on"
    # robust first: the first adjustment is the robust one, its sigma0 not that of the blunders
    before = "in the robust adjustment" if q.get("first_adjustment") == "robust" else "before"
    text = (f"quality control ({' -> '.join(q['steps'])}): {q['image_observations_removed']} of "
            f"{q['image_observations']} image observations removed ({by or 'none'}; {acted})")
    if q.get("final_status"):
        text += "; final status: " + ", ".join(f"{k} {v}" for k, v in q["final_status"].items())
    if q.get("clean") is False:
        text += "; NOT A CLEAN BLOCK: " + "; ".join(q.get("flags", []))
    return text + (f"; sigma0 {q['sigma0_first']:.3f} {before}, {q['sigma0_last']:.3f} after" if sigma0 else "")


#: What the columns of the QC decisions table mean (the report prints it above the table).
QC_COLUMNS = {
    "step": "the QC step that decided (sequent: ray intersections; robust: robust weights; baarda: data snooping "
            "with w-tests)",
    "round": "adjustment round within the step (0: before any adjustment)",
    "kind": "what was acted on: an image observation (both coordinates of one ray), a navigation row, a "
            "control point's coordinates, a point",
    "image": "the image of the observation", "point": "the point's id",
    "coord": "the coordinate whose test failed (line or sample)",
    "w": "the test value: Baarda's w-test (normalised residual against sigma0), the robust step's weight, or "
         "Sequent's intersection misfit; beyond the limit (baarda_limit) the observation fails",
    "r": "redundancy number of the observation (0: fully determined by it, untestable; 1: fully checked by the "
         "others)",
    "action": "removed (weight 0), withdrawn (a point whose failing ray no test can single out, removed with all "
              "its rays), reinstated (given back: it fits once the error it was pulled by is gone), down-weighted "
              "or flagged (navigation and control observations)",
    "group": "the observation group the decision belongs to",
}

#: The check-point frame: components of every check-point error in the report, the demo and the README.
CHECK_FRAME = "along-track / cross-track / height (m; along-track = the images' mean ground track direction)"


def verdict(summary: dict[str, Any], residuals: xr.Dataset | None = None,
            qc_truth: dict[str, Any] | None = None, min_observations: int = 20) -> list[tuple[str, str]]:
    """Whether the adjustment is good, as (status, sentence) pairs; status ``"ok"``, ``"warn"`` or ``"info"``.

    Parameters
    ----------
    summary : dict
        The run's summary (``outputs/adjustment/summary.json`` with the run's additions).
    residuals : xarray.Dataset, optional
        ``outputs/adjustment/residuals.nc`` (observations per image).
    qc_truth : dict, optional
        Quality control against a simulation's truth (:func:`lunarmap.evaluate.qc_truth.qc_against_truth`).
    min_observations : int
        Images with fewer image observations left are named.

    Returns
    -------
    list of (str, str)
    """
    out: list[tuple[str, str]] = []
    s0 = float(summary.get("sigma0", np.nan))
    scale = float(summary.get("tie_sigma_scale", 1.0))
    scaled = f" (tie-point sigma scaled x{scale:.2f} by variance-component estimation)" if abs(scale - 1) > 1e-3 else ""
    if 0.8 <= s0 <= 1.25:
        out.append(("ok", f"sigma0 {s0:.3f}: the residuals agree with the observations' sigmas{scaled}, so the "
                          "posterior sigmas can be taken as they are."))
    else:
        out.append(("warn", f"sigma0 {s0:.3f}: the residuals are {s0:.2f} times what the sigmas say{scaled}; the "
                            "sigmas (and every posterior sigma) are too " + ("small" if s0 > 1 else "large") + "."))
    if not summary.get("converged", True):
        out.append(("warn", f"the adjustment did not converge: {summary.get('message', '')}"))
    z = summary.get("check_normalized_rms")
    if z is not None:
        after = np.asarray(summary["check_rms_after_m"], float)
        before = np.asarray(summary["check_rms_before_m"], float)
        a3, b3 = float(np.sqrt(np.sum(after ** 2))), float(np.sqrt(np.sum(before ** 2)))
        good = 0.5 <= float(z) <= 1.5
        out.append(("ok" if good else "warn",
                    f"check points: 3-D RMS {b3:.3f} m before, {a3:.3f} m after; errors / predicted sigma RMS "
                    f"{float(z):.2f} ({'the precision is as predicted' if good else 'the predicted sigmas are ' + ('too small' if z > 1 else 'too large')}; 1 = as predicted)."))
    else:
        out.append(("warn", "no check points: the accuracy is not checked against independent points (add check "
                            "points to [points])."))
    q = summary.get("qc")
    if q:
        n, m = int(q["image_observations_removed"]), int(q["image_observations"])
        text = f"quality control removed {n:,} of {m:,} image observations ({100.0 * n / max(m, 1):.1f} %)"
        if qc_truth:
            t = qc_truth
            prec = t["removed_wrong"] / t["removed"] if t["removed"] else float("nan")
            rec = t["removed_wrong"] / t["wrong"] if t["wrong"] else float("nan")
            text += (f"; against the simulation's truth {t['removed_wrong']} of the {t['removed']:,} removed tie "
                     f"observations were true mismatches (> {t['limit_px']:g} px from the true conjugate: precision "
                     f"{prec:.2f}), of {t['wrong']} in the block (recall "
                     + (f"{rec:.2f}" if t["wrong"] else "n/a: the block has none, so every removal was of a good "
                        "observation") + f"); true error of the removed median {t['removed_median_px']:.2f} px, of "
                     f"the kept {t['kept_median_px']:.2f} px")
            if t.get("good"):
                text += (f"; {t.get('removed_good', t['removed'] - t['removed_wrong']):,} good observations removed "
                         f"= {100.0 * t.get('removed_good', 0) / t['good']:.1f} % of the {t['good']:,} good")
            out.append(("warn" if t["removed"] and prec < 0.5 else "ok", text + "."))
        else:
            out.append(("info", text + " (how many were wrong is known only where the truth is, e.g. the example)."))
        if q.get("clean") is False:
            out.append(("warn", "quality control ended without a clean block: " + "; ".join(q.get("flags", []))))
        lost = q.get("check_points_without_rays") or []
        if lost:
            out.append(("warn", f"{len(lost)} check point(s) lost their rays to quality control and are not scored: "
                                + ", ".join(lost[:8])))
    if residuals is not None:
        names = list(summary.get("images", []))
        kept = ~residuals["qc_removed"].values.astype(bool) if "qc_removed" in residuals else \
            np.ones(residuals.sizes["obs"], bool)
        per = np.bincount(residuals["image"].values[kept], minlength=len(names))
        few = [(names[i], int(per[i])) for i in range(len(names)) if per[i] < min_observations]
        if few:
            out.append(("warn", "images with fewer than %d image observations left: " % min_observations
                        + ", ".join(f"{n} ({k})" for n, k in few) + "; their orientation rests on the navigation."))
        elif names:
            i = int(np.argmin(per))
            out.append(("ok", f"every image keeps {min_observations} or more image observations (fewest: "
                              f"{names[i]}, {int(per[i])})."))
    return out


def _figure(draw: Any, width: float = 6.4, height: float = 4.2) -> bytes:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(width, height), dpi=100)
    try:
        draw(ax)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
    finally:
        plt.close(fig)
    return buf.getvalue()


def _footprints(result: Any) -> dict[str, np.ndarray]:
    from ..camera.factory import camera_from_isd_file
    from ..camera.geodesy import xyz_to_lonlat_height

    out = {}
    for p in sorted(Path(result.outputs["isd"]).glob("*.json")):
        cam = camera_from_isd_file(p)
        t = np.linspace(0.0, 1.0, 9)
        edge = np.concatenate([np.column_stack([0 * t, t]), np.column_stack([t, 0 * t + 1]),
                               np.column_stack([0 * t + 1, 1 - t]), np.column_stack([1 - t, 0 * t])])
        g = cam.image_to_ground(edge[:, 0] * cam.n_lines, edge[:, 1] * cam.n_samples, height=0.0, on_miss="nan")
        lon, lat, _ = xyz_to_lonlat_height(g)
        out[p.stem] = np.column_stack([lon, lat])
    return out


#: Per-step records -> the graph stage they belong to (for showing reused stages as reused).
_STAGE_OF_STEP = {"isd": "image", "rpc": "image", "pyramid": "image", "detect": "image", "footprint": "image",
                  "match": "match", "tiepoints": "tiepoints", "adjust": "adjust", "kernels": "kernels",
                  "rpc_adjusted": "rpc_adjusted"}

_SORT_JS = """<script>
function sortTable(th) {
  const table = th.closest('table'), body = table.tBodies[0], col = th.cellIndex;
  const asc = th.dataset.order !== 'asc'; th.dataset.order = asc ? 'asc' : 'desc';
  const key = td => { const t = td.textContent.trim(), x = parseFloat(t); return isNaN(x) ? t : x; };
  const rows = Array.from(body.rows);
  rows.sort((a, b) => { const x = key(a.cells[col]), y = key(b.cells[col]);
    return (x < y ? -1 : x > y ? 1 : 0) * (asc ? 1 : -1); });
  rows.forEach(r => body.appendChild(r));
}
</script>"""


def _label_positions(outlines: list[np.ndarray], min_gap: float) -> np.ndarray:
    """One label position per outline, on the outline, chosen greedily far from the labels placed before
    (footprints of a block overlap: their centres crowd, their outlines do not); ``min_gap`` weighs a
    candidate's distance to the other outlines' labels against staying near the outline's corners."""
    placed: list[np.ndarray] = []
    for poly in outlines:
        ok = poly[np.all(np.isfinite(poly), axis=1)]
        if not ok.size:
            placed.append(np.array([np.nan, np.nan]))
            continue
        # candidates: the outline's vertices and the midpoints between them
        cand = np.concatenate([ok, 0.5 * (ok + np.roll(ok, -1, axis=0))])
        if placed and np.isfinite(np.array(placed)).any():
            p = np.array([q for q in placed if np.all(np.isfinite(q))])
            d = np.min(np.hypot(cand[:, None, 0] - p[None, :, 0], cand[:, None, 1] - p[None, :, 1]), axis=1)
            best = int(np.argmax(np.minimum(d, 3 * min_gap)))
        else:
            best = 0
        placed.append(cand[best])
    return np.array(placed)


def _table(header: list[tuple[str, str]], rows: list[list[Any]], sortable: bool = False, cls: str = "") -> str:
    """An HTML table; ``header`` = (title, tooltip) pairs."""
    onclick = ' onclick="sortTable(this)"' if sortable else ""
    head = "".join(f'<th title="{html.escape(tip)}"{onclick}>{html.escape(t)}</th>' for t, tip in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def write_report(result: Any, qc_truth: dict[str, Any] | None = None) -> Path:
    """Write ``<run>/report/index.html`` (and its PNGs).

    Parameters
    ----------
    result : lunarmap.workflows.RunResult
    qc_truth : dict, optional
        Quality control against a simulation's truth (:func:`lunarmap.evaluate.qc_truth.qc_against_truth`), for the
        verdict.

    Returns
    -------
    pathlib.Path
        The HTML page.
    """
    import matplotlib.ticker as mticker

    folder = result.folder / "report"
    folder.mkdir(parents=True, exist_ok=True)
    adj = Path(result.outputs["adjustment"])
    summary = result.summary
    with xr.open_dataset(adj / "points.nc") as ds:
        pts = ds.load()
    with xr.open_dataset(adj / "residuals.nc") as ds:
        res = ds.load()
    check = None
    if (adj / "check_points.nc").exists():
        with xr.open_dataset(adj / "check_points.nc") as ds:
            check = ds.load()
    t_last = [time.perf_counter()]

    def step(what: str) -> None:      # a progress line at most every 2 s
        if time.perf_counter() - t_last[0] > 2.0:
            t_last[0] = time.perf_counter()
            _log.info("report: %s", what)

    step("footprints of the images")
    feet = _footprints(result)
    images: list[tuple[str, str, bytes]] = []
    names = list(summary.get("images", []))

    def degrees(ax: Any) -> None:
        # plain degrees (no offset, no "+5.7e1"), with as many decimals as the ticks' spacing needs
        for axis, lim in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            axis.set_major_locator(mticker.MaxNLocator(5))
            step = abs(lim[1] - lim[0]) / 5 or 1.0
            dec = int(max(0, np.ceil(-np.log10(step))))
            axis.set_major_formatter(mticker.FuncFormatter(lambda v, _, d=dec: f"{v:.{d}f}\N{DEGREE SIGN}"))

    def map_plot(ax: Any) -> None:
        import matplotlib.pyplot as plt

        colours = plt.get_cmap("tab20")
        outlines = []
        for k, (name, poly) in enumerate(feet.items()):
            ok = np.all(np.isfinite(poly), axis=1)
            ax.plot(poly[ok, 0], poly[ok, 1], lw=1.2, color=colours(k % 20), label=f"{k + 1}: {name}")
            outlines.append(poly)
        kind = pts["point_type"].values.astype(str)
        for ptype, c, m, sz in (("tie", "0.55", ".", 3), ("control", "tab:red", "^", 30), ("check", "tab:blue", "o", 22)):
            sel = kind == ptype
            if sel.any():
                ax.scatter(pts["lon"].values[sel], pts["lat"].values[sel], s=sz, c=c, marker=m, zorder=3,
                           label=f"{ptype} points ({int(sel.sum())})", edgecolors="white" if ptype != "tie" else "none",
                           linewidths=0.5)
        if outlines:
            allp = np.concatenate(outlines)
            span = max(float(np.nanmax(allp[:, 0]) - np.nanmin(allp[:, 0])),
                       float(np.nanmax(allp[:, 1]) - np.nanmin(allp[:, 1])), 1e-9)
            for k, xy in enumerate(_label_positions(outlines, 0.05 * span)):
                if np.all(np.isfinite(xy)):
                    ax.text(xy[0], xy[1], str(k + 1), fontsize=8, ha="center", va="center", color=colours(k % 20),
                            fontweight="bold", zorder=4,
                            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": colours(k % 20), "lw": 0.8})
        ax.set_xlabel("longitude (east)")
        ax.set_ylabel("latitude (north)")
        degrees(ax)
        ax.set_aspect(1.0 / max(np.cos(np.radians(np.nanmean(pts["lat"].values))), 0.05))
        ax.set_title("footprints at height 0 (numbered as in the legend) and adjusted points")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    step("footprint map")
    images.append(("map", "Footprints and points", _figure(map_plot, 9.4, 6.2)))
    step("residual and check-point plots")

    v = res["residual"].values
    img = res["image"].values
    kept = ~res["qc_removed"].values.astype(bool) if "qc_removed" in res else np.ones(img.size, bool)

    def resid_plot(ax: Any) -> None:
        rms = np.array([np.sqrt(np.mean(v[(img == i) & kept] ** 2, axis=0)) if np.any((img == i) & kept)
                        else [np.nan, np.nan] for i in range(len(names))])
        x = np.arange(len(names))
        ax.bar(x - 0.2, rms[:, 0], 0.4, label="line")
        ax.bar(x + 0.2, rms[:, 1], 0.4, label="sample")
        ax.set_xticks(x, names, rotation=60, fontsize=7, ha="right")
        ax.set_ylabel("residual RMS (px)")
        ax.set_title("image residuals per image (observations kept by quality control)")
        ax.legend(fontsize=7)
    images.append(("residuals", "Residuals per image", _figure(resid_plot)))

    if check is not None:
        def check_plot(ax: Any) -> None:
            b = np.sqrt(np.mean(check["error_before"].values ** 2, axis=0))
            a = np.sqrt(np.mean(check["error_after"].values ** 2, axis=0))
            sg = np.sqrt(np.mean(check["sigma_after"].values ** 2, axis=0))
            x = np.arange(3)
            ax.bar(x - 0.27, b, 0.27, label="before (navigation)")
            ax.bar(x, a, 0.27, label="after (adjusted)")
            ax.bar(x + 0.27, sg, 0.27, label="posterior sigma")
            ax.set_yscale("log")
            ax.set_xticks(x, ["along-track", "cross-track", "height"])
            ax.set_ylabel("check-point RMS (m)")
            ax.set_title("check points against their reference coordinates")
            ax.legend(fontsize=7)
        images.append(("check_points", "Check points before and after", _figure(check_plot)))

    computed_stage: dict[str, bool] = {}
    for d in result.done:
        st = _STAGE_OF_STEP.get(d.step, d.step)
        computed_stage[st] = computed_stage.get(st, False) or bool(d.computed)

    def timing_plot(ax: Any) -> None:
        st = result.stage_seconds
        stages = list(st)
        ends = np.array([st[k] for k in stages])
        starts = np.concatenate([[0.0], ends[:-1]])
        for k, name in enumerate(stages):
            if computed_stage.get(name, True):
                ax.barh(k, ends[k] - starts[k], left=starts[k], color="tab:blue")
            else:
                ax.barh(k, 0.0, left=starts[k])
                # x in axes fractions: the note stays inside the plot whatever the time scale
                ax.text(0.01, k, "reused from the store (not computed in this run)", va="center", fontsize=8,
                        color="0.35", transform=ax.get_yaxis_transform())
        ax.set_yticks(range(len(stages)), stages)
        ax.invert_yaxis()
        ax.set_xlabel("wall time since the start of the graph (s)")
        ax.set_title("stages computed in this run (a stage ends with its last task)")
    if result.stage_seconds:
        images.append(("timings", "Stage timings", _figure(timing_plot, 6.4, 3.2)))

    step("tables")
    for name, _, png in images:
        (folder / f"{name}.png").write_bytes(png)
    ptype = res["point_type"].values.astype(str)
    groups = []
    for k in ("tie", "control", "check"):
        m = (ptype == k) & kept
        if m.any():
            z = res["normalized"].values[m]
            groups.append((k, int(m.sum()), f"{float(np.sqrt(np.mean(v[m] ** 2))):.3f}",
                           f"{float(np.sqrt(np.mean(z ** 2))):.3f}"))
    counts = result.counts()

    def fmt(val: Any) -> str:
        if val is None:
            return "none"
        if isinstance(val, (list, tuple)):
            return " / ".join(f"{x:.3f}" for x in val)
        if isinstance(val, float):
            return f"{val:.4g}"
        return str(val)

    has_check = "check_rms_after_m" in summary
    rows = [[k, fmt(val)] for k, val in [
        ("configuration", result.config.source), ("images", len(names)),
        ("pairs whose footprints cannot meet (not matched)", summary.get("pairs_apart", 0)),
        ("pairs matched", summary.get("pairs_candidate", 0) - len(summary.get("skipped_pairs", []))),
        ("pairs skipped (overlap below min_overlap)", len(summary.get("skipped_pairs", []))),
        ("points", summary.get("n_points")), ("image observations", summary.get("n_observations")),
        ("sigma0", f"{summary.get('sigma0', float('nan')):.4f}"),
        ("tie-point sigma scale (variance components)", f"{summary.get('tie_sigma_scale', float('nan')):.3f}"),
        ("iterations", summary.get("iterations")), ("converged", summary.get("converged")),
    ] + ([
        (f"check points RMS before, {CHECK_FRAME}", summary.get("check_rms_before_m")),
        ("check points RMS after (m)", summary.get("check_rms_after_m")),
        ("check points posterior sigma RMS (m)", summary.get("check_sigma_after_m")),
        ("check points errors / posterior sigma (RMS)", summary.get("check_normalized_rms")),
    ] if has_check else [("check points", "none in this run")]) + [
        ("steps computed / reused", ", ".join(f"{st} {c}/{r}" for st, (c, r) in counts.items())),
    ]]
    figs = {name: (title, png) for name, title, png in images}

    def fig(name: str) -> str:
        if name not in figs:
            return ""
        title, png = figs[name]
        return (f'<h2 id="{name}">{html.escape(title)}</h2><img alt="{name}" src="data:image/png;base64,'
                f'{base64.b64encode(png).decode()}">')

    marks = {"ok": ("&#10004;", "ok"), "warn": ("&#9888;", "warn"), "info": ("&#8505;", "info")}
    judged = verdict(summary, res, qc_truth)
    verdict_html = "<ul class=\"verdict\">" + "".join(
        f'<li class="{marks[st][1]}"><span class="mark">{marks[st][0]}</span> {html.escape(text)}</li>'
        for st, text in judged) + "</ul>"
    good = all(st != "warn" for st, _ in judged)
    headline = ("The adjustment is consistent: every check below passed." if good else
                "Look at the points marked &#9888; before using the results.")

    check_section = ""
    if check is not None:
        ids = [str(x) for x in check["check"].values]
        eb, ea, sa = (check[k].values for k in ("error_before", "error_after", "sigma_after"))
        zz = check["normalized_after"].values
        crow = [[ids[i], *(f"{x:.3f}" for x in eb[i]), *(f"{x:.3f}" for x in ea[i]), *(f"{x:.3f}" for x in sa[i]),
                 f"{float(np.sqrt(np.mean(zz[i] ** 2))):.2f}"] for i in range(len(ids))]
        comp = ("along", "cross", "height")
        head = ([("point", "check point id")] + [(f"before {c}", f"error of the navigation's point, {c} (m)")
                                                 for c in comp]
                + [(f"after {c}", f"error of the adjusted point, {c} (m)") for c in comp]
                + [(f"sigma {c}", f"posterior sigma, {c} (m)") for c in comp]
                + [("|error / sigma|", "RMS over the three components of error / sigma (1 = as predicted)")])
        lost = (summary.get("qc") or {}).get("check_points_without_rays") or []
        check_section = (f"<h2 id=\"check_table\">Check points, one by one</h2><p>Errors against the reference "
                         f"coordinates, {html.escape(CHECK_FRAME)}; click a column to sort.</p>"
                         + _table(head, crow, sortable=True, cls="num")
                         + (f"<p>Not scored (fewer than 2 rays after quality control): {html.escape(', '.join(lost))}"
                            "</p>" if lost else ""))
    qc_section = ""
    if summary.get("qc") and (adj / "qc.nc").exists():
        with xr.open_dataset(adj / "qc.nc") as ds:
            dec = ds[[k for k in ("step", "round", "kind", "index", "image", "point", "component", "value",
                                  "redundancy", "action", "group") if k in ds]].load() if "decision" in ds.dims \
                else None
        pid = {}
        if "point_id" in res:
            pid = dict(zip(res["point"].values.tolist(), res["point_id"].values.astype(str).tolist()))
        qrows = []
        step("QC decisions table")
        if dec is not None:
            for kd in range(dec.sizes["decision"]):
                image = int(dec["image"].values[kd])
                point = int(dec["point"].values[kd])
                component = int(dec["component"].values[kd])
                val, red = float(dec["value"].values[kd]), float(dec["redundancy"].values[kd])
                qrows.append([str(dec["step"].values[kd]), int(dec["round"].values[kd]), str(dec["kind"].values[kd]),
                              names[image] if 0 <= image < len(names) else "",
                              pid.get(point, str(point)) if point >= 0 else "",
                              {0: "line", 1: "sample"}.get(component, ""), f"{val:.2f}" if np.isfinite(val) else "",
                              f"{red:.3f}" if np.isfinite(red) else "", str(dec["action"].values[kd]),
                              str(dec["group"].values[kd])])
        cols = [("step", QC_COLUMNS["step"]), ("round", QC_COLUMNS["round"]), ("kind", QC_COLUMNS["kind"]),
                ("image", QC_COLUMNS["image"]), ("point", QC_COLUMNS["point"]), ("coord", QC_COLUMNS["coord"]),
                ("w", QC_COLUMNS["w"]), ("r", QC_COLUMNS["r"]), ("action", QC_COLUMNS["action"]),
                ("group", QC_COLUMNS["group"])]
        explain = "".join(f"<dt>{html.escape(c)}</dt><dd>{html.escape(t)}</dd>" for c, t in cols)
        qc_section = (f"<h2 id=\"qc\">Quality control</h2><p>{html.escape(qc_text(summary))}.</p>"
                      f"<p>{len(qrows):,} decisions; click a column to sort (full text in "
                      f"<code>outputs/adjustment/qc.txt</code>, every field in <code>qc.nc</code>).</p>"
                      f"<details open><summary>what the columns mean</summary><dl>{explain}</dl></details>"
                      f"<div class=\"scroll\">{_table(cols, qrows, sortable=True, cls='qc num')}</div>")
    terrain_section = ""
    if summary.get("terrain"):
        def num(v: Any, f: str = ".3f") -> str:
            return format(v, f) if isinstance(v, (int, float)) and np.isfinite(v) else ""

        trows = [[name, t["observations"], t["outside_dtm"], num(t["rms_residual_m"]), num(t["sigma_apriori_m"]),
                  num(t["sigma_estimated_m"]) if t["variance_component_estimated"] else "not estimated",
                  num(t["sigma_estimated_sd_m"]) if t["variance_component_estimated"] else "",
                  num(t["variance_component"], ".4g"), t["removed"]]
                 for name, t in summary["terrain"].items()]
        thead = [("DTM", "name of the [[adjust.terrain.dtm]] table"),
                 ("observations", "tie point heights observed by the DTM"),
                 ("outside", "tie points outside the DTM or on its holes (no observation)"),
                 ("RMS residual (m)", "point height minus DTM height, over the rows in the final adjustment"),
                 ("a-priori sigma (m)", "sigma of the configuration"),
                 ("estimated sigma (m)", "a-priori sigma x the square root of the group's variance component"),
                 ("± (m)", "standard deviation of the estimated sigma"),
                 ("variance component", "factor on the a-priori variance (1: the a-priori sigma was right)"),
                 ("removed", "rows down-weighted by the w-tests, or whose point quality control took out")]
        terrain_section = ("<h2 id=\"terrain\">Reference DTMs</h2><p>DTM heights observing the tie points "
                           "(one row per observation in <code>outputs/adjustment/terrain_residuals.nc</code>).</p>"
                           + _table(thead, trows, cls="num"))
    if summary.get("altimetry"):
        def fnum(v: Any, f: str = ".3f") -> str:
            return format(v, f) if isinstance(v, (int, float)) and np.isfinite(v) else ""

        arows = [[name, track, tr["shots"], fnum(tr["offset_m"]), fnum(tr["offset_sigma_m"])]
                 for name, a in summary["altimetry"].items() for track, tr in a["tracks"].items()]
        ahead = [("altimeter", "name of the [[adjust.terrain.altimetry]] table"), ("track", "track identifier"),
                 ("shots", "shots of the track inside the tie points' triangulation"),
                 ("offset (m)", "estimated radial offset of the track"), ("± (m)", "its posterior sigma")]
        alt_groups = "; ".join(f"{html.escape(name)}: {a['shots']:,} shots ({a['outside_tie_points']:,} outside "
                               f"the tie points), residual RMS {fnum(a['rms_residual_m'])} m, sigma scale {fnum(a['sigma_scale'])}"
                               for name, a in summary["altimetry"].items())
        terrain_section += ("<h2 id=\"altimetry\">Laser altimetry</h2><p>Shots observing the tie points' surface; "
                            f"{alt_groups}.</p>" + _table(ahead, arows, cls="num"))
    terrain_section += _groups_section(summary) + _jitter_section(summary)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>lunarmap run report</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}}
td,th{{padding:2px 10px;text-align:left}} th{{background:#e4e8ee;cursor:pointer;position:sticky;top:0}}
table{{border-collapse:collapse}} tr:nth-child(even){{background:#f4f4f4}} img{{max-width:100%}}
table.num td{{font-variant-numeric:tabular-nums}} div.scroll{{max-height:32em;overflow:auto;border:1px solid #ccc}}
ul.verdict{{list-style:none;padding-left:0;font-size:1.05em}} ul.verdict li{{margin:.35em 0;padding:.35em .6em;border-radius:4px}}
li.ok{{background:#e7f5e9}} li.warn{{background:#fff1d6}} li.info{{background:#e8f0fb}} .mark{{font-weight:bold}}
dl{{font-size:.9em}} dt{{font-weight:bold;float:left;width:5em}} dd{{margin-left:6em;margin-bottom:.3em}}</style>
{_SORT_JS}</head>
<body><h1>lunarmap run: {html.escape(result.config.name or str(result.config.source))}</h1>
<h2 id="verdict">Verdict</h2><p><b>{headline}</b></p>{verdict_html}
<h2 id="summary">Summary</h2>
{_table([("quantity", ""), ("value", "")], rows)}
<h2>Image residuals per group of points</h2>
{_table([("group", "point type"), ("observations", "image observations kept"), ("RMS (px)", "residual RMS"),
         ("normalised RMS", "RMS of residual / sigma")], [list(g) for g in groups])}
{fig("map")}{fig("residuals")}{fig("check_points")}
{check_section}
{terrain_section}
{qc_section}
{fig("timings")}
<h2>Skipped pairs</h2><pre>{html.escape(chr(10).join(summary.get("skipped_pairs", [])) or "none")}</pre>
<h2>Summary (JSON)</h2><pre>{html.escape(json.dumps(summary, indent=1))}</pre>
</body></html>
"""
    from ..atomic import atomic_write

    return atomic_write(folder / "index.html", lambda tmp: tmp.write_text(page, encoding="utf-8"))


def _groups_section(summary: dict[str, Any]) -> str:
    """Every observation group of the final adjustment: observations and normalised residual RMS."""
    g = summary.get("groups") or {}
    if len(g) < 2:
        return ""
    rows = [[name, int(n), f"{float(np.sqrt(q / n)):.3f}" if n else ""] for name, (q, n) in g.items()]
    head = [("group", "image observations, control points, and each camera-level term (navigation, altimetry, "
                      "jitter smoothness)"), ("observations", "scalar observations"),
            ("normalised RMS", "sqrt(v'Pv / n): RMS of residual / a-priori sigma (1 if the sigmas are right; "
                               "below 1 for groups with little redundancy)")]
    return ("<h2 id=\"groups\">Residuals per observation group</h2>" + _table(head, rows, cls="num"))


def _jitter_section(summary: dict[str, Any]) -> str:
    """The adjusted jitter splines (summary ``jitter``): per image and axis, RMS, sigma and spectrum peak; a
    figure of the amplitude spectra (with the truth's and the error's when a simulation added them)."""
    jit = summary.get("jitter") or {}
    if not jit:
        return ""
    rows = []
    for name, r in jit.items():
        for ax in range(3):
            row = [name, r["axes"][ax], f"{1e6 * r['rms_rad'][ax]:.3f}", f"{1e6 * r['sigma_rms_rad'][ax]:.3f}",
                   f"{r['peak_hz'][ax]:.2f}", f"{1e6 * r['peak_amplitude_rad'][ax]:.3f}"]
            if "truth_rms_rad" in r:
                row += [f"{1e6 * r['truth_rms_rad'][ax]:.3f}", f"{r['truth_peak_hz'][ax]:.2f}",
                        f"{1e6 * r['truth_peak_amplitude_rad'][ax]:.3f}", f"{1e6 * r['error_rms_rad'][ax]:.3f}"]
            rows.append(row)
    head = [("image", ""), ("axis", "sensor frame"), ("RMS (urad)", "adjusted spline correction over the lines"),
            ("sigma RMS (urad)", "its posterior sigma, RMS over the lines"),
            ("peak (Hz)", "frequency of the largest amplitude of its spectrum"),
            ("peak amplitude (urad)", "one-sided amplitude spectrum, mean removed")]
    if any("truth_rms_rad" in r for r in jit.values()):
        head += [("truth RMS (urad)", "the simulation's jitter, high-passed by the correction polynomial"),
                 ("truth peak (Hz)", ""), ("truth peak (urad)", ""),
                 ("error RMS (urad)", "truth minus adjusted spline (after); the truth is the error before")]

    def draw(axs: Any) -> None:
        for name, r in jit.items():
            f = np.asarray(r["frequency_hz"])
            for ax in range(2):          # roll and pitch: the axes tie points see (yaw moves the edges only)
                line, = axs.plot(f, 1e6 * np.asarray(r["amplitude_rad"][ax]), lw=1.0,
                                 label=f"{name} {r['axes'][ax]} adjusted")
                if "truth_amplitude_rad" in r:
                    axs.plot(f, 1e6 * np.asarray(r["truth_amplitude_rad"][ax]), lw=0.8, ls="--", color=line.get_color())
                    axs.plot(f, 1e6 * np.asarray(r["error_amplitude_rad"][ax]), lw=0.8, ls=":", color=line.get_color())
        axs.set_xlabel("frequency (Hz)")
        axs.set_ylabel("amplitude (urad)")
        axs.set_title("jitter spectra: adjusted (solid), truth before (dashed), error after (dotted)"
                      if any("truth_amplitude_rad" in r for r in jit.values()) else "adjusted jitter spectra")
        axs.legend(fontsize=6, ncol=2)

    png = _figure(draw, 7.0, 4.2)
    return ("<h2 id=\"jitter\">Line-scan jitter</h2><p>The adjusted attitude splines ([adjust.jitter]) per image and "
            "sensor axis; the spectra in <code>summary.json</code> (<code>jitter</code>).</p>"
            + _table(head, rows, cls="num")
            + f'<img alt="jitter spectra" src="data:image/png;base64,{base64.b64encode(png).decode()}">')

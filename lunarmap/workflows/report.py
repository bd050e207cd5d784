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
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

__all__ = ["write_report", "qc_text"]


def qc_text(summary: dict[str, Any]) -> str:
    """One line on the run's quality control (``""`` if it had none): steps, observations removed, sigma0."""
    q = summary.get("qc")
    if not q:
        return ""
    by = ", ".join(f"{k} {v}" for k, v in q["removed_by_point_type"].items() if v)
    acted = ", ".join(f"{k}: {v}" for k, v in q["actions"].items()) or "nothing acted on"
    # robust first: the first adjustment is the robust one, its sigma0 not that of the blunders
    before = "in the robust adjustment" if q.get("first_adjustment") == "robust" else "before"
    return (f"quality control ({' -> '.join(q['steps'])}): {q['image_observations_removed']} of "
            f"{q['image_observations']} image observations removed ({by or 'none'}; {acted}); sigma0 "
            f"{q['sigma0_first']:.3f} {before}, {q['sigma0_last']:.3f} after")


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


def write_report(result: Any) -> Path:
    """Write ``<run>/report/index.html`` (and its PNGs); returns the HTML path."""
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
    feet = _footprints(result)
    images: list[tuple[str, str, bytes]] = []

    def map_plot(ax: Any) -> None:
        for name, poly in feet.items():
            ax.plot(poly[:, 0], poly[:, 1], lw=1)
            ax.annotate(name, poly[:, :2].mean(axis=0), fontsize=6, ha="center")
        kind = pts["point_type"].values.astype(str)
        for k, c in (("tie", "0.5"), ("control", "tab:red"), ("check", "tab:blue")):
            m = kind == k
            ax.scatter(pts["lon"].values[m], pts["lat"].values[m], s=3 if k == "tie" else 18, c=c, label=k,
                       marker="." if k == "tie" else "^")
        ax.set_xlabel("longitude (deg E)")
        ax.set_ylabel("latitude (deg N)")
        ax.set_title("footprints (height 0) and adjusted points")
        ax.legend(fontsize=7)
    images.append(("map", "Footprints and tie-point coverage", _figure(map_plot, 6.4, 5.6)))

    names = list(summary.get("images", []))
    v = res["residual"].values
    img = res["image"].values

    def resid_plot(ax: Any) -> None:
        rms = np.array([np.sqrt(np.mean(v[img == i] ** 2, axis=0)) if np.any(img == i) else [np.nan, np.nan]
                        for i in range(len(names))])
        x = np.arange(len(names))
        ax.bar(x - 0.2, rms[:, 0], 0.4, label="line")
        ax.bar(x + 0.2, rms[:, 1], 0.4, label="sample")
        ax.set_xticks(x, names, rotation=60, fontsize=7, ha="right")
        ax.set_ylabel("residual RMS (px)")
        ax.set_title("image residuals per image")
        ax.legend(fontsize=7)
    images.append(("residuals", "Residuals per image", _figure(resid_plot)))

    if check is not None:
        def check_plot(ax: Any) -> None:
            b = np.sqrt(np.mean(check["error_before"].values ** 2, axis=0))
            a = np.sqrt(np.mean(check["error_after"].values ** 2, axis=0))
            s = np.sqrt(np.mean(check["sigma_after"].values ** 2, axis=0))
            x = np.arange(3)
            ax.bar(x - 0.27, b, 0.27, label="before (navigation)")
            ax.bar(x, a, 0.27, label="after (adjusted)")
            ax.bar(x + 0.27, s, 0.27, label="posterior sigma")
            ax.set_yscale("log")
            ax.set_xticks(x, ["along-track", "cross-track", "height"])
            ax.set_ylabel("check-point RMS (m)")
            ax.set_title("check points against their reference coordinates")
            ax.legend(fontsize=7)
        images.append(("check_points", "Check points before and after", _figure(check_plot)))

    def timing_plot(ax: Any) -> None:
        st = result.stage_seconds
        stages = list(st)
        ends = np.array([st[s] for s in stages])
        starts = np.concatenate([[0.0], ends[:-1]])
        ax.barh(stages, ends - starts, left=starts)
        ax.invert_yaxis()
        ax.set_xlabel("wall time since the start of the graph (s)")
        ax.set_title("stages (a stage ends with its last task)")
    if result.stage_seconds:
        images.append(("timings", "Stage timings", _figure(timing_plot, 6.4, 3.2)))

    for name, _, png in images:
        (folder / f"{name}.png").write_bytes(png)
    ptype = res["point_type"].values.astype(str)
    kept = ~res["qc_removed"].values.astype(bool) if "qc_removed" in res else np.ones(ptype.size, bool)
    groups = []
    for k in ("tie", "control", "check"):
        m = (ptype == k) & kept
        if m.any():
            z = res["normalized"].values[m]
            groups.append((k, int(m.sum()), float(np.sqrt(np.mean(v[m] ** 2))), float(np.sqrt(np.mean(z ** 2)))))
    counts = result.counts()

    def fmt(v: Any) -> str:
        if isinstance(v, (list, tuple)):
            return " / ".join(f"{x:.3f}" for x in v)
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(fmt(val))}</td></tr>" for k, val in [
        ("configuration", result.config.source), ("images", len(names)),
        ("pairs whose footprints cannot meet (not matched)", summary.get("pairs_apart", 0)),
        ("pairs matched", summary.get("pairs_candidate", 0) - len(summary.get("skipped_pairs", []))),
        ("pairs skipped (overlap below min_overlap)", len(summary.get("skipped_pairs", []))),
        ("points", summary.get("n_points")), ("image observations", summary.get("n_observations")),
        ("sigma0", f"{summary.get('sigma0', float('nan')):.4f}"),
        ("tie-point sigma scale (variance components)", f"{summary.get('tie_sigma_scale', float('nan')):.3f}"),
        ("iterations", summary.get("iterations")), ("converged", summary.get("converged")),
        ("check points RMS after, along/cross/height (m)", summary.get("check_rms_after_m")),
        ("check points RMS before (m)", summary.get("check_rms_before_m")),
        ("check points errors / posterior sigma (RMS)", summary.get("check_normalized_rms")),
        ("steps computed / reused", ", ".join(f"{s} {c}/{r}" for s, (c, r) in counts.items())),
    ])
    grow = "".join(f"<tr><td>{k}</td><td>{n}</td><td>{r:.3f}</td><td>{z:.3f}</td></tr>" for k, n, r, z in groups)
    qc_section = ""
    if summary.get("qc"):
        table = (adj / "qc.txt").read_text() if (adj / "qc.txt").exists() else ""
        lines = table.splitlines()
        if len(lines) > 80:
            lines = lines[:80] + [f"... ({len(lines) - 80} more lines in outputs/adjustment/qc.txt; all decisions "
                                  "in outputs/adjustment/qc.nc)"]
        qc_section = (f"<h2>Quality control</h2><p>{html.escape(qc_text(summary))}</p>"
                      f"<pre>{html.escape(chr(10).join(lines))}</pre>")
    figs = "".join(f'<h2>{html.escape(title)}</h2><img alt="{name}" src="data:image/png;base64,'
                   f'{base64.b64encode(png).decode()}">' for name, title, png in images)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>lunarmap run report</title>
<style>body{{font-family:sans-serif;max-width:980px;margin:2em auto}} td,th{{padding:2px 10px;text-align:left}}
table{{border-collapse:collapse}} tr:nth-child(even){{background:#f2f2f2}} img{{max-width:100%}}</style></head>
<body><h1>lunarmap run: {html.escape(result.config.name or str(result.config.source))}</h1>
<table>{rows}</table>
<h2>Image residuals per group of points</h2>
<table><tr><th>group</th><th>observations</th><th>RMS (px)</th><th>normalised RMS</th></tr>{grow}</table>
{figs}
{qc_section}
<h2>Skipped pairs</h2><pre>{html.escape(chr(10).join(summary.get("skipped_pairs", [])) or "none")}</pre>
<h2>Summary (JSON)</h2><pre>{html.escape(json.dumps(summary, indent=1))}</pre>
</body></html>
"""
    from ..atomic import atomic_write

    return atomic_write(folder / "index.html", lambda tmp: tmp.write_text(page, encoding="utf-8"))

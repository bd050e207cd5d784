"""``lunarmap run`` with reference DTM heights as observations (issue 30): ``[adjust.terrain]`` through the
public API and the command line on the small rendered example, with a reference DTM of known error (the
simulator's truth DTM plus white node noise of known sigma); the terrain group's variance component
recovered from far-off starting sigmas, its outputs, the cache key, and bad DTMs named before any work."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from lunarmap.errors import ConfigError, DtmCoverageError, DtmCrsError
from lunarmap.workflows import config_from_dict, load_config, run, write_example

NAMES = ["orbit1_nac", "orbit2_nac", "orbit3_nac", "orbit2_frame_a"]
NOISE = 3.0              # white noise per DTM node, metres: interpolated, 2/3 of it (the truth of the estimate)
SPACING = 10.0           # DTM node spacing, metres
BASELINE = 48.0          # slope baseline of the partials, metres


@pytest.fixture(scope="module")
def example(tmp_path_factory) -> dict:
    """The 4-image example, its reference DTM (truth + noise), a DTM without CRS and one of another area."""
    from lunarmap.camera.intersect import DtmSampler
    from lunarmap.simulate import reference_dtm

    folder = tmp_path_factory.mktemp("run_terrain")
    toml = write_example(folder, quick=True, names=NAMES, n_control=4, n_check=8)
    with xr.open_dataarray(folder / "mission" / "dtm.nc") as da:
        truth_da = da.load()
    truth = DtmSampler(truth_da)
    lon, lat = truth_da["lon"].values, truth_da["lat"].values
    m = 0.05          # inside the truth grid: every node of the reference DTM is the truth's
    lon_r = (lon.min() + m * np.ptp(lon), lon.max() - m * np.ptp(lon))
    lat_r = (lat.min() + m * np.ptp(lat), lat.max() - m * np.ptp(lat))
    sim = reference_dtm(folder / "ref.tif", truth, lon_r, lat_r, SPACING, noise_sigma=NOISE, seed=5)
    reference_dtm(folder / "ref_other.tif", truth, lon_r, lat_r, SPACING, noise_sigma=NOISE, seed=6)
    reference_dtm(folder / "nocrs.tif", truth, lon_r, lat_r, SPACING, noise_sigma=NOISE, seed=5, crs=None)
    reference_dtm(folder / "far.tif", lambda lo, la: np.zeros_like(lo), (10.0, 10.5), (-20.0, -19.5), 300.0,
                  noise_sigma=1.0, seed=1)
    return {"toml": toml, "folder": folder, "sim": sim, "truth": truth}


def _config(example: dict, name: str, sigma: float | None, dtm: str = "ref.tif", steps: str = '["variance"]',
            baseline: float | None = BASELINE, output: str = "shared") -> Path:
    """The example's configuration with ``[adjust.terrain]`` (``sigma=None``: none) and the QC steps."""
    text = example["toml"].read_text().replace('output = "run"', f'output = "{output}"')
    text = text.replace('steps = ["baarda"]', f"steps = {steps}")
    if sigma is not None:
        extra = "" if baseline is None else f"\nslope_baseline = {baseline}"
        text = text.replace("[report]", f'[adjust.terrain]\n[[adjust.terrain.dtm]]\npath = "{dtm}"\nsigma = {sigma}\n'
                                         f'name = "lola"{extra}\n\n[report]')
    path = example["folder"] / f"{name}.toml"
    path.write_text(text)
    return path


def _tie_height_rms(result, truth) -> float:
    """Median |adjusted tie point height - truth DTM height| (an independent oracle), metres."""
    from lunarmap.adjust.terrain import point_height

    with xr.open_dataset(result.outputs["adjustment"] / "points.nc") as ds:
        X = ds["xyz"].values[ds["point_type"].values.astype(str) == "tie"]
    lon, lat, h, _ = point_height(X, 1737400.0)
    d = h - truth(lon, lat)
    # the median: a tie point that quality control took out stays where its gross error left it
    return float(np.nanmedian(np.abs(d)))


@pytest.fixture(scope="module")
def runs(example) -> dict:
    """The same block without terrain and with it, the DTM's sigma started 10 x too small and too large (one run
    folder: the images' and pairs' steps are computed once)."""
    out = {}
    for k, cfg, rep in (("none", _config(example, "none", None), False),
                        ("x0.1", _config(example, "x01", 0.1 * example["sim"].sigma_m), False),
                        ("x10", _config(example, "x10", 10.0 * example["sim"].sigma_m), True)):
        r = out[k] = run(cfg, scheduler="sync", report=rep)
        # read now: the next run of the folder replaces its outputs
        r.tie_height = _tie_height_rms(r, example["truth"])       # type: ignore[attr-defined]
        s = r.summary       # the figures of the CHANGELOG / docs, printed for -s
        print(k, "check 3-D RMS", np.sqrt(np.sum(np.square(s["check_rms_after_m"]))), "errors/sigma",
              s["check_normalized_rms"], "tie height median |error|", r.tie_height, json.dumps(s.get("terrain")))
    return out


def test_terrain_variance_component_is_recovered_from_far_off_starts(example, runs):
    truth = example["sim"].sigma_m                      # 2/3 x the node noise: 2.0 m
    for start in ("x0.1", "x10"):
        t = runs[start].summary["terrain"]["lola"]
        assert t["group"] == "terrain lola" and t["variance_component_estimated"]
        assert t["observations"] > 100 and t["outside_dtm"] == 0
        # within 2 sigma of its own precision (sigma / sqrt(2 r) of the estimate)
        assert abs(t["sigma_estimated_m"] - truth) < 2.0 * t["sigma_estimated_sd_m"], (start, t)
        assert 0.02 < t["sigma_estimated_sd_m"] / truth < 0.2
        # the residuals' RMS agrees with the estimated sigma (no group took the DTM's error)
        assert 0.7 < t["rms_residual_m"] / truth < 1.3
    # the starts are 100 x apart in variance, the estimates the same to well within their precision
    a, b = (runs[s].summary["terrain"]["lola"]["sigma_estimated_m"] for s in ("x0.1", "x10"))
    assert abs(a - b) < 0.5 * runs["x10"].summary["terrain"]["lola"]["sigma_estimated_sd_m"]


def test_terrain_outputs_report_and_check_points(example, runs):
    r = runs["x10"]
    adj = r.outputs["adjustment"]
    assert "terrain" not in runs["none"].summary
    with xr.open_dataset(adj / "terrain_residuals.nc") as ds:
        n = ds.sizes["observation"]
        assert n == r.summary["terrain"]["lola"]["observations"]
        assert set(ds["dtm"].values.astype(str)) == {"lola"}
        assert set(ds["status"].values.astype(str)) <= {"in", "down-weighted", "point out", "lost"}
        assert int(np.sum(ds["status"].values.astype(str) != "in")) == r.summary["terrain"]["lola"]["removed"]
        res = ds["residual"].values
        assert ds["residual"].attrs["units"] == "m" and ds.attrs["config_sha256"] == r.config.digest()
        ids = ds["point_id"].values.astype(str)
    # the residuals are the adjusted points' heights above the DTM file's (read here independently)
    import rasterio

    from lunarmap.adjust.terrain import point_height

    with xr.open_dataset(adj / "points.nc") as ds:
        order = {p: i for i, p in enumerate(ds["point"].values.astype(str))}
        X = ds["xyz"].values
    lon, lat, h, _ = point_height(X[[order[i] for i in ids]], 1737400.0)
    with rasterio.open(example["folder"] / "ref.tif") as src:
        tr = src.transform
        cols = np.floor((lon - tr.c) / tr.a).astype(int)
        rows = np.floor((lat - tr.f) / tr.e).astype(int)
        z = src.read(1)[rows, cols]
    # nearest node against the bilinear height: within the node noise and the terrain between nodes
    assert np.sqrt(np.mean((h - z - res) ** 2)) < 2.0 * NOISE
    # the run report has the table
    html = r.report.read_text()
    assert ">Reference DTMs</h2>" in html and "estimated sigma (m)" in html
    # check points: the DTM observes the tie points' heights, the check points' heights get no worse
    rms = {k: float(np.sqrt(np.sum(np.square(v.summary["check_rms_after_m"])))) for k, v in runs.items()}
    assert rms["x10"] < 1.2 * rms["none"], rms
    assert 0.5 < r.summary["check_normalized_rms"] < 1.5
    # tie points' heights against the truth DTM: the DTM's heights bring them closer
    th = {k: v.tie_height for k, v in runs.items()}
    assert th["x10"] < th["none"], th


def test_cli_run_and_the_dtm_file_is_part_of_the_adjust_key(example, runs):
    """The command line runs [adjust.terrain]; another DTM file (same name, other content) reruns the adjustment
    and what follows it, nothing before."""
    import shutil

    shutil.copyfile(example["folder"] / "ref_other.tif", example["folder"] / "ref_cli.tif")
    cfg = _config(example, "cli", 10.0 * example["sim"].sigma_m, dtm="ref_cli.tif")
    proc = subprocess.run([sys.executable, "-m", "lunarmap", "run", str(cfg), "--serial"], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((example["folder"] / "shared" / "outputs" / "adjustment" / "summary.json").read_text())
    t = summary["terrain"]["lola"]
    assert abs(t["sigma_estimated_m"] - example["sim"].sigma_m) < 2.0 * t["sigma_estimated_sd_m"]
    # the same configuration with other DTM content: only the adjustment and what follows it rerun
    shutil.copyfile(example["folder"] / "ref.tif", example["folder"] / "ref_cli.tif")
    res = run(cfg, scheduler="sync", report=False)
    counts = res.counts()
    assert counts["adjust"][0] == 0             # ref.tif's content: the x10 run's adjustment, reused
    assert all(counts[s][0] == 0 for s in ("isd", "rpc", "detect", "match", "tiepoints"))
    assert res.summary["terrain"] == runs["x10"].summary["terrain"]


def _entries(folder: Path) -> set[str]:
    store = folder / "store"
    return {str(p.relative_to(store)) for p in store.rglob("*")} if store.exists() else set()


def test_bad_dtms_are_named_before_anything_is_written(example, runs):
    # no CRS: before any step runs (a fresh run folder gets no store entry, no outputs)
    cfg = _config(example, "nocrs", 2.0, dtm="nocrs.tif", output="nocrs")
    with pytest.raises(DtmCrsError, match=r"adjust\.terrain\.dtm\[0\] \(lola\).*no coordinate reference system"):
        run(cfg, scheduler="sync")
    assert not (example["folder"] / "nocrs" / "outputs").exists()
    assert not [e for e in _entries(example["folder"] / "nocrs") if "/" in e]
    # a DTM of another area: named once the footprints are known, before any pair is matched or adjusted
    shared = example["folder"] / "shared"
    before = _entries(shared)
    stamp = (shared / "outputs" / "adjustment" / "summary.json").stat().st_mtime_ns
    with pytest.raises(DtmCoverageError, match="covers none of the run's tie points"):
        run(_config(example, "far", 2.0, dtm="far.tif"), scheduler="sync")
    assert _entries(shared) == before
    assert (shared / "outputs" / "adjustment" / "summary.json").stat().st_mtime_ns == stamp


def _dict(example: dict, **terrain) -> dict:
    import tomllib

    d = tomllib.loads(example["toml"].read_text())
    d["adjust"]["terrain"] = terrain
    return d


def test_terrain_configuration_is_validated(example):
    base = example["folder"]
    ok = config_from_dict(_dict(example, dtm=[{"path": "ref.tif", "sigma": 2.0, "slope_baseline": 48}]), base=base)
    assert ok.terrain[0].name == "ref" and ok.terrain[0].slope_baseline == 48.0 and ok.terrain[0].group == "terrain ref"
    assert ok.terrain[0].path == base / "ref.tif"
    bad = [
        ({"dtm": [{"path": "ref.tif", "sigma": 0.0}]}, "sigma must be > 0"),
        ({"dtm": [{"path": "ref.tif", "sigma": 2.0, "slope_baseline": -1.0}]}, "slope_baseline must be > 0"),
        ({"dtm": [{"path": "ref.tif", "sigma": 2.0, "name": "a"}, {"path": "ref_other.tif", "sigma": 2.0,
                                                                  "name": "a"}]}, "repeats"),
        ({"dtm": [{"path": "missing.tif", "sigma": 2.0}]}, "does not exist"),
        ({"dtm": [{"path": "ref.tif", "sigma": 2.0, "colour": "red"}]}, "unknown key"),
        ({"dtm": [{"path": "ref.tif"}]}, "missing required key adjust.terrain.dtm\\[0\\].sigma"),
        ({"dtm": []}, "at least one"),
    ]
    for terrain, msg in bad:
        with pytest.raises(ConfigError, match=msg):
            config_from_dict(_dict(example, **terrain), base=base)
    # the DTM heights are tested at their estimated sigma: variance components before the w-tests
    d = _dict(example, dtm=[{"path": "ref.tif", "sigma": 2.0}])
    d["adjust"]["qc"]["steps"] = ["baarda", "variance"]
    with pytest.raises(ConfigError, match="'variance' must come before 'baarda'"):
        config_from_dict(d, base=base)
    assert load_config(_config(example, "valid", 2.0)).terrain[0].sigma == 2.0

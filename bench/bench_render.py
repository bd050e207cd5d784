"""Full-size rendering: time per image, peak memory, disk, correlation at true conjugates, faults.

In one invocation (``nice -n 5 .venv/bin/python bench/bench_render.py [--mission DIR]``):

1. the full-size block mission (``write_block_mission(layout="full_size")``: 8 LRO-NAC-like images of
   52,224 x 5,064 pixels) and its scene (4 m DTM, tiled albedo), timed;
2. the baseline: the numpy renderer (``render_image``, 1 ray per pixel, Lambert shading) on a stripe of
   64 lines of one image, ns per ray; the compiled renderer on the same stripe: the ratio;
3. one whole image rendered into an UnsignedByte ISIS cube (``render_cube``, 2 threads) in a *fresh
   process* that reads the DTM file and builds the tiled albedo, as the example writer's renders do:
   wall and CPU time, the load average, the process's peak RSS (``VmHWM``) and its RSS sampled while
   the stripes are written (flat: memory does not grow with the image), the cube's size;
4. with ``--all``: the other 7 images too (the example's images); with ``--correlation``: windows of
   15 x 15 pixels at true conjugates (truth cameras through the DTM, ``true_conjugates``) of
   cross-orbit pairs of a 3-orbit full-size mission (20 and 40 degrees), correlated after resampling
   through the local affine map (as ``tests/test_block_mission.py`` does), and 3 px off;
5. with ``--faults``: a render into a 1 MB tmpfs (full disk) and into a read-only tmpfs (needs root):
   the named error, and what is left in the folder.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np


def _status(key: str) -> float:
    """``VmHWM`` / ``VmRSS`` of this process, MB."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _render_one(mission: str, name: str, out: str) -> dict:
    """Child process: read the DTM, build the albedo, render one cube; report times and memory."""
    import xarray as xr

    from lunarmap.simulate import block_cameras
    from lunarmap.simulate.albedo import tiled_albedo
    from lunarmap.simulate.compiled_render import RenderScene, render_cube
    from lunarmap.simulate.mission import _label_groups, _site_seeds, image_seed
    from lunarmap.synthetic import open_block_mission

    bm = open_block_mission(mission)
    t0 = time.perf_counter()
    with xr.open_dataarray(Path(mission) / "dtm.nc") as d:
        dtm = d.load()
    s = bm.model.site(1)
    albedo = tiled_albedo(s.longitude_deg, s.latitude_deg, _site_seeds(bm.model.seed, 1)[1])
    scene = RenderScene.of(dtm, albedo)
    t_scene = time.perf_counter() - t0
    rss_scene = _status("VmRSS")
    cam = block_cameras(bm, "truth", [name])[name]
    samples: list[float] = []
    stop = threading.Event()

    def sample() -> None:
        while not stop.wait(2.0):
            samples.append(_status("VmRSS"))

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    load0 = os.getloadavg()
    cpu0 = resource.getrusage(resource.RUSAGE_SELF)
    r = render_cube(cam, scene, Path(out) / f"{name}.cub", seed=image_seed(bm, name), threads=2,
                    groups=_label_groups(bm, name))
    cpu1 = resource.getrusage(resource.RUSAGE_SELF)
    stop.set()
    th.join()
    return {"image": name, "wall_s": r.seconds, "cpu_s": (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime),
            "load_before": load0, "load_after": os.getloadavg(), "scene_s": t_scene, "rss_scene_mb": rss_scene,
            "rss_during_mb": [round(v) for v in samples[:: max(1, len(samples) // 12)]],
            "vmhwm_mb": _status("VmHWM"), "bytes": r.nbytes, "n_null": r.n_null, "n_clipped": r.n_clipped,
            "pixels": r.lines * r.samples}


def _correlations(folder: Path, n: int = 60) -> dict:
    """NCC of 15 x 15 windows at true conjugates of cross-orbit pairs of a 3-orbit full-size mission.

    The windows are rendered where they are needed (``render_window`` + the cubes' noise and
    quantisation, seeded per image: the pixels a cube of the image holds), so that orbit 3 (40 degrees
    from orbit 1) needs no whole image.
    """
    from scipy.ndimage import map_coordinates

    from lunarmap.simulate import block_cameras, block_check_points
    from lunarmap.simulate.compiled_render import RenderScene, render_window
    from lunarmap.simulate.mission import block_scene, image_seed
    from lunarmap.simulate.raycast import add_noise_and_quantise
    from lunarmap.simulate.truth import true_conjugates
    from lunarmap.synthetic import write_block_mission

    bm = write_block_mission(folder / "mission3", layout="full_size", orbits=3)
    dtm, albedo = block_scene(bm)
    scene = RenderScene.of(dtm, albedo)

    def dn(cam, name, l0, l1, s0, s1):
        v, _ = render_window(cam, scene, (l0, l1, s0, s1), threads=2)
        out = np.empty_like(v)
        add_noise_and_quantise(v, l0, s0, image_seed(bm, name), 160.0, 0.0, 2.0, 1.0, 254.0, 0.0, out)
        return out

    def ncc(a, b):
        a, b = a - a.mean(), b - b.mean()
        return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))

    u = np.arange(-7, 8)
    ul, us = np.meshgrid(u, u, indexing="ij")
    out = {}
    for a, b in (("orbit1_nacl_a", "orbit2_nacl_a"), ("orbit2_nacr_b", "orbit3_nacr_b"),
                 ("orbit1_nacl_a", "orbit3_nacl_a"), ("orbit1_nacr_b", "orbit3_nacr_b")):
        cams = block_cameras(bm, "truth", [a, b])
        pts = block_check_points(bm, n, sigma_px=0.0, seed=5, cameras=cams, names=[a, b], dtm=dtm, margin_px=40.0)
        sel = pts["image_id"].values == 0
        l1 = np.floor(pts["line_true"].values[sel]) + 0.5
        s1 = np.floor(pts["sample_true"].values[sel]) + 0.5
        l2, s2 = true_conjugates(cams[a], cams[b], l1, s1, dtm)
        dl_l, ds_l = true_conjugates(cams[a], cams[b], l1 + 1.0, s1, dtm)
        dl_s, ds_s = true_conjugates(cams[a], cams[b], l1, s1 + 1.0, dtm)
        good, wrong, conv = [], [], []
        for k in range(l1.size):
            if not np.isfinite(l2[k]):
                continue
            i, j = int(l1[k]), int(s1[k])
            w1 = dn(cams[a], a, i - 7, i + 8, j - 7, j + 8)
            lw = l2[k] + (dl_l[k] - l2[k]) * ul + (dl_s[k] - l2[k]) * us
            sw = s2[k] + (ds_l[k] - s2[k]) * ul + (ds_s[k] - s2[k]) * us
            r0, c0 = int(lw.min()) - 4, int(sw.min()) - 4
            block = dn(cams[b], b, r0, int(lw.max()) + 6, c0, int(sw.max()) + 6)
            good.append(ncc(w1, map_coordinates(block, [lw - 0.5 - r0, sw - 0.5 - c0], order=1)))
            wrong.append(ncc(w1, map_coordinates(block, [lw + 2.5 - r0, sw + 2.5 - c0], order=1)))
            va = cams[a].look_vector(l1[k], s1[k])
            vb = cams[b].look_vector(l2[k], s2[k])
            conv.append(np.degrees(np.arccos(np.clip(float(np.dot(va, vb)), -1.0, 1.0))))
        out[f"{a}|{b}"] = {"n": len(good), "convergence_deg": round(float(np.median(conv)), 1),
                           "median": round(float(np.median(good)), 3), "p10": round(float(np.percentile(good, 10)), 3),
                           "min": round(float(np.min(good)), 3), "median_3px_off": round(float(np.median(wrong)), 3)}
        print(a, b, out[f"{a}|{b}"], flush=True)
    return out


def _faults(mission: Path) -> dict:
    """Render into a full and a read-only tmpfs (root): the error, and the folder's content."""
    import xarray as xr

    from lunarmap.errors import LunarmapError
    from lunarmap.simulate import block_cameras
    from lunarmap.simulate.compiled_render import RenderScene, render_cube

    bm_name = "orbit1_nacl_a"
    from lunarmap.synthetic import open_block_mission

    bm = open_block_mission(mission)
    cam = block_cameras(bm, "truth", [bm_name])[bm_name]
    with xr.open_dataarray(mission / "dtm.nc") as d:
        dtm = d.load()
    from lunarmap.simulate.albedo import tiled_albedo

    s = bm.model.site(1)
    scene = RenderScene.of(dtm, tiled_albedo(s.longitude_deg, s.latitude_deg, 1, tile_nodes=(512, 480)))
    out = {}
    for label, opts in (("full disk (1 MB tmpfs)", "size=1m"), ("read-only tmpfs", "ro,size=1m")):
        mnt = Path(tempfile.mkdtemp(prefix="bench_render_mnt_"))
        if subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(mnt)]).returncode:
            out[label] = "mount failed (needs root)"
            continue
        try:
            render_cube(cam, scene, mnt / "x.cub", threads=2)
            out[label] = "no error!"
        except LunarmapError as err:
            out[label] = f"{type(err).__name__}: {err}; left in the folder: {sorted(os.listdir(mnt))}"
        finally:
            subprocess.run(["umount", str(mnt)])
            mnt.rmdir()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mission", help="a full-size mission folder with dtm.nc (default: written to a temp folder)")
    ap.add_argument("--out", help="folder for the cubes (default: a temp folder)")
    ap.add_argument("--all", action="store_true", help="render all 8 images")
    ap.add_argument("--correlation", action="store_true", help="correlation at true conjugates, 20 and 40 degrees")
    ap.add_argument("--faults", action="store_true", help="full and read-only folders (root: tmpfs mounts)")
    ap.add_argument("--no-render", action="store_true", help="skip steps 1-4's rendering (e.g. --correlation alone)")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(_render_one(*args.child)))
        return
    from lunarmap.simulate import block_cameras, render_image
    from lunarmap.simulate.compiled_render import RenderScene, render_window
    from lunarmap.simulate.mission import block_scene
    from lunarmap.synthetic import open_block_mission, write_block_mission

    tmp = Path(tempfile.mkdtemp(prefix="bench_render_"))
    report: dict = {"load_at_start": os.getloadavg()}
    if args.no_render:
        if args.correlation:
            report["correlation"] = _correlations(tmp)
        if args.faults:
            report["faults"] = _faults(Path(args.mission))
        print(json.dumps(report, indent=1, default=str))
        return
    if args.mission:
        mission = Path(args.mission)
        bm = open_block_mission(mission)
    else:
        mission = tmp / "mission"
        t = time.perf_counter()
        bm = write_block_mission(mission, layout="full_size")
        report["mission_s"] = time.perf_counter() - t
    t = time.perf_counter()
    dtm, albedo = block_scene(bm)
    report["scene_s"] = time.perf_counter() - t
    if not (mission / "dtm.nc").is_file():
        dtm.to_netcdf(mission / "dtm.nc", engine="netcdf4")
    report["dtm_file_mb"] = (mission / "dtm.nc").stat().st_size / 1e6
    name = "orbit1_nacl_a"
    cam = block_cameras(bm, "truth", [name])[name]
    win = (26000, 26064, 0, 5064)
    t = time.perf_counter()
    render_image(cam, dtm, albedo, supersample=1, sun="eo", gain=1.0, window=win, chunks=256).compute(scheduler="sync")
    numpy_ns = (time.perf_counter() - t) * 1e9 / (64 * 5064)
    scene = RenderScene.of(dtm, albedo)
    render_window(cam, scene, (0, 8, 0, 8), threads=1)
    t = time.perf_counter()
    render_window(cam, scene, win, threads=1)
    compiled_ns = (time.perf_counter() - t) * 1e9 / (64 * 5064)
    report["stripe_ns_per_ray"] = {"numpy_render_image_1thread": round(numpy_ns), "compiled_1thread": round(compiled_ns),
                                   "ratio": round(numpy_ns / compiled_ns, 1)}
    del dtm, albedo, scene
    out = Path(args.out) if args.out else tmp / "cubes"
    out.mkdir(parents=True, exist_ok=True)
    names = list(bm.image_names) if args.all else [name]
    report["renders"] = []
    for n in names:
        if (out / f"{n}.cub").is_file():
            continue
        res = subprocess.run([sys.executable, __file__, "--child", str(mission), n, str(out)], capture_output=True,
                             text=True, check=True)
        rec = json.loads(res.stdout.strip().splitlines()[-1])
        report["renders"].append(rec)
        print(json.dumps(rec), flush=True)
    report["disk_cubes_gb"] = sum(p.stat().st_size for p in out.glob("*.cub")) / 1e9
    if args.correlation:
        report["correlation"] = _correlations(tmp)
    if args.faults:
        report["faults"] = _faults(mission)
    report["load_at_end"] = os.getloadavg()
    print(json.dumps(report, indent=1, default=str))


if __name__ == "__main__":
    main()

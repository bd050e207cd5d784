"""Build lunarmap's sdist and wheel, install the wheel into a fresh venv and use it there (``make wheel-check``).

Nothing of the source tree is on the fresh environment's path: the venv and the working folders are
made in a temporary directory, every command runs there, and the check asserts that ``lunarmap`` is
imported from the venv's ``site-packages``. Steps, each timed:

1. ``python -m build`` (sdist + wheel into ``dist/``; sizes printed, the wheel's content checked:
   every subpackage, ``py.typed``, no tests or benchmarks);
2. a fresh ``venv``, ``pip install <wheel>`` (dependencies from the index, as a user gets them);
3. ``lunarmap --version`` equals ``lunarmap.__version__`` of the source tree;
4. ``lunarmap isd`` on the shared LRO NAC label (``$LUNARMAP_SHARED_KERNELS``, default
   ``../shared/data/kernels``; skipped with a message when absent, a failure under ``CI=true``);
5. a short Python API smoke test (camera from that ISD, ground to image and back, a cubic RPC);
6. ``lunarmap run --example --quick --serial`` in an empty folder.

Not part of ``.ci/run`` (it takes minutes: the install and the example run); run it before a release
or after changing packaging: ``make wheel-check`` (``KEEP=1`` keeps the temporary folder).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("LUNARMAP_SHARED_KERNELS", ROOT.parent / "shared" / "data" / "kernels"))
LRO = SHARED / "lro_nac_M103595705LE"


def _version() -> str:
    text = (ROOT / "lunarmap" / "__init__.py").read_text()
    match = re.search(r'^__version__ = "([^"]+)"', text, re.M)
    assert match, "no __version__ in lunarmap/__init__.py"
    return match.group(1)


def _run(cmd: list[str], cwd: Path, env: dict[str, str] | None = None, what: str = "") -> tuple[str, float]:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.stderr.write(proc.stdout[-4000:] + proc.stderr[-4000:])
        raise SystemExit(f"wheel check: {what or cmd[0]} failed (exit {proc.returncode}) after {dt:.1f} s")
    return proc.stdout + proc.stderr, dt


def _kib(path: Path) -> str:
    return f"{path.stat().st_size / 1024:,.0f} KiB"


def main() -> int:
    version = _version()
    dist = ROOT / "dist"
    shutil.rmtree(dist, ignore_errors=True)
    out, dt = _run([sys.executable, "-m", "build", "--outdir", str(dist), str(ROOT)], ROOT, what="python -m build")
    for line in out.splitlines():
        if "warning" in line.lower() and "location" not in line.lower():
            print("build:", line)
    wheel = next(dist.glob("lunarmap-*.whl"))
    sdist = next(dist.glob("lunarmap-*.tar.gz"))
    print(f"build: {dt:.1f} s; wheel {wheel.name} {_kib(wheel)}, sdist {sdist.name} {_kib(sdist)}")
    assert wheel.name.startswith(f"lunarmap-{version}-py3-none-any"), wheel.name
    names = zipfile.ZipFile(wheel).namelist()
    packages = sorted({str(p.parent.relative_to(ROOT)) for p in (ROOT / "lunarmap").rglob("__init__.py")})
    missing = [p for p in packages if f"{p}/__init__.py" not in names]
    assert not missing, f"subpackages missing from the wheel: {missing}"
    assert "lunarmap/py.typed" in names
    stray = [n for n in names if n.startswith(("tests/", "bench/", "docs/", "workflows/"))]
    assert not stray, f"the wheel holds files outside the package: {stray[:5]}"
    print(f"wheel: {len(names)} files, {len(packages)} packages, py.typed present, no tests/bench/docs")

    tmp = Path(tempfile.mkdtemp(prefix="lunarmap-wheel-"))
    try:
        venv = tmp / "venv"
        _, dt = _run([sys.executable, "-m", "venv", str(venv)], tmp, what="venv")
        py = venv / "bin" / "python"
        exe = venv / "bin" / "lunarmap"
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
        env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
        _, dt_install = _run([str(py), "-m", "pip", "install", "--quiet", str(wheel)], tmp, env, "pip install wheel")
        print(f"fresh venv {venv}: wheel installed in {dt_install:.1f} s")
        where, _ = _run([str(py), "-c", "import lunarmap, sys; print(lunarmap.__file__)"], tmp, env, "import")
        assert str(venv) in where and str(ROOT) not in where, f"lunarmap imported from {where.strip()}"
        print(f"import: {where.strip()}")

        out, dt = _run([str(exe), "--version"], tmp, env, "lunarmap --version")
        assert out.strip() == f"lunarmap {version}", out
        print(f"lunarmap --version: {out.strip()!r} ({dt:.1f} s)")

        if LRO.is_dir():
            isd_path = tmp / "nac.json"
            _, dt = _run([str(exe), "isd", str(LRO / "M103595705LE_isis3.lbl"), "--kernels",
                          str(LRO / "lro_nac_M103595705LE.tm"), "-o", str(isd_path)], tmp, env, "lunarmap isd")
            isd = json.loads(isd_path.read_text())
            assert isd["name_model"] == "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL", isd["name_model"]
            print(f"lunarmap isd (LRO NAC M103595705LE): {isd['image_lines']} lines, "
                  f"{len(isd['instrument_position']['ephemeris_times'])} epochs ({dt:.1f} s)")
            smoke = (
                "import numpy as np, lunarmap\n"
                f"cam = lunarmap.camera_from_isd_file({str(isd_path)!r})\n"
                "n, m = cam.n_lines, cam.n_samples\n"
                "ls = np.array([[10.5, 20.5], [n / 2, m / 2], [n - 10.5, m - 10.5]])\n"
                "xyz = cam.image_to_ground(ls[:, 0], ls[:, 1], height=0.0)\n"
                "back = np.stack(cam.ground_to_image(xyz), axis=-1)\n"
                "err = float(np.abs(np.asarray(back) - ls).max())\n"
                "assert err < 1e-4, err\n"
                "fit = lunarmap.fit_rpc(cam, height_range=(-2000.0, 2000.0))\n"
                "print(f'round trip {err:.1e} px; RPC check RMS {fit.check.rms:.4f} px')\n"
            )
            out, dt = _run([str(py), "-c", smoke], tmp, env, "API smoke test")
            print(f"API (camera_from_isd_file, image_to_ground/ground_to_image, fit_rpc): {out.strip()} ({dt:.1f} s)")
        elif os.environ.get("CI") == "true":
            raise SystemExit(f"wheel check: shared kernel set {LRO} is required on CI but absent")
        else:
            print(f"lunarmap isd: skipped, shared kernel set {LRO} absent")

        empty = tmp / "empty"
        empty.mkdir()
        t0 = time.perf_counter()
        proc = subprocess.run([str(exe), "run", "--example", "--quick", "--serial"], cwd=empty, env=env,
                              capture_output=True, text=True)
        dt = time.perf_counter() - t0
        if proc.returncode != 0:
            sys.stderr.write(proc.stdout[-4000:] + proc.stderr[-4000:])
            raise SystemExit(f"wheel check: lunarmap run --example failed (exit {proc.returncode}) after {dt:.0f} s")
        assert (empty / "demo_output").is_dir()
        print(f"lunarmap run --example --quick --serial (empty folder): {dt:.0f} s; its report (last lines):")
        for line in proc.stdout.strip().splitlines()[-12:]:
            print("   ", line.rstrip())
    finally:
        if os.environ.get("KEEP") == "1":
            print(f"kept {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    print("wheel check passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())

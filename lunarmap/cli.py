"""The ``lunarmap`` command line.

``lunarmap isd LABEL --kernels META_KERNEL [-o FILE] [--csm]``
    write the CSM image support data (ALE ISD layout) of one image; ``--csm``: with a distortion model
    usgscsm applies (a fitted transverse polynomial for the Apollo metric and Lunar Orbiter cameras).
``lunarmap run CONFIG [--scheduler ADDRESS] [--workers N] [--serial] [--dry-run] [--wait | --force] [--check]``
    the whole chain of a run configuration (TOML, see :mod:`lunarmap.workflows.config`) as one dask
    graph: ISDs, RPCs, tie points, adjustment, adjusted kernels, report; resumable. Everything the
    configuration names is checked before any step runs; ``--dry-run`` prints the plan (images,
    candidate pairs, steps to compute or reuse) and stops. One run per folder at a time (``run.lock``):
    a second one stops with a named error, or waits with ``--wait``; ``--force`` takes the folder
    whatever its lock says. ``--check`` verifies every stored output against its checksum without
    computing anything (exit status 1 when one is damaged).
``lunarmap run --example [--output DIR] [--seed N] [--quick] [--full-size | --terrain]`` (= ``lunarmap demo``)
    writes the embedded example (a synthetic mission with rendered images and perturbed navigation;
    with ``--full-size`` eight LRO-NAC-like images of 52,224 x 5,064 pixels as ISIS cubes; with
    ``--terrain`` LOLA-like altimetry tracks, bus jitter in the true CK and no control points, adjusted
    with ``[[adjust.terrain.altimetry]]`` and ``[adjust.jitter]``) and runs it; prints accuracy against
    the simulation's truth. What is already written is not written again.
``lunarmap --version``
    prints the installed version (``lunarmap.__version__``) and exits.
``lunarmap ranger-kernels TABLE -o DIR [--focal-length MM --format MM --pixel MM]``
    write a flight-parameter table (Ranger paper) as a SPICE kernel set with labels.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Sequence

from .errors import LunarmapError

__all__ = ["main", "plain_text"]


def plain_text(text: str) -> str:
    """``text`` without its reStructuredText markup (for ``--help``): literals lose their double backticks,
    cross-reference roles (``:func:``, ``:class:``, ...) keep their target's last name."""
    import re

    text = re.sub(r":[a-z]+:`~?([^`<]*?)(?:\s*<[^>]*>)?`", lambda m: m.group(1).split(".")[-1]
                  if "~" in m.group(0) else m.group(1), text)
    text = re.sub(r"``([^`]*)``", r"\1", text)
    return re.sub(r"\*\*([^*]*)\*\*", r"\1", text)


def _cmd_isd(args: argparse.Namespace) -> int:
    from .orientation.drivers import image_support

    isd = image_support(args.label, args.kernels)
    if args.csm:
        from .camera.csm import csm_image_support

        isd = csm_image_support(isd)
        fit = isd.provenance.get("csm_distortion")
        if fit:
            print(f"--csm: {fit['replaced']} distortion replaced by {fit['by']}: {fit['fit_rms_px']:.2g} px RMS, "
                  f"{fit['fit_max_px']:.2g} px max ({fit['check_grid']} check grid)", file=sys.stderr)
    if args.output:
        isd.write_json(args.output)
        print(f"wrote {args.output}", file=sys.stderr)
    else:
        json.dump(isd.to_ale_dict(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    return 0


def _cmd_ranger_kernels(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .missions import RangerCamera, read_flight_parameters
    from .missions.ranger_kernels import write_ranger_kernels

    if not Path(args.table).is_file():
        print(f"lunarmap: error: flight-parameter table {args.table} does not exist", file=sys.stderr)
        return 2
    table = read_flight_parameters(args.table, radius=args.radius)
    if args.tolerance > 0:
        table.check_consistency(tolerance_deg=args.tolerance)
    camera = RangerCamera(focal_length=args.focal_length, format=args.format, pixel=args.pixel)
    written = write_ranger_kernels(table, camera, args.output)
    print(written.metakernel)
    for photo, label in written.labels.items():
        print(f"{photo}: {label}", file=sys.stderr)
    return 0


def _progress_to_stderr() -> Any:
    import logging

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("lunarmap: %(message)s"))
    log = logging.getLogger("lunarmap")
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    return handler


def _scheduler(args: argparse.Namespace) -> Any:
    return "sync" if args.serial else args.scheduler


def _example_output(args: argparse.Namespace) -> None:
    """The example's folder: ``--output``, or the default of the example chosen."""
    if getattr(args, "output", None) is None:
        args.output = "demo_terrain_output" if getattr(args, "terrain", False) else "demo_output"
    if getattr(args, "terrain", False) and getattr(args, "full_size", False):
        raise SystemExit("lunarmap run: --terrain and --full-size are two examples; give one")


def _cmd_demo(args: argparse.Namespace) -> int:
    import logging

    _example_output(args)
    handler = _progress_to_stderr()
    logging.getLogger("lunarmap").info("example in %s: loading lunarmap (numpy, dask, SPICE)", args.output)
    from .demo import run_demo

    try:
        report = run_demo(args.output, seed=args.seed, quick=args.quick, scheduler=_scheduler(args),
                          workers=args.workers, full_size=args.full_size, terrain=args.terrain)
    finally:
        logging.getLogger("lunarmap").removeHandler(handler)
    print(report.text())
    return 0


def _cmd_plan(args: argparse.Namespace) -> int:
    from .workflows import plan, write_example

    _example_output(args)
    handler = _progress_to_stderr()
    try:
        config = args.config
        if args.example:
            config = write_example(args.output, seed=args.seed, quick=args.quick, full_size=args.full_size,
                                   terrain=args.terrain)
        print(plan(config).text())
    finally:
        import logging

        logging.getLogger("lunarmap").removeHandler(handler)
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    import logging

    if args.example and args.config:
        raise SystemExit("lunarmap run: give a CONFIG or --example, not both")
    if not args.example and not args.config:
        raise SystemExit("lunarmap run: a CONFIG (TOML) or --example is needed")
    if getattr(args, "dry_run", False):
        return _cmd_plan(args)
    if args.example:
        return _cmd_demo(args)
    from .workflows import run

    if getattr(args, "check", False):
        from .workflows.engine import check_run

        n, problems = check_run(args.config)
        for why in problems:
            print(f"damaged: {why}")
        print(f"{n} stored outputs checked, {len(problems)} damaged"
              + (" (a run computes them again)" if problems else ""))
        return 1 if problems else 0
    handler = _progress_to_stderr()
    try:
        result = run(args.config, scheduler=_scheduler(args), workers=args.workers,
                     wait=getattr(args, "wait", False), force=getattr(args, "force", False))
    finally:
        logging.getLogger("lunarmap").removeHandler(handler)
    s = result.summary
    print(f"run folder {result.folder}: sigma0 {s['sigma0']:.4f}, {s['n_points']} points, "
          f"{s['n_observations']} observations; adjusted kernels "
          f"{result.outputs.get('metakernel', result.outputs['kernels'])}")
    if "check_rms_after_m" in s:
        print("check points RMS along/cross/height (m): before "
              + " ".join(f"{v:.3f}" for v in s["check_rms_before_m"]) + ", after "
              + " ".join(f"{v:.3f}" for v in s["check_rms_after_m"])
              + f" (errors / posterior sigma: RMS {s['check_normalized_rms']:.2f})")
    from .workflows.report import qc_text

    if qc_text(s):
        print(qc_text(s) + f"; decisions in {result.outputs['adjustment'] / 'qc.txt'}")
    if result.report is not None:
        print(f"report {result.report}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(
        prog="lunarmap", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="lunarmap: planetary photogrammetry for the Moon, from SPICE kernels and image labels to "
                    "adjusted orientations.",
        epilog="commands:\n" + plain_text(__doc__.split("\n\n", 1)[1]).split("\n\nfrom __future__")[0])
    parser.add_argument("--version", action="version", version=f"lunarmap {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("isd", help="write the image support data (ALE/CSM ISD JSON) of an image")
    p.add_argument("label", help="ISIS cube or label, or PDS3 label")
    p.add_argument("--kernels", "-k", required=True, help="meta-kernel (.tm)")
    p.add_argument("--output", "-o", help="output JSON file (default: standard output)")
    p.add_argument("--csm", action="store_true",
                   help="write a distortion model usgscsm applies: Apollo metric and Lunar Orbiter distortions become "
                        "the usgscsm model fitted to them best (transverse or radtan; the fit error is printed and "
                        "kept in the ISD)")
    p.set_defaults(func=_cmd_isd)
    r = sub.add_parser("run", help="run the whole chain of a configuration (TOML) as one dask graph")
    r.add_argument("config", nargs="?", help="run configuration (TOML)")
    r.add_argument("--example", action="store_true",
                   help="write the embedded example (synthetic mission, rendered images, run.toml) and run it")
    r.add_argument("--check", action="store_true",
                   help="verify the run folder's stored outputs against their checksums; compute nothing")
    r.add_argument("--wait", action="store_true",
                   help="when another run uses the folder, wait for it instead of stopping")
    r.add_argument("--force", action="store_true",
                   help="take the run folder whatever its lock says (a run known to be gone)")
    r.add_argument("--dry-run", action="store_true",
                   help="check everything, print the plan (images, candidate pairs, steps to compute or reuse) and "
                        "stop; nothing is computed")
    d = sub.add_parser("demo", help="the same as 'run --example'")
    for q in (r, d):
        q.add_argument("--scheduler", help="address of a running dask scheduler (default: a local cluster)")
        q.add_argument("--workers", type=int, default=2, help="processes of the local cluster (default 2)")
        q.add_argument("--serial", action="store_true", help="run every step in this process, one after another")
        q.add_argument("--output", "-o", default=None,
                       help="with --example: folder for everything it writes (default demo_output, with --terrain "
                            "demo_terrain_output)")
        q.add_argument("--seed", type=int, default=0, help="with --example: seed of the mission, scene, measurements")
        q.add_argument("--quick", action="store_true",
                       help="with --example: fewer interest and check points (same chain, faster)")
        q.add_argument("--full-size", action="store_true",
                       help="with --example: 8 full-size LRO-NAC-like images (52,224 x 5,064 pixels, ISIS cubes, "
                            "~2.3 GB, minutes to render) instead of the 12 small ones")
        q.add_argument("--terrain", action="store_true",
                       help="with --example: LOLA-like altimetry tracks and CK jitter on the line scanners, adjusted "
                            "with [[adjust.terrain.altimetry]] and [adjust.jitter]; no control points")
    r.set_defaults(func=_cmd_run)
    d.set_defaults(func=_cmd_demo, example=True)
    g = sub.add_parser("ranger-kernels", help="write a Ranger flight-parameter table as SPICE kernels and labels")
    g.add_argument("table", help="flight-parameter table (.csv or .nc; see lunarmap.missions.flight_parameters)")
    g.add_argument("--output", "-o", required=True, help="folder for the kernels, labels and ranger.tm")
    g.add_argument("--focal-length", type=float, default=76.0, help="mm, in the photo coordinates' units")
    g.add_argument("--format", type=float, default=11.0, help="side of the square image, mm")
    g.add_argument("--pixel", type=float, default=0.01, help="image-coordinate pixel, mm")
    g.add_argument("--radius", type=float, default=None, help="sphere radius, m (default: the table's, 1736600)")
    g.add_argument("--tolerance", type=float, default=0.01,
                   help="refuse LATp/LONp farther than this (deg) from the orientation's principal point; 0: no check")
    g.set_defaults(func=_cmd_ranger_kernels)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``lunarmap`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except LunarmapError as err:
        log = getattr(err, "run_log", None)
        print(f"lunarmap: error: {type(err).__name__}: {err}" + (f" (details in {log})" if log else ""),
              file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

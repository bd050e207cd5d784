"""The ``lunarmap`` command line.

``lunarmap isd LABEL --kernels META_KERNEL [-o FILE]``
    write the CSM image support data (ALE ISD layout) of one image.
``lunarmap ranger-kernels TABLE -o DIR [--focal-length MM --format MM --pixel MM]``
    write a flight-parameter table (Ranger paper) as a SPICE kernel set with labels (issue 13).
``lunarmap demo [--output DIR] [--seed N] [--quick]``
    the whole chain on a synthetic mission: kernels, rendered images, tie points, adjustment with
    navigation observations, adjusted kernels reloaded, accuracy against truth.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Sequence

from .errors import LunarmapError

__all__ = ["main"]


def _cmd_isd(args: argparse.Namespace) -> int:
    from .orientation.drivers import image_support

    isd = image_support(args.label, args.kernels)
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


def _cmd_demo(args: argparse.Namespace) -> int:
    import logging

    from .demo import run_demo

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("lunarmap: %(message)s"))
    log = logging.getLogger("lunarmap")
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    try:
        report = run_demo(args.output, seed=args.seed, quick=args.quick)
    finally:
        log.removeHandler(handler)
    print(report.text())
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lunarmap", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("isd", help="write the image support data (ALE/CSM ISD JSON) of an image")
    p.add_argument("label", help="ISIS cube or label, or PDS3 label")
    p.add_argument("--kernels", "-k", required=True, help="meta-kernel (.tm)")
    p.add_argument("--output", "-o", help="output JSON file (default: standard output)")
    p.set_defaults(func=_cmd_isd)
    r = sub.add_parser("ranger-kernels", help="write a Ranger flight-parameter table as SPICE kernels and labels")
    r.add_argument("table", help="flight-parameter table (.csv or .nc; see lunarmap.missions.flight_parameters)")
    r.add_argument("--output", "-o", required=True, help="folder for the kernels, labels and ranger.tm")
    r.add_argument("--focal-length", type=float, default=76.0, help="mm, in the photo coordinates' units")
    r.add_argument("--format", type=float, default=11.0, help="side of the square image, mm")
    r.add_argument("--pixel", type=float, default=0.01, help="image-coordinate pixel, mm")
    r.add_argument("--radius", type=float, default=None, help="sphere radius, m (default: the table's, 1736600)")
    r.add_argument("--tolerance", type=float, default=0.01,
                   help="refuse LATp/LONp farther than this (deg) from the orientation's principal point; 0: no check")
    r.set_defaults(func=_cmd_ranger_kernels)
    d = sub.add_parser("demo", help="the whole chain on a synthetic mission with known truth")
    d.add_argument("--output", "-o", default="demo_output", help="folder for everything the demo writes")
    d.add_argument("--seed", type=int, default=0, help="seed of the mission, scene and measurements")
    d.add_argument("--quick", action="store_true", help="fewer interest and check points (same chain, faster)")
    d.set_defaults(func=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``lunarmap`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except LunarmapError as err:
        print(f"lunarmap: error: {type(err).__name__}: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""ISDs for many images on dask: one task per image, SPICE loaded once per worker.

``python -m workflows.isd_batch META_KERNEL OUT_DIR LABEL [LABEL ...] [--scheduler ADDRESS]``

Kernels reach the workers through :class:`lunarmap.parallel.SpiceKernelPlugin`
(a picklable list of paths); each task samples SPICE for one image under the
worker's SPICE lock and writes ``<label stem>.isd.json`` atomically.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Sequence

import dask
from dask.delayed import Delayed

from lunarmap.orientation.drivers import image_support
from lunarmap.spice import KernelSet

__all__ = ["build", "run", "isd_task"]


def isd_task(label: str, kernel_set: KernelSet, out_dir: str) -> str:
    """Write one image's ISD; returns the output path."""
    isd = image_support(label, kernel_set)
    out = Path(out_dir) / (Path(label).stem + ".isd.json")
    isd.write_json(out)
    return str(out)


def build(labels: Sequence[str | os.PathLike[str]], kernel_set: KernelSet, out_dir: str | os.PathLike[str]) -> list[Delayed]:
    """One delayed task per label."""
    task = dask.delayed(isd_task, pure=True)
    return [task(os.fspath(lab), kernel_set, os.fspath(out_dir)) for lab in labels]


def run(labels: Sequence[str | os.PathLike[str]], metakernel: str | os.PathLike[str], out_dir: str | os.PathLike[str],
        scheduler: str | None = None, n_workers: int = 2) -> list[str]:
    """Compute the ISDs on a local cluster (default) or on the scheduler at ``scheduler``."""
    from distributed import Client, LocalCluster

    from lunarmap.parallel import register_kernels

    kset = KernelSet.from_metakernel(metakernel)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    cluster = None if scheduler else LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                                  dashboard_address=":0")
    try:
        with Client(scheduler or cluster) as client:
            register_kernels(client, kset)
            return list(client.compute(build(labels, kset, out_dir), sync=True))
    finally:
        if cluster is not None:
            cluster.close()


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("metakernel")
    ap.add_argument("out_dir")
    ap.add_argument("labels", nargs="+")
    ap.add_argument("--scheduler", help="address of a dask-distributed scheduler (default: a local cluster)")
    args = ap.parse_args(argv)
    for path in run(args.labels, args.metakernel, args.out_dir, args.scheduler):
        print(path)


if __name__ == "__main__":
    main()

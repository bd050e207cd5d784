"""ISIS cube laziness (a script, not a test): a 52,224 x 5,064 Real cube opened, one tile read.

Prints one JSON line. The cube (1.06 GB of pixels, 512 x 422 tiles, the layout ISIS gives an LRO
NAC image) is written as a *sparse* file: the label by lunarmap's writer, the core holes that
read as zeros, one tile of data. Timed, medians of ``--repeat`` runs: opening (label, layout,
truncation check, dask graph), reading one tile (``chunks="tile"``) and one row of tiles (the
default chunk), against the baseline of reading the whole image in the same run; the ratio
whole / tile is what laziness saves.

    python bench/bench_isis_cube.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from lunarmap.io import IsisCube, write_cube


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    lines, samples, tl, ts = 52224, 5064, 512, 422
    with tempfile.TemporaryDirectory() as tmp:
        seed = write_cube(Path(tmp) / "seed.cub", np.zeros((tl, ts), np.float32), tile=(tl, ts))
        text = seed.read_bytes()[:65536].replace(b"      Samples = 422\n", b"      Samples = 5064\n")
        text = text.replace(b"      Lines   = 512\n", b"      Lines   = 52224\n")[:65536]
        path = Path(tmp) / "big.cub"
        tile = np.arange(tl * ts, dtype="<f4").reshape(tl, ts)
        with open(path, "wb") as fh:
            fh.write(text)
            fh.truncate(65536 + lines * samples * 4)
            fh.seek(65536 + (50 * 12 + 5) * tl * ts * 4)
            fh.write(tile.tobytes())
        opens, tiles, rows, whole = [], [], [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            dn = IsisCube(path).pixels(chunks="tile")
            t1 = time.perf_counter()
            got = dn.isel(line=slice(50 * tl, 51 * tl), sample=slice(5 * ts, 6 * ts)).values
            t2 = time.perf_counter()
            IsisCube(path).pixels().isel(line=slice(50 * tl, 51 * tl)).values
            t3 = time.perf_counter()
            opens.append(t1 - t0)
            tiles.append(t2 - t1)
            rows.append(t3 - t2)
        assert np.array_equal(got[0], tile)
        for _ in range(2):
            t0 = time.perf_counter()
            total = float(IsisCube(path).pixels(dtype=np.float64).sum().values)
            whole.append(time.perf_counter() - t0)
        assert total == float(tile.astype(np.float64).sum())
    med = statistics.median
    print(json.dumps({
        "lines": lines, "samples": samples, "tile": [tl, ts], "core_gb": round(lines * samples * 4 / 1e9, 2),
        "open_s": round(med(opens), 4), "one_tile_s": round(med(tiles), 4), "one_tile_row_s": round(med(rows), 4),
        "whole_image_s": round(med(whole), 2), "whole_over_tile": round(med(whole) / med(tiles), 0),
        "load_average": os.getloadavg()[0],
    }))


if __name__ == "__main__":
    main()

"""Fuzz every reader of outside files with a large budget (the suite runs 200 inputs per reader).

    python bench/fuzz.py                      # 10,000 inputs per reader, fresh random draws
    python bench/fuzz.py --budget 500 --readers rpc_txt network
    python bench/fuzz.py --collect            # list every distinct breach instead of stopping at the first

Inputs and the contract are those of ``tests/test_fuzz_readers.py`` (``tests/fuzzhelp.py``,
``tests/fuzz_targets.py``): a mutated real file or a random input; the reader must return a usable
result or raise a named lunarmap exception, within the time limit, leaving no file behind. Readers
that exercise several targets (``image_support``: one per kernel set) split the budget between them.
Prints per reader the inputs run, how they ended and the time; exits 1 on a breach.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import fuzzhelp  # noqa: E402
from fuzz_targets import READERS, build_targets  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--budget", type=int, default=10_000, help="inputs per reader (default 10,000)")
    ap.add_argument("--readers", nargs="*", default=sorted(READERS), choices=sorted(READERS))
    ap.add_argument("--seed", type=int, default=None, help="random seed (default: a fresh one, printed)")
    ap.add_argument("--collect", action="store_true", help="collect every distinct breach, do not stop")
    ap.add_argument("--deadline", default=None,
                    help="UTC time HH:MM after which no reader starts another chunk of inputs (the figures "
                         "then say how many inputs each reader actually ran)")
    ap.add_argument("--chunk", type=int, default=1000, help="inputs per hypothesis run (default 1,000)")
    args = ap.parse_args(argv)
    deadline = None
    if args.deadline:
        import datetime as _dt

        hh, mm = (int(v) for v in args.deadline.split(":"))
        now = _dt.datetime.now(_dt.timezone.utc)
        deadline = now.replace(hour=hh, minute=mm, second=0, microsecond=0).timestamp()
    seed = args.seed if args.seed is not None else int.from_bytes(os.urandom(4), "little")
    print(f"seed {seed}, budget {args.budget} inputs per reader, load average {os.getloadavg()[0]:.2f}", flush=True)
    if args.collect:
        fuzzhelp.COLLECT = {}
    with tempfile.TemporaryDirectory(prefix="lunarmap_fuzz_") as tmp:
        targets = build_targets(tmp)
        failed = False
        total_inputs, t_all = 0, time.perf_counter()
        for reader in args.readers:
            mine = [targets[n] for n in READERS[reader] if n in targets]
            if not mine:
                print(f"{reader:14s} skipped: no seed files (shared kernel sets absent)")
                continue
            per = -(-args.budget // len(mine))
            t0 = time.perf_counter()
            try:
                # in chunks of fresh draws (a new seed each), so that a deadline can end a reader between them
                done = {t.name: 0 for t in mine}
                k = 0
                while any(done[t.name] < per for t in mine):
                    if deadline is not None and time.time() > deadline:
                        print(f"{reader:14s} deadline reached", flush=True)
                        break
                    for j, target in enumerate(mine):
                        if done[target.name] >= per:
                            continue
                        n_chunk = min(args.chunk, per - done[target.name])
                        fuzzhelp.fuzz(target, max_examples=n_chunk, derandomize=False,
                                      seed=seed + 1000 * k + j)
                        done[target.name] += n_chunk
                    k += 1
                    ran = sum(sum(fuzzhelp.COUNTS[t.name].values()) for t in mine)
                    print(f"{reader:14s} ... {ran} inputs at {time.perf_counter() - t0:.0f} s", flush=True)
            except AssertionError as err:
                failed = True
                print(f"{reader:14s} BREACH: {str(err).splitlines()[0]}", flush=True)
            counts = sum((fuzzhelp.COUNTS[t.name] for t in mine), start=fuzzhelp.collections.Counter())
            n = sum(counts.values())
            total_inputs += n
            outcomes = ", ".join(f"{k} {v}" for k, v in counts.most_common())
            slow = max((fuzzhelp.SLOWEST[t.name] for t in mine if t.name in fuzzhelp.SLOWEST), default=(0.0, "", 0))
            grow = max((fuzzhelp.PEAK_GROWTH[t.name] for t in mine if t.name in fuzzhelp.PEAK_GROWTH),
                       default=(0.0, "", 0))
            over = sum(fuzzhelp.OVER_TIME[t.name] for t in mine)
            print(f"{reader:14s} {n:7d} inputs in {time.perf_counter() - t0:7.1f} s: {outcomes}", flush=True)
            print(f"{'':14s} slowest {slow[0]:.2f} s ({slow[2]} bytes from {slow[1]}), {over} over "
                  f"{fuzzhelp.TIME_BUDGET:g} s; largest peak growth {grow[0]:.1f} MB ({grow[2]} bytes from {grow[1]})",
                  flush=True)
        print(f"total {total_inputs} inputs in {time.perf_counter() - t_all:.0f} s, "
              f"load average {os.getloadavg()[0]:.2f}, peak RSS of the process "
              f"{fuzzhelp.PEAK_RSS_KB[0] / 1024:.0f} MB")
        if fuzzhelp.COLLECT:
            failed = True
            print("\nbreaches:")
            for (target, err, where), example in sorted(fuzzhelp.COLLECT.items()):
                print(f"  {target}: {err} at {where}\n      {example}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

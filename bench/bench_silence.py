"""Longest silence on stderr of a command: every stderr line timestamped as it arrives.

    python bench/bench_silence.py [--log FILE] -- make demo
    python bench/bench_silence.py -- .venv/bin/lunarmap run --example --output /tmp/demo

Prints the command's stderr lines with their time since the start, then the longest gaps between
lines (from the start to the first line, between lines, from the last line to the end) and where
they were. The acceptance figure of issue 29 is the longest gap of ``make demo``: at most 10 s.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", help="also write the timestamped stderr lines to this file")
    ap.add_argument("--top", type=int, default=5, help="longest gaps to print")
    ap.add_argument("command", nargs=argparse.REMAINDER)
    args = ap.parse_args(argv)
    cmd = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not cmd:
        ap.error("a command is needed after --")
    t0 = time.monotonic()
    stamps: list[tuple[float, str]] = []
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)

    def out() -> None:
        for line in proc.stdout:    # type: ignore[union-attr]
            sys.stdout.write(line)

    # pip's progress bars end their updates with '\r': read by character chunks and split on both
    def err() -> None:
        buf = ""
        while True:
            chunk = proc.stderr.read(1)   # type: ignore[union-attr]
            if not chunk:
                break
            if chunk in "\r\n":
                if buf.strip():
                    stamps.append((time.monotonic() - t0, buf))
                buf = ""
            else:
                buf += chunk
        if buf.strip():
            stamps.append((time.monotonic() - t0, buf))

    threads = [threading.Thread(target=out, daemon=True), threading.Thread(target=err, daemon=True)]
    for t in threads:
        t.start()
    rc = proc.wait()
    for t in threads:
        t.join()
    total = time.monotonic() - t0
    lines = [f"{t:8.1f} {s}" for t, s in stamps]
    if args.log:
        with open(args.log, "w") as fh:
            fh.write("\n".join(lines) + "\n")
    times = [0.0] + [t for t, _ in stamps] + [total]
    labels = ["(start)"] + [s for _, s in stamps] + ["(end)"]
    gaps = sorted(((times[k + 1] - times[k], k) for k in range(len(times) - 1)), reverse=True)
    print(f"\n{len(stamps)} stderr lines in {total:.1f} s, exit status {rc}", file=sys.stderr)
    for gap, k in gaps[:args.top]:
        print(f"  silence {gap:6.1f} s at {times[k]:7.1f} s after: {labels[k][:110]}", file=sys.stderr)
    print(f"longest silence: {gaps[0][0]:.1f} s", file=sys.stderr)
    return rc


if __name__ == "__main__":
    sys.exit(main())

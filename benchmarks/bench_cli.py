"""Start-up time of the ``tunnelsim`` command: ``--version`` and every ``<command> --help``,
best of N runs (warm: the second and later runs of a fresh process each).

Target (issue 14): <= 0.3 s warm on the project's 2-core VM.

    python benchmarks/bench_cli.py [--runs 5] [--exe .venv/bin/tunnelsim]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time


def best_of(argv: list[str], runs: int) -> float:
    best = float("inf")
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--exe", default=shutil.which("tunnelsim") or "tunnelsim")
    args = ap.parse_args()
    from survey.cli.main import build_parser  # only to list the commands

    commands = sorted(build_parser()[1])
    python = best_of([sys.executable, "-c", "pass"], args.runs)
    rows = [("--version", best_of([args.exe, "--version"], args.runs))]
    rows += [(f"{c} --help", best_of([args.exe, c, "--help"], args.runs)) for c in commands]
    print(f"bare Python start: {python:.3f} s; best of {args.runs}")
    print("| command | seconds |\n|---|---:|")
    for name, s in rows:
        print(f"| `tunnelsim {name}` | {s:.3f} |")
    worst = max(s for _n, s in rows)
    print(f"slowest: {worst:.3f} s (target <= 0.3 s): {'met' if worst <= 0.3 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

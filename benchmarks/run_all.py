"""`make bench`: run every benchmark in benchmarks/, each writing its table (and plot) to benchmarks/results/.

    .venv/bin/python -m benchmarks.run_all [--only NAME ...] [--skip NAME ...]

Every module of this folder except this one and private ones (`_*`) is a benchmark, found at run time so that a
new one is included without editing this file. They run one after the other, each in its own interpreter
(`python -m benchmarks.<name>`, as documented in its docstring) so that one crash or one module's OpenCV thread
setting does not affect the next. The exit code is non-zero when any of them failed.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: Run first (quick checks of the simulator and the hardware path), then the rest alphabetically.
FIRST = ("bench_render", "bench_faults", "bench_calibration", "bench_reconstruction")


def benchmark_names() -> list[str]:
    names = sorted(p.stem for p in HERE.glob("*.py") if not p.stem.startswith("_") and p.stem != "run_all")
    return [n for n in FIRST if n in names] + [n for n in names if n not in FIRST]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=None, help="run only these benchmarks")
    ap.add_argument("--skip", nargs="*", default=[], help="do not run these")
    args = ap.parse_args()
    names = [n for n in benchmark_names() if (args.only is None or n in args.only) and n not in args.skip]
    unknown = set(args.only or []) - set(benchmark_names())
    if unknown:
        print(f"run_all: no benchmark called {', '.join(sorted(unknown))}; there are: {', '.join(benchmark_names())}", file=sys.stderr)
        return 2
    failed = []
    t_all = time.perf_counter()
    for name in names:
        print(f"=== benchmarks.{name}", flush=True)
        t0 = time.perf_counter()
        code = subprocess.call([sys.executable, "-m", f"benchmarks.{name}"], cwd=HERE.parent)
        print(f"=== benchmarks.{name}: {'ok' if code == 0 else f'FAILED (exit {code})'} in {time.perf_counter() - t0:.0f} s", flush=True)
        if code != 0:
            failed.append(name)
    print(f"ran {len(names)} benchmark(s) in {time.perf_counter() - t_all:.0f} s; results in {HERE / 'results'}/")
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

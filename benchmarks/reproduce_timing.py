"""Wall and CPU time of every paper's reproduction at 20 seeds, as the CLI runs it.

Target (issue 13): each reproduction at 20 seeds in <= 60 s WALL on this 2-core machine. Each
reproduction runs as ``python -m navlab reproduce NAME --seeds 20 -q`` in a child process; the
figures are its wall time, the CPU time of it and its worker processes (user + system, from
``wait4``) and the largest resident set of any one of them (not their sum). With ``--base DIR``
(another checkout, e.g. ``git worktree add /tmp/base main``) the same command runs there too,
alternating with this checkout, so that before and after are measured side by side on a machine
shared with others (the load average is printed with each line: read the ratios).

    python benchmarks/reproduce_timing.py [--only hakf] [--seeds 20] [--jobs 2] [--base DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NAMES = ("irakf", "vbekf", "hakf", "nnmfukf")


def measure(checkout: Path, name: str, seeds: int, jobs: str | None) -> tuple[float, float, float]:
    """(wall s, CPU s, peak RSS MB) of one reproduction run in ``checkout``."""
    cmd = [sys.executable, "-m", "navlab", "reproduce", name, "--seeds", str(seeds), "-q"]
    if jobs is not None:
        cmd += ["--jobs", jobs]
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    t0 = time.perf_counter()
    child = subprocess.Popen(cmd, cwd=checkout, env=env, stdout=subprocess.DEVNULL)
    _, status, ru = os.wait4(child.pid, 0)  # the child's usage, its reaped workers' included
    wall = time.perf_counter() - t0
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed in {checkout} (exit {child.returncode})")
    return wall, ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024  # ru_maxrss in kB


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=NAMES, action="append")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--jobs", help="--jobs of this checkout's runs (default: its default)")
    ap.add_argument("--base", type=Path, help="another checkout to time beside this one")
    a = ap.parse_args()
    print(f"{os.cpu_count()} CPUs; {a.seeds} seeds; peak MB = the largest process of a run")
    print(f"{'reproduction':10s} {'checkout':8s} {'wall s':>7s} {'CPU s':>7s} {'peak MB':>8s}  load")
    for name in a.only or NAMES:
        runs = [("base", a.base, None)] if a.base else []
        runs.append(("this", ROOT, a.jobs))
        for label, where, jobs in runs:
            wall, cpu, rss = measure(where, name, a.seeds, jobs)
            load = " ".join(f"{v:.1f}" for v in os.getloadavg())
            print(f"{name:10s} {label:8s} {wall:7.1f} {cpu:7.1f} {rss:8.0f}  {load}", flush=True)


if __name__ == "__main__":
    main()

"""What ``navlab bench`` costs here, serially and on a 2-worker cluster, and that it resumes.

    python benchmarks/bench_scale.py [--suite small|tiny] [--kill-after 50] [--workers 2]

Prints, on this machine now (each with the load average before and after: on a shared machine
the wall times move with it):

1. the suite in this process (``--scheduler serial``), each task computed (a fresh store);
2. the suite on a ``distributed.LocalCluster`` of ``--workers`` worker processes, one thread
   each (a fresh store), and whether its rows equal the serial ones (every column but the
   timing ``us_per_run_step``);
3. ``navlab bench`` as a child process killed with SIGKILL after ``--kill-after`` seconds, the
   tasks it left in the store, then the same command again: the time to finish, and whether its
   rows equal the serial ones;
4. every task from the store (the serial run again): the statistics of the tables alone;
5. the suite's cost on paper (:func:`navlab.bench.estimate`) for comparison with 1 and 2.

``tiny`` (2 cv2d problems of 40 epochs, 4 filters) checks the script in a minute.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from navlab import bench as BN  # noqa: E402
from navlab.cluster import DaskExecutor, SerialExecutor  # noqa: E402
from navlab.store import Store  # noqa: E402

TIMING = ["us_per_run_step"]


def load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load {one:.2f} {five:.2f} {fifteen:.2f}"


def same(a, b) -> bool:
    import pandas as pd

    x = BN.rows(a).drop(columns=TIMING, errors="ignore").reset_index(drop=True)
    y = BN.rows(b).drop(columns=TIMING, errors="ignore").reset_index(drop=True)
    try:
        pd.testing.assert_frame_equal(x, y)
    except AssertionError:
        return False
    return True


def timed(label: str, fn):
    before = load()
    t0 = time.perf_counter()
    out = fn()
    dt = time.perf_counter() - t0
    print(f"{label}: {dt:.1f} s ({before} → {load()})", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--suite", choices=["small", "tiny"], default="small")
    ap.add_argument("--kill-after", type=float, default=50.0)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    suite = BN.get_suite(a.suite)
    filters = ["kf", "huber-kf", "chi2-kf", "oracle-kf"] if a.suite == "tiny" else None
    tmp = Path(tempfile.mkdtemp(prefix="bench-scale-"))
    print(f"{suite.describe()}; stores under {tmp}", flush=True)

    serial = timed(
        "1. serial",
        lambda: BN.run(suite, filters=filters, store=Store(tmp / "serial"), executor=SerialExecutor()),
    )
    print(f"   {serial.computed} tasks computed", flush=True)

    import distributed

    cluster = distributed.LocalCluster(
        n_workers=a.workers, threads_per_worker=1, processes=True, dashboard_address=":0", host="127.0.0.1"
    )
    try:
        with distributed.Client(cluster, set_as_default=False) as c:
            c.wait_for_workers(a.workers, timeout=300)
            ex = DaskExecutor(c, f"{a.workers}-worker LocalCluster")
            par = timed(
                f"2. {a.workers}-worker cluster",
                lambda: BN.run(suite, filters=filters, store=Store(tmp / "cluster"), executor=ex),
            )
    finally:
        cluster.close()
    print(f"   same numbers as serial: {same(par, serial)}", flush=True)

    if a.suite == "small":
        store = tmp / "kill"
        cmd = [sys.executable, "-m", "navlab", "bench", "--suite", a.suite, "--scheduler", "serial"]
        cmd += ["--store", str(store), "--outdir", str(tmp / "out"), "-q", "--out", os.devnull]
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        child = subprocess.Popen(cmd, env=env)
        time.sleep(a.kill_after)
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
        kept = len(Store(store).files())
        print(f"3. killed (SIGKILL) after {a.kill_after:g} s with {kept} tasks in the store", flush=True)
        resumed = timed(
            "   resumed",
            lambda: BN.run(suite, filters=filters, store=Store(store), executor=SerialExecutor()),
        )
        print(
            f"   {resumed.computed} computed, {resumed.cached} from the store; same numbers as serial: "
            f"{same(resumed, serial)}",
            flush=True,
        )

    cached = timed(
        "4. every task from the store (the tables' statistics alone)",
        lambda: BN.run(suite, filters=filters, store=Store(tmp / "serial"), executor=SerialExecutor()),
    )
    print(f"   {cached.computed} computed, {cached.cached} from the store", flush=True)

    _, tot = BN.estimate(suite, filters, workers=(1, a.workers, 8, 64))
    walls = ", ".join(f"{w}: {v:.0f} s" for w, v in tot["wall_s"].items())
    print(
        f"5. on paper: {tot['tasks']} tasks, {3600 * tot['cpu_hours']:.0f} s of tasks; "
        f"wall by workers {walls}"
    )


if __name__ == "__main__":
    main()

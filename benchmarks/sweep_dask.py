"""A 16-task sweep on 2 local Dask workers against the serial path, side by side.

    python benchmarks/sweep_dask.py [--workers 2] [--runs 100] [--epochs 300] [--repeat 2]

Prints the time of the same 16 tasks (one filter × 16 values of its parameter, --runs runs each)
computed in this process and on an embedded LocalCluster (started and warmed beforehand: its
start-up is reported apart), their ratio (target ≥ 1.6× on 2 cores), the cluster's per-task
overhead (100 empty tasks) and the overhead implied by the sweep (workers × cluster time −
serial time, per task). Results are checked equal. No results store: every task is computed.
The machine's load average is printed too: on a shared machine the ratio moves with it.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def noop(i: int) -> int:
    return i


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()

    import numpy as np
    from distributed import Client, LocalCluster

    from navlab import sweep as SW
    from navlab import tasks as T
    from navlab.cluster import DaskExecutor, SerialExecutor
    from navlab.experiment import ExperimentSpec

    spec = ExperimentSpec(filters=("huber-kf",), runs=a.runs, epochs=a.epochs, contamination=0.1)
    axis = SW.Axis(SW.resolve(spec, "huber-kf.gamma"), tuple(np.geomspace(0.3, 30, 16)))
    tasks = SW.make_sweep(spec, [axis]).all_tasks()
    assert len(tasks) == 16

    t0 = time.perf_counter()
    cluster = LocalCluster(
        n_workers=a.workers, threads_per_worker=1, processes=True, dashboard_address=":0", host="127.0.0.1"
    )
    client = Client(cluster, set_as_default=False)
    client.wait_for_workers(a.workers)
    start_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    # warm: every worker imports navlab and runs one small task
    client.gather(
        [
            client.submit(T.run_task, T.Task(spec.replace(runs=1), 0), key=f"warm-{i}")
            for i in range(a.workers)
        ]
    )
    warm_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    client.gather([client.submit(noop, i, pure=False) for i in range(100)])
    noop_ms = 1e3 * (time.perf_counter() - t0) / 100

    ser, par = [], []
    for _ in range(a.repeat):  # interleaved, so both see the same machine load
        t0 = time.perf_counter()
        r_ser = T.compute(tasks, executor=SerialExecutor())
        ser.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        r_par = T.compute(tasks, executor=DaskExecutor(client, "bench"))
        par.append(time.perf_counter() - t0)
    for t in tasks:
        assert (r_ser[t.key].stats.sse["pos"] == r_par[t.key].stats.sse["pos"]).all()
    s, p = min(ser), min(par)
    per_task = sum(r.elapsed_s for r in r_ser.values()) / len(tasks)
    implied = (a.workers * p - s) / len(tasks)
    load = os.getloadavg()
    print(
        f"16 tasks: huber-kf on cv2d, {a.runs} runs × {a.epochs} epochs each "
        f"({per_task:.3f} s of work per task)"
    )
    print(f"cluster start {start_s:.2f} s, warm-up (import navlab on {a.workers} workers) {warm_s:.2f} s")
    print(f"serial                 {s:7.2f} s   (runs: {', '.join(f'{x:.2f}' for x in ser)})")
    print(f"{a.workers} local workers        {p:7.2f} s   (runs: {', '.join(f'{x:.2f}' for x in par)})")
    print(f"speed-up               {s / p:7.2f}×  (target ≥ 1.6× on 2 cores)")
    print(
        f"per-task overhead      {noop_ms:7.2f} ms (100 empty tasks); "
        f"{1e3 * implied:.1f} ms implied by the sweep"
    )
    print(f"load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} on {os.cpu_count()} cores")
    client.close()
    cluster.close()


if __name__ == "__main__":
    main()

"""The figures behind the default executor's choice (navlab.cluster): what the embedded cluster's
start costs, and when a warm one beats this process.

    python benchmarks/sweep_dask.py [--workers 2] [--runs 100] [--epochs 300] [--repeat 3]

Prints, on this machine now:

* the embedded cluster's start-up as navlab does it (``navlab.cluster.Embedded``: LocalCluster up,
  then every worker warmed on one run of the filter), against ``START_S``;
* the cluster's per-task overhead (100 empty tasks);
* a 16-task and a 4-task job (one filter × values of its parameter, --runs runs each) in this
  process and on the warm cluster, interleaved so both see the same load (min of --repeat), the
  speed-up, and from the two sizes the fixed cost of a job on the warm cluster and the work where
  it breaks even, against ``PAYS_S``; results are checked equal;
* where the default executor (``navlab.cluster.LocalExecutor``, with this warm cluster) runs the
  16 tasks, and why;
* with ``--long N`` (0: skip): a job of N tasks run serially and by the default executor with no
  cluster up (it starts one in the background when the work is long enough and hands over), in
  turn, each --repeat times: is a cold start worth it at that size (``START_FACTOR``)?

No results store: every task is computed. The load average is printed: on a shared machine the
figures move with it (a busy machine gives 2 workers less than 2 cores).
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
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--long", type=int, default=0, help="tasks of the cold-start comparison (e.g. 120)")
    a = ap.parse_args()

    import numpy as np

    from navlab import cluster as C
    from navlab import sweep as SW
    from navlab import tasks as T
    from navlab.experiment import ExperimentSpec

    print(f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    spec = ExperimentSpec(filters=("huber-kf",), runs=a.runs, epochs=a.epochs, contamination=0.1)

    def job(n: int, seed: int) -> list:
        axis = SW.Axis(SW.resolve(spec, "huber-kf.gamma"), tuple(np.geomspace(0.3, 30, n)))
        return SW.make_sweep(spec.replace(seed=seed), [axis]).all_tasks()

    emb = C.Embedded()
    t0 = time.perf_counter()
    client = emb.wait(a.workers, T.run_task, [job(1, 0)[0].probe()])
    print(
        f"embedded cluster start-up (up + {a.workers} workers warm) {time.perf_counter() - t0:6.2f} s"
        f"   (navlab assumes START_S = {C.START_S:g} s; starts it above {C.START_FACTOR:g} × that)"
    )
    t0 = time.perf_counter()
    client.gather([client.submit(noop, i, pure=False) for i in range(100)])
    print(f"per-task overhead {1e3 * (time.perf_counter() - t0) / 100:6.2f} ms (100 empty tasks)")

    T.compute(job(2, 1))  # this process's kernels loaded, as in a running app
    cost: dict[int, tuple[float, float, float]] = {}
    for n in (16, 4):
        ser, par = [], []
        for r in range(a.repeat):  # interleaved; a new seed each time: nothing is cached
            tasks = job(n, 100 + r)
            t0 = time.perf_counter()
            want = T.compute(tasks, executor=C.SerialExecutor())
            ser.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            got = T.compute(tasks, executor=C.DaskExecutor(client, "bench"))
            par.append(time.perf_counter() - t0)
            for t in tasks:
                assert (want[t.key].stats.sse["pos"] == got[t.key].stats.sse["pos"]).all()
        s, p = min(ser), min(par)
        cost[n] = (s, p, s / p)
        print(
            f"{n:2d} tasks ({s / n:.3f} s each): this process {s:6.2f} s, warm cluster {p:6.2f} s, "
            f"speed-up {s / p:4.2f}×   (runs: {', '.join(f'{x:.2f}' for x in ser)} | "
            f"{', '.join(f'{x:.2f}' for x in par)})"
        )
    (s1, p1, _), (s2, p2, _) = cost[16], cost[4]
    slope = (p1 - p2) / (s1 - s2)  # cluster seconds per second of serial work
    fixed = p1 - slope * s1
    even = fixed / (1 - slope) if slope < 1 else float("inf")
    print(
        f"warm cluster: {fixed:.2f} s per job + {slope:.2f} s per second of work → breaks even at "
        f"{even:.2f} s of work   (navlab's PAYS_S = {C.PAYS_S:g} s)"
    )
    ex = C.LocalExecutor(a.workers, embedded=emb)
    t0 = time.perf_counter()
    T.compute(job(16, 999), executor=ex)
    print(f"default executor, 16 tasks: {time.perf_counter() - t0:.2f} s, ran {ex.report}")
    emb.close()
    for r in range(a.repeat if a.long else 0):
        tasks = job(a.long, 2000 + r)
        t0 = time.perf_counter()
        T.compute(tasks, executor=C.SerialExecutor())
        ser = time.perf_counter() - t0
        ex = C.LocalExecutor(a.workers, embedded=C.Embedded())
        t0 = time.perf_counter()
        T.compute(job(a.long, 3000 + r), executor=ex)
        auto = time.perf_counter() - t0
        ex.embedded.close()
        print(
            f"{a.long} tasks, no cluster up: serial {ser:6.1f} s, default executor {auto:6.1f} s "
            f"(ratio {auto / ser:.2f}; load {os.getloadavg()[0]:.1f}): ran {ex.report}"
        )


if __name__ == "__main__":
    main()

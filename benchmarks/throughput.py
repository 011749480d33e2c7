"""Monte Carlo throughput: navlab's batched `kf` against a FilterPy KalmanFilter loop.

Same cv2d workload (100 epochs, the same simulated measurements) for 1, 100 and 1000 runs,
measured side by side in one process; prints filter-steps per second and the ratio. Also times
a default Compare run (cv2d, 100 runs, kf + oracle-kf + chi2-kf). Not a test: these machines
are shared and noisy, so read the ratio, not the absolute figures.

    python benchmarks/throughput.py [--repeat 3] [--runs 1,100,1000]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, no install

from navlab.experiment import ExperimentSpec, plan, run_experiment, run_filters
from navlab.filters import make_filter


def best_of(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def filterpy_loop(data):
    from filterpy.kalman import KalmanFilter

    m = data.model
    xs = np.empty_like(data.x_true)
    for b in range(data.B):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.F, kf.Q, kf.H, kf.R = m.F_, m.Q_, m.H_, m.R0
        kf.x, kf.P = data.x0[b].copy(), data.P0.copy()
        xs[b, 0] = kf.x
        for k in range(1, data.K + 1):
            kf.predict()
            kf.update(data.z[b, k])
            xs[b, k] = kf.x
    return xs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--runs", default="1,100,1000")
    a = ap.parse_args()

    print("cv2d, 100 epochs; steps = runs x epochs; best of", a.repeat)
    print(f"{'runs':>6} {'navlab kf steps/s':>18} {'filterpy steps/s':>17} {'ratio':>7} {'max |dx|':>9}")
    for runs in [int(r) for r in a.runs.split(",")]:
        p = plan(ExperimentSpec(filters=("kf",), runs=runs, seed=1, outliers="mixture"))
        data = p.scenario.simulate(p.schedule, p.outliers, range(runs), 1)
        steps = runs * data.K
        t_nav, out = best_of(lambda: run_filters(data, [make_filter("kf")]), a.repeat)  # noqa: B023
        t_fp, xs = best_of(lambda: filterpy_loop(data), 1 if runs >= 1000 else a.repeat)  # noqa: B023
        dx = np.max(np.abs(out["kf"].x - xs))
        print(f"{runs:6d} {steps / t_nav:18,.0f} {steps / t_fp:17,.0f} {t_fp / t_nav:7.1f} {dx:9.1e}")

    spec = ExperimentSpec(filters=("kf", "oracle-kf", "chi2-kf"), runs=100, seed=1)
    t, _ = best_of(lambda: run_experiment(spec), a.repeat)
    print(f"default compare run (cv2d, 100 runs x 100 epochs, 3 filters, with metrics): {t:.3f} s")


if __name__ == "__main__":
    main()

"""Monte Carlo throughput: navlab's batched `kf` against a FilterPy KalmanFilter loop.

Same cv2d workload (100 epochs, the same simulated measurements) for 1, 100 and 1000 runs,
measured side by side in one process; prints filter-steps per second and the ratio. Also times
a default Compare run (cv2d, 100 runs, kf + oracle-kf + chi2-kf).

The whole pipeline (issue 13, target ≥ 60× FilterPy): simulate + filter + record + metrics,
``run_experiment(spec).metrics()`` for `kf` on cv2d (100 epochs, the default mixture outliers)
at two sizes (``--pipeline-runs``, default 1000 and 10 000 runs); the MARGINAL throughput is the
extra steps over the extra time between them (what one more run costs, start-up costs cancel).
Its split at the larger size: simulation (``Scenario.simulate``), the filter (``runtime_s``),
metrics (``Results.metrics``) and the rest of ``run_experiment`` (driver + recorder), and the
floor set by random-number generation (the same draws as the simulation, nothing else).
The same through the CLI: ``python -m navlab run --scenario cv2d --filters kf --runs N -q`` once
at each size in a child process (what one more run costs a user of the CLI, who also gets the
table with its intervals and the diagnostics), with numpy's huge pages as the CLI sets them and
as numpy sets them (``NUMPY_MADVISE_HUGEPAGE=1``, see navlab/__main__.py), and its ratio to the
in-process figure (``--cli`` 0 to skip).
Not a test: these machines are shared and noisy, so read the ratios, not the absolute figures;
every time is the best of ``--repeat`` (default 7: with 3 the marginal ratio ranged 46–65× over
a dozen runs on one quiet 2-core machine, with 7 it ranged 63–69× over six).

    python benchmarks/throughput.py [--repeat 7] [--runs 1,100,1000] [--pipeline-runs 1000,10000] [--cli 1]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, no install

from navlab.experiment import ExperimentSpec, plan, run_experiment, run_filters
from navlab.filters import make_filter
from navlab.scenarios.base import run_streams

ROOT = Path(__file__).resolve().parents[1]


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


def rng_floor(runs: int, K: int, m: int, n: int, truth_dim: int, seed: int = 1) -> None:
    """Only the draws of cv2d with mixture outliers: truth (K, 2), init (4), meas 2 × (K+1, m)."""
    s = run_streams(seed, range(runs))
    s.truth.standard_normal((K, truth_dim))
    s.init.standard_normal(n)
    s.meas.standard_normal((K + 1, m))
    s.meas.random((K + 1, m))


def cli_run(runs: int, env: dict[str, str]) -> tuple[float, float]:
    """(wall s, CPU s of user + system) of one ``python -m navlab run`` of kf on cv2d."""
    cmd = [sys.executable, "-m", "navlab", "run", "--scenario", "cv2d", "--filters", "kf"]
    cmd += ["--runs", str(runs), "--epochs", "100", "--seed", "1", "-q"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), **env}
    t0 = time.perf_counter()
    child = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL)
    _, status, ru = os.wait4(child.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"{' '.join(cmd)} failed")
    return wall, ru.ru_utime + ru.ru_stime


def cli(sizes: list[int], K: int, fp: float, marg: float) -> None:
    """The marginal throughput through the CLI, one child process per size (alternating)."""
    lo, hi = sizes[0], sizes[-1]
    print(f"through the CLI (python -m navlab run ... -q, one run at {lo} and at {hi} runs; a child's")
    print("start-up varies by seconds on a loaded machine, so the CPU figure is the steadier one):")
    variants = (("as the CLI runs", {}), ("numpy huge pages", {"NUMPY_MADVISE_HUGEPAGE": "1"}))
    for name, env in variants:
        (w_lo, c_lo), (w_hi, c_hi) = cli_run(lo, env), cli_run(hi, env)
        m, mc = (hi - lo) * K / (w_hi - w_lo), (hi - lo) * K / (c_hi - c_lo)
        load = " ".join(f"{v:.1f}" for v in os.getloadavg())
        print(
            f"  {name}: wall {w_lo:.2f} -> {w_hi:.2f} s, CPU {c_lo:.2f} -> {c_hi:.2f} s (load {load})\n"
            f"    marginal by wall {m:,.0f} steps/s = {m / fp:.1f}x FilterPy = {m / marg:.2f} of in-process; "
            f"by CPU {mc:,.0f} steps/s = {mc / fp:.1f}x = {mc / marg:.2f}"
        )


def pipeline(sizes: list[int], repeat: int, with_cli: bool = True) -> None:
    spec0 = ExperimentSpec(filters=("kf",), runs=sizes[0], seed=1, epochs=100)
    p = plan(spec0)
    fp_runs = 300
    data = p.scenario.simulate(p.schedule, p.outliers, range(fp_runs), 1)
    t_fp, _ = best_of(lambda: filterpy_loop(data), repeat)
    fp = fp_runs * data.K / t_fp
    K, m, n = data.K, data.z.shape[2], data.x0.shape[1]
    print(f"\nwhole pipeline, kf on cv2d ({K} epochs, mixture outliers); best of {repeat}")
    print(f"FilterPy loop: {fp:,.0f} steps/s ({fp_runs} runs)")
    print(f"{'runs':>6} {'pipeline s':>10} {'steps/s':>12} {'x FilterPy':>10}")
    times = {}
    for runs in sizes:
        spec = spec0.replace(runs=runs)
        t, _ = best_of(lambda: run_experiment(spec).metrics(), repeat)  # noqa: B023
        times[runs] = t
        print(f"{runs:6d} {t:10.3f} {runs * K / t:12,.0f} {runs * K / t / fp:10.1f}")
    lo, hi = sizes[0], sizes[-1]
    marg = (hi - lo) * K / (times[hi] - times[lo])
    print(f"marginal {lo} -> {hi} runs: {marg:,.0f} steps/s = {marg / fp:.1f}x FilterPy (target 60x)")
    if with_cli:
        cli(sizes, K, fp, marg)

    # where the time goes at the larger size: timers inside one run_experiment (best of `repeat`)
    spec = spec0.replace(runs=hi)
    cls = type(p.scenario)
    simulate = cls.simulate
    best = None
    for _ in range(repeat):
        spent = []

        def timed_simulate(self, *args, spent=spent):
            t0 = time.perf_counter()
            out = simulate(self, *args)
            spent.append(time.perf_counter() - t0)
            return out

        cls.simulate = timed_simulate
        try:
            t0 = time.perf_counter()
            res = run_experiment(spec)
            t_run = time.perf_counter() - t0
        finally:
            cls.simulate = simulate
        t0 = time.perf_counter()
        res.metrics()
        t_met = time.perf_counter() - t0
        t_filt = sum(fr.runtime_s for fr in res.runs.values())
        parts = (t_run + t_met, sum(spent), t_filt, t_run - sum(spent) - t_filt, t_met)
        best = parts if best is None or parts[0] < best[0] else best
        del res
    total, t_sim, t_filt, rest, t_met = best
    t_rng, _ = best_of(lambda: rng_floor(hi, K, m, n, 2), repeat)
    print(f"split at {hi} runs (one run_experiment + metrics, {total:.3f} s):")
    for name, t in (
        ("simulation", t_sim),
        ("  of which random draws", t_rng),
        ("filter (kf)", t_filt),
        ("driver + recorder", rest),
        ("metrics", t_met),
    ):
        print(f"  {name:24s} {t:7.3f} s {100 * t / total:5.1f} %")
    print(
        f"random draws alone: {hi * K / t_rng:,.0f} steps/s = {hi * K / t_rng / fp:.0f}x FilterPy "
        "(the ceiling of a pipeline that draws them)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7, help="best of this many (the uncontended time)")
    ap.add_argument("--runs", default="1,100,1000")
    ap.add_argument("--pipeline-runs", default="1000,10000", help="two sizes ('' to skip)")
    ap.add_argument("--cli", type=int, default=1, help="1: time the pipeline through the CLI too")
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
    if a.pipeline_runs:
        pipeline([int(r) for r in a.pipeline_runs.split(",")], a.repeat, bool(a.cli))


if __name__ == "__main__":
    main()

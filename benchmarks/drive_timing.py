"""drive0708 with 7 filters x 10 runs: compute time, compiled vs numpy kernels, and the split.

Target (issue 13): kf, huber-kf, vb-akf, hakf, sage-husa, irakf, chi2-kf x 10 runs on the real
drive in <= 1.5 s of compute. Measured side by side in one process: ``run_experiment`` (simulate
+ filters + record; the drive's one-off set-up and reference solution are cached per process and
excluded) with navlab's compiled kernels (numba, navlab.jit: the strapdown mechanisation, the
rotation-vector conversions) and with their numpy reference paths. Compute = CPU seconds of this
process (``time.process_time``; BLAS single-threaded, so a busy second core does not count
twice), and wall seconds. Then where the time goes with the compiled path: the model's calls
(``InsGnssModel.f`` = the mechanisation + the conversions around it; ``h``/``H``), the filters'
own arithmetic (their runtime minus the model calls) and simulate + driver + recorder (the rest).

    NAVLAB_DATA=../shared/data python benchmarks/drive_timing.py [--repeat 3] [--runs 10]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy is imported

import argparse  # noqa: E402
import contextlib  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, no install

from navlab import jit  # noqa: E402
from navlab.experiment import ExperimentSpec, run_experiment  # noqa: E402
from navlab.ins import lc  # noqa: E402

FILTERS = ("kf", "huber-kf", "vb-akf", "hakf", "sage-husa", "irakf", "chi2-kf")


def timed(fn, repeat):
    best = (float("inf"), float("inf"), None)
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        out = fn()
        best = min(best, (time.process_time() - c0, time.perf_counter() - w0, out), key=lambda b: b[0])
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--runs", type=int, default=10)
    a = ap.parse_args()
    spec = ExperimentSpec(scenario="drive0708", filters=FILTERS, runs=a.runs, seed=1)
    w0 = time.perf_counter()
    run_experiment(spec.replace(runs=1, filters=("kf",)))  # drive set-up, reference, kernel load
    print(
        f"first call in this process (set-up, reference solution, kernels): {time.perf_counter() - w0:.2f} s"
    )
    print(f"drive0708, {len(FILTERS)} filters x {a.runs} runs, best of {a.repeat} (compute = CPU s)")

    results = {}
    for label in ("compiled", "numpy") if jit.enabled() else ("numpy",):
        with jit.numpy_paths() if label == "numpy" else contextlib.nullcontext():
            cpu, wall, res = timed(lambda: run_experiment(spec), a.repeat)
        results[label] = (cpu, wall, res)
        print(f"  kernels {label:8s}: {cpu:6.2f} s compute, {wall:6.2f} s wall (target 1.5 s)")
    if len(results) == 2:
        print(f"  compiled / numpy: {results['numpy'][0] / results['compiled'][0]:.1f}x faster")
        x_c, x_n = results["compiled"][2].runs["kf"].x, results["numpy"][2].runs["kf"].x
        print(f"  max |x_compiled - x_numpy| (kf): {abs(x_c - x_n).max():.1e}")
    print(f"  numba: {'on' if jit.enabled() else 'off'}")

    # where the time goes (compiled path if available)
    spent: dict[str, float] = defaultdict(float)
    originals = {}

    def wrap(owner, name, bucket):
        orig = getattr(owner, name)
        originals[(owner, name)] = orig

        def timed_call(*args, **kw):
            t0 = time.perf_counter()
            try:
                return orig(*args, **kw)
            finally:
                spent[bucket] += time.perf_counter() - t0

        setattr(owner, name, timed_call)

    wrap(lc, "propagate_block", "mechanisation (propagate_block)")
    wrap(lc.InsGnssModel, "f", "model.f")
    wrap(lc.InsGnssModel, "h", "model.h, model.H")
    wrap(lc.InsGnssModel, "H", "model.h, model.H")
    t0 = time.perf_counter()
    res = run_experiment(spec)
    total = time.perf_counter() - t0
    for (owner, name), orig in originals.items():
        setattr(owner, name, orig)
    filt = sum(fr.runtime_s for fr in res.runs.values())
    model = spent["model.f"] + spent["model.h, model.H"]
    parts = {
        "mechanisation (propagate_block)": spent["mechanisation (propagate_block)"],
        "model.f around it (state <-> total)": spent["model.f"] - spent["mechanisation (propagate_block)"],
        "model.h, model.H": spent["model.h, model.H"],
        "filters' own arithmetic": filt - model,
        "simulate + driver + recorder": total - filt,
    }
    print(f"split (one run, wall, timers included: {total:.2f} s):")
    for name, t in parts.items():
        print(f"  {name:38s} {t:6.2f} s {100 * t / total:5.1f} %")
    per = {k: fr.runtime_s for k, fr in res.runs.items()}
    print("  per filter (s, incl. model calls): " + ", ".join(f"{k} {v:.2f}" for k, v in per.items()))


if __name__ == "__main__":
    main()

"""The reproductions at 20 seeds as ONE batched experiment each: what every part costs.

Target (issue 13): each paper's reproduction at 20 seeds in <= 60 s on 2 cores. The lead's
restructuring runs S seeds x N runs as one experiment of S*N runs (run r of set s = s*N + i), so
this times ``run_experiment`` at those sizes with each reproduction's filter set, one experiment
per paper (a reproduction runs several: its cases / variants, column "x"), and splits it into the
simulation (``Scenario.simulate``), each filter's ``runtime_s`` and the rest of
``run_experiment`` (driver + recorder); ``Results.metrics`` is timed on its own.
"estimate" = x * (experiment + metrics). Also the simulation with the numpy paths (NAVLAB_NUMBA=0
equivalent) beside the compiled one. Not a test: the machine is shared, read the shares.

    python benchmarks/reproduce_scale.py [--only sins-gps] [--scale 1.0]

``--scale 0.1`` runs a tenth of the runs (a quick look; the shares change little).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, no install

from navlab import jit
from navlab.experiment import ExperimentSpec, plan, run_experiment
from navlab.warmup import warm

# (paper, experiments per reproduction, spec) at 20 seeds x the reproduction's default runs
CASES = {
    "sins-gps": (
        "hakf (4 cases)",
        4,
        ExperimentSpec(
            scenario="sins-gps",
            filters=("kf", "huber-kf", "vb-akf", "hakf", "oracle-kf"),
            runs=20 * 50,
            outliers="mixture",
            contamination=0.1,
            outlier_scale=10.0,
            scenario_params={"case": 4},
        ),
    ),
    "gps-ins-rtk": (
        "nnmfukf (4 variants)",
        4,
        ExperimentSpec(
            scenario="gps-ins-rtk",
            filters=("ekf", "svd-ukf", "mfukf", "nnmfukf", "nnmfukf-guarded", "oracle-kf"),
            runs=20 * 20,
            outliers="none",
        ),
    ),
    "gps-ins-pseudorange": (
        "vbekf (1 experiment)",
        1,
        ExperimentSpec(
            scenario="gps-ins-pseudorange",
            filters=("ekf", "vb-ekf", "oracle-kf"),
            runs=20 * 50,
            noise_schedule="constant",
            outliers="none",
        ),
    ),
    "cv2d": (
        "irakf (2 experiments)",
        2,
        ExperimentSpec(
            scenario="cv2d",
            filters=("kf", "rrae", "rakf", "rsshakf", "irakf", "oracle-kf"),
            runs=20 * 100,
            outliers="isolated",
        ),
    ),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=sorted(CASES))
    ap.add_argument("--scale", type=float, default=1.0)
    a = ap.parse_args()
    warm()
    print(f"numba: {'on' if jit.enabled() else 'off'}; one experiment per paper, wall seconds")
    for key, (paper, times, spec) in CASES.items():
        if a.only and key != a.only:
            continue
        spec = spec.replace(runs=max(1, round(spec.runs * a.scale)))
        p = plan(spec)
        runs = range(spec.runs)
        t0 = time.perf_counter()
        data = p.scenario.simulate(p.schedule, p.outliers, runs, spec.seed)
        t_sim = time.perf_counter() - t0
        t_sim_np = float("nan")
        if jit.enabled():
            with jit.numpy_paths():
                t0 = time.perf_counter()
                p.scenario.simulate(p.schedule, p.outliers, runs, spec.seed)
                t_sim_np = time.perf_counter() - t0
        del data
        t0 = time.perf_counter()
        res = run_experiment(spec)
        t_run = time.perf_counter() - t0
        t0 = time.perf_counter()
        res.metrics()
        t_met = time.perf_counter() - t0
        filt = {k: fr.runtime_s for k, fr in res.runs.items()}
        rest = t_run - t_sim - sum(filt.values())
        total = t_run + t_met
        print(
            f"\n{key}: {spec.runs} runs x {res.data.K} epochs, {len(filt)} filters — {paper}; "
            f"experiment + metrics {total:.1f} s, estimate {times * total:.0f} s (target 60 s)"
        )
        print(f"  {'simulation':28s} {t_sim:7.2f} s {100 * t_sim / total:5.1f} %  (numpy: {t_sim_np:.2f} s)")
        for k, t in filt.items():
            print(f"  {'filter ' + k:28s} {t:7.2f} s {100 * t / total:5.1f} %")
        print(f"  {'driver + recorder':28s} {rest:7.2f} s {100 * rest / total:5.1f} %")
        print(f"  {'metrics':28s} {t_met:7.2f} s {100 * t_met / total:5.1f} %")
        del res


if __name__ == "__main__":
    main()

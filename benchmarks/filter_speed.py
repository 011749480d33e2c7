"""Each filter's cost per run-step, this checkout beside another git revision, in one run.

Every filter of a case runs on the same simulated batch through a plain predict/update loop (the
shared time loop without the recorder). With ``--against REV`` the revision is unpacked into a
temporary directory (``git archive``) and the two trees are measured in alternating worker
processes, round after round, so both see the same machine load; the best round of each filter
counts. Times are CPU time of the worker (``time.process_time``), which a busy machine disturbs
far less than wall-clock time. Not a test: read the ratios, the machine is shared.

    python benchmarks/filter_speed.py [--against REV] [--rounds 3] [--repeat 3] [--case cv2d,...]

Prints µs per run-step (one predict + update of one Monte Carlo run) per filter and case, and
with ``--against`` the ratio this/REV (> 1: this checkout is slower). Workers run single-threaded
BLAS (``--threads`` to change) so that the other users of the machine disturb less.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# (scenario, runs, epochs, scenario params, filters); epochs None: the scenario's default
CASES: dict[str, tuple] = {
    "cv2d": (
        "cv2d",
        100,
        100,
        {},
        (
            "kf",
            "oracle-kf",
            "chi2-kf",
            "huber-kf",
            "vb-akf",
            "hakf",
            "student-t-kf",
            "sage-husa",
            "irakf",
            "rrae",
            "rakf",
            "rsshakf",
            "ekf",
            "svd-ukf",
            "mfukf",
            "vb-ekf",
            "wls",
        ),
    ),
    "sins-gps": (
        "sins-gps",
        50,
        300,
        {},
        ("kf", "chi2-kf", "huber-kf", "vb-akf", "hakf", "student-t-kf", "sage-husa", "irakf", "rakf"),
    ),
    "gps-ins-rtk": (
        "gps-ins-rtk",
        10,
        800,
        {},
        ("kf", "hakf", "svd-ukf", "mfukf", "nnmfukf", "nnmfukf-guarded"),
    ),
    "gps-ins-pseudorange": (
        "gps-ins-pseudorange",
        50,
        200,
        {},
        ("kf", "chi2-kf", "huber-kf", "student-t-kf", "ekf", "vb-ekf", "wls", "rsshakf"),
    ),
    "smartloc-berlin": (
        "smartloc-berlin",
        5,
        300,
        {},
        ("wls", "ekf", "huber-kf", "vb-ekf", "chi2-kf", "student-t-kf", "irakf"),
    ),
}


def worker(case: str, repeat: int) -> dict[str, float]:
    """CPU seconds (best of ``repeat``) of each filter's predict/update loop on the case's batch."""
    import numpy as np

    from navlab.experiment import ExperimentSpec, plan
    from navlab.filters import make_filter

    scenario, runs, epochs, sp, keys = CASES[case]
    p = plan(ExperimentSpec(scenario=scenario, filters=("kf",), runs=runs, epochs=epochs, scenario_params=sp))
    data = p.scenario.simulate(p.schedule, p.outliers, range(runs), 1)
    out = {}
    for key in keys:
        best = float("inf")
        for _ in range(repeat):
            f = make_filter(key, p.scenario.filter_defaults.get(key, {}))
            model = data.model
            st = f.init(model, data.x0, data.P0)
            t0 = time.process_time()
            with np.errstate(all="ignore"):
                for k in range(1, data.K + 1):
                    st = f.predict(model, st, k)
                    st, _ = f.update(model, st, k, data.z[:, k], data.side(k))
            best = min(best, time.process_time() - t0)
        out[key] = best
    out["_steps"] = float(data.B * data.K)
    return out


def run_worker(tree: Path, case: str, repeat: int, threads: int) -> dict[str, float]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree)
    env.setdefault("NAVLAB_DATA", str((ROOT / ".." / "shared" / "data").resolve()))
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = str(threads)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", case, "--repeat", str(repeat)]
    res = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise SystemExit(f"worker for {case} in {tree} failed:\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def unpack(rev: str, into: Path) -> Path:
    """The tree of git revision ``rev`` extracted into ``into`` (no worktree, no checkout)."""
    arch = subprocess.run(["git", "-C", str(ROOT), "archive", rev], capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=arch.stdout, check=True)
    return into


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", help="git revision to measure beside this checkout")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds per tree")
    ap.add_argument("--repeat", type=int, default=3, help="timed loops per filter per round")
    ap.add_argument("--case", default=",".join(CASES), help="comma-separated cases")
    ap.add_argument("--threads", type=int, default=1, help="BLAS threads of the workers")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        print(json.dumps(worker(a.worker, a.repeat)))
        return
    cases = [c for c in a.case.split(",") if c]
    with tempfile.TemporaryDirectory(prefix="navlab-bench-") as tmp:
        trees = {"this": ROOT}
        if a.against:
            trees[a.against] = unpack(a.against, Path(tmp))
        for case in cases:
            best: dict[str, dict[str, float]] = {t: {} for t in trees}
            for _ in range(a.rounds):
                for name, tree in trees.items():
                    for key, s in run_worker(tree, case, a.repeat, a.threads).items():
                        best[name][key] = min(best[name].get(key, float("inf")), s)
            _, runs, epochs, _, keys = CASES[case]
            print(f"\n{case}: {runs} runs x {epochs} epochs; µs per run-step, best of {a.rounds}x{a.repeat}")
            head = f"{'filter':>16} {'this':>9}"
            if a.against:
                head += f" {a.against[:12]:>12} {'this/' + a.against[:6]:>12}"
            print(head)
            for key in keys:
                us = {t: 1e6 * best[t][key] / best[t]["_steps"] for t in trees}
                line = f"{key:>16} {us['this']:9.2f}"
                if a.against:
                    line += f" {us[a.against]:12.2f} {us['this'] / us[a.against]:12.2f}"
                print(line, flush=True)


if __name__ == "__main__":
    main()

"""Each filter's cost per run-step, this checkout beside another git revision, in one process.

Every filter of a case runs on the same simulated batch through a plain predict/update loop (the
shared time loop without the recorder). With ``--against REV`` the revision's ``navlab`` package
is unpacked (``git archive``) into a temporary directory under the name ``navlab_rev`` (its
imports rewritten), so both versions live in ONE process and are timed alternately, round after
round, on the same data: they see the same machine load and the same caches. Times are CPU time
(``time.process_time``, BLAS on one thread), which a busy machine disturbs far less than
wall-clock time. Not a test: read the ratios, the machine is shared.

    python benchmarks/filter_speed.py [--against REV] [--rounds 7] [--case cv2d,...] [--filters kf,...]

Prints µs per run-step (one predict + update of one Monte Carlo run) per filter and case: this
checkout's best round, REV's best round, and the median over the rounds of the paired ratio
this/REV (> 1: this checkout is slower).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # before numpy
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout, no install

import numpy as np  # noqa: E402

# (scenario, runs, epochs, filters)
CASES: dict[str, tuple] = {
    "cv2d": (
        "cv2d",
        100,
        100,
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
        ("kf", "chi2-kf", "huber-kf", "vb-akf", "hakf", "student-t-kf", "sage-husa", "irakf", "rakf"),
    ),
    "gps-ins-rtk": ("gps-ins-rtk", 10, 800, ("kf", "hakf", "svd-ukf", "mfukf", "nnmfukf", "nnmfukf-guarded")),
    "gps-ins-pseudorange": (
        "gps-ins-pseudorange",
        50,
        200,
        ("kf", "chi2-kf", "huber-kf", "student-t-kf", "ekf", "vb-ekf", "wls", "rsshakf"),
    ),
    "smartloc-berlin": (
        "smartloc-berlin",
        5,
        300,
        ("wls", "ekf", "huber-kf", "vb-ekf", "chi2-kf", "student-t-kf", "irakf"),
    ),
}


def unpack(rev: str, into: Path) -> str:
    """Revision ``rev``'s navlab package as the importable package ``navlab_rev`` under ``into``."""
    arch = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "navlab"], capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=arch.stdout, check=True)
    pkg = into / "navlab_rev"
    (into / "navlab").rename(pkg)
    pat = re.compile(r"\bnavlab(?=[.\s])")
    for f in pkg.rglob("*.py"):
        f.write_text(pat.sub("navlab_rev", f.read_text()))
    sys.path.insert(0, str(into))
    return "navlab_rev"


def loop(f, data, side_type) -> float:
    """CPU seconds of one predict/update pass of filter ``f`` over the batch."""
    model = data.model
    st = f.init(model, data.x0, data.P0)
    t0 = time.process_time()
    with np.errstate(all="ignore"):
        for k in range(1, data.K + 1):
            s = data.side(k)
            if side_type is not None:
                s = side_type(s.R_true, s.bias, s.outlier, s.Q_extra)
            st = f.predict(model, st, k)
            st, _ = f.update(model, st, k, data.z[:, k], s)
    return time.process_time() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", help="git revision to measure beside this checkout")
    ap.add_argument("--rounds", type=int, default=7, help="alternating rounds per filter")
    ap.add_argument("--case", default=",".join(CASES), help="comma-separated cases")
    ap.add_argument("--filters", help="comma-separated filter keys (default: each case's list)")
    a = ap.parse_args()

    import importlib

    from navlab.experiment import ExperimentSpec, plan
    from navlab.filters import make_filter

    with tempfile.TemporaryDirectory(prefix="navlab-bench-") as tmp:
        other = None
        if a.against:
            name = unpack(a.against, Path(tmp))
            other = (
                importlib.import_module(f"{name}.filters").make_filter,
                importlib.import_module(f"{name}.filters.base").SideInfo,
            )
        for case in [c for c in a.case.split(",") if c]:
            scenario, runs, epochs, keys = CASES[case]
            if a.filters:
                keys = tuple(k for k in a.filters.split(",") if k in keys)
            p = plan(ExperimentSpec(scenario=scenario, filters=("kf",), runs=runs, epochs=epochs))
            data = p.scenario.simulate(p.schedule, p.outliers, range(runs), 1)
            steps = data.B * data.K
            print(f"\n{case}: {runs} runs x {epochs} epochs; CPU µs per run-step, best of {a.rounds} rounds")
            head = f"{'filter':>16} {'this':>9}"
            if other:
                head += f" {a.against[:10]:>10} {'this/rev':>9}"
            print(head)
            for key in keys:
                fp = p.scenario.filter_defaults.get(key, {})
                mine = make_filter(key, fp)
                theirs = other[0](key, fp) if other else None
                loop(mine, data, None)  # warm up
                if theirs is not None:
                    loop(theirs, data, other[1])
                t_this, t_rev = [], []
                for r in range(a.rounds):
                    order = (0, 1) if r % 2 == 0 else (1, 0)
                    for who in order:
                        if who == 0:
                            t_this.append(loop(mine, data, None))
                        elif theirs is not None:
                            t_rev.append(loop(theirs, data, other[1]))
                line = f"{key:>16} {1e6 * min(t_this) / steps:9.2f}"
                if theirs is not None:
                    ratio = float(np.median(np.array(t_this) / np.array(t_rev)))
                    line += f" {1e6 * min(t_rev) / steps:10.2f} {ratio:9.2f}"
                print(line, flush=True)


if __name__ == "__main__":
    main()

"""What each speed trick of the filters is worth: every filter it serves, with and without it.

A trick is a place where the code takes a shorter road than the textbook formula (a closed-form
inverse, an indexing shortcut, a cache, a closed-form unscented transform). For each one this
script swaps in the plain version (the textbook formula, the uncached call) and times the
filters that use it on the same simulated batch, with and without the trick back to back in
alternating order, round after round, in one process. Times are the process's CPU time
(``time.process_time``, BLAS on one thread), which a busy machine disturbs far less than
wall-clock time.

The house rule (issue 13): a trick stays only where it is worth ≥ 10 % of some filter's time;
the module notes say which stayed and why. A batched path beside a filter's compiled one-run steps
(issue 23) stays only where it is ≥ 1.5× faster than them (the ``speed-up`` column).

    python benchmarks/tricks.py [--rounds 7] [--trick NAME,...] [--list]

Prints, per trick and filter, the CPU time per run-step with the trick and without it (best
round) and ``worth`` = 1 − median over the rounds of the paired ratio with/without: the share
of the filter's time the trick saves (negative: it costs time). Not a test: read the figures.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # before numpy
    os.environ.setdefault(_var, "1")

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, no install

import numpy as np  # noqa: E402

# (scenario, runs, epochs): small batches, enough epochs for the adaptive parts to engage
CASES = {
    "cv2d": ("cv2d", 100, 100),
    "sins-gps": ("sins-gps", 50, 150),
    "sins-gps-200": ("sins-gps", 200, 150),  # the runs of a block of `reproduce hakf --seeds 20`
    "sins-gps-200-clean": ("sins-gps", 200, 150, (("outliers", "none"),)),  # its case 1
    "gps-ins-rtk": ("gps-ins-rtk", 10, 300),
    "pseudorange": ("gps-ins-pseudorange", 50, 100),
    "smartloc": ("smartloc-berlin", 5, 150),
}


@contextlib.contextmanager
def swap(module: str, name: str, new: object) -> Iterator[None]:
    """Replace ``module.name`` by ``new`` in every navlab module that imported it (by identity)."""
    import importlib

    orig = getattr(importlib.import_module(module), name)
    hits = [
        m
        for m in list(sys.modules.values())
        if m is not None
        and getattr(m, "__name__", "").startswith("navlab")
        and getattr(m, name, None) is orig
    ]
    for m in hits:
        setattr(m, name, new)
    try:
        yield
    finally:
        for m in hits:
            setattr(m, name, orig)


@contextlib.contextmanager
def swap_attr(owner: object, name: str, new: object) -> Iterator[None]:
    orig = owner.__dict__[name]
    setattr(owner, name, new)
    try:
        yield
    finally:
        setattr(owner, name, orig)


@dataclass(frozen=True)
class Trick:
    """A speed trick: where it lives, which filters on which cases use it, and its plain version."""

    name: str
    where: str
    uses: dict[str, tuple[str, ...]]  # case -> filters
    plain: Callable[[], contextlib.AbstractContextManager]
    need: float = 1.0 / 0.9  # speed-up (without/with) to keep it: 10 %; a batched path beside the
    # compiled one-run steps: 1.5× (issue 23)
    recorded: bool = False  # timed with the shared time loop's recorder (run_filters), not without


# ------------------------------------------------------------------------------ plain versions
def _plain_pht():
    from navlab.linalg import mT

    def PHt(P, H):
        U = P @ mT(H)
        return U, H @ U

    return swap("navlab.linalg", "PHt", PHt)


def _plain_kf_gain():
    from navlab.linalg import mT, solve_sym

    def kf_gain(U, S):
        Kt, fixed = solve_sym(S, mT(U))
        return mT(Kt), fixed

    return swap("navlab.linalg", "kf_gain", kf_gain)


def _plain_selection():
    import navlab.linalg as L

    def selection(H):
        if H.ndim != 2:
            return None
        return L._selection.__wrapped__(H.shape, np.ascontiguousarray(H, dtype=float).tobytes())

    return swap("navlab.linalg", "selection", selection)


def _plain_bcast():
    return swap("navlab.linalg", "bcast", lambda a, shape: np.broadcast_to(np.asarray(a), shape))


def _plain_chi2():
    from scipy.stats import chi2

    return swap(
        "navlab.linalg",
        "chi2_threshold",
        lambda alpha, dof, m: chi2.ppf(1.0 - alpha, np.maximum(dof, 1)),
    )


def _plain_quad():
    import navlab.linalg as L

    def quad(v, S):
        v = np.asarray(v, dtype=float)
        d = v.shape[-1]
        Sb = np.broadcast_to(S, (*v.shape, d))
        return L._quad_lu(v.reshape(-1, d), Sb.reshape(-1, d, d)).reshape(v.shape[:-1])

    return swap("navlab.linalg", "quad", quad)


def _plain_select():
    """np.where with an all-true mask where the code passes None (every channel, every run)."""

    def select(mask, new, old):
        if mask is None:
            mask = np.ones(np.shape(new)[:1] + (1,) * (np.ndim(new) - 1), dtype=bool)
        return np.where(mask, new, old)

    return swap("navlab.linalg", "select", select)


def _plain_linear_ut():
    """A linear model's moments from the compiled one-run sigma-point steps (no closed form)."""
    import navlab.filters.ukf as uk

    return swap_attr(uk._UKFBase, "_closed_form", lambda self, model: False)


def _plain_linear_sqrt():
    """Each run's SVD factor (the spec's square root) in a linear model's closed form."""
    import navlab.filters.ukf as uk

    def linear_sqrt(P):
        n = P.shape[-1]
        L, neg = uk.SQUARE_ROOTS((P.reshape(-1, n, n),), (uk.SVD,))
        return L.reshape(P.shape), neg.reshape(P.shape[:-2])

    return swap("navlab.filters.ukf", "linear_sqrt", linear_sqrt)


def _plain_recorder_nees():
    """The recorder's NEES by one call per block of epochs on a stacked copy of every P."""
    from navlab.experiment import _Recorder, _stack
    from navlab.linalg import quad

    def nees(dx, Ps):
        return quad(dx, _stack(Ps, (*dx.shape[1:], dx.shape[-1])))

    return swap_attr(_Recorder, "_nees", staticmethod(nees))


def _plain_oracle_shared_R():
    """The oracle KF's true R always per run (its P then per run from the first update)."""
    return swap("navlab.filters.kalman", "true_R", lambda side, m: side.R_true[..., :, None] * np.eye(m))


def _plain_kf_batched():
    """The KF family's predict and update steps 3–6 by the compiled one-run textbook step."""
    from kf_paths import compiled_kf  # beside this script

    return compiled_kf()


TRICKS: list[Trick] = [
    Trick(
        "PHt-indexing",
        "linalg.PHt (P Hᵀ, H P Hᵀ by indexing for a selection H)",
        {
            "cv2d": ("kf", "chi2-kf", "huber-kf", "hakf", "sage-husa", "irakf"),
            "sins-gps": ("kf", "hakf", "sage-husa", "irakf"),
            "pseudorange": ("kf", "huber-kf"),
        },
        _plain_pht,
    ),
    Trick(
        "kf_gain-closed-form",
        "linalg.kf_gain (adjugate/det for m ≤ 3)",
        {
            "cv2d": ("kf", "chi2-kf", "huber-kf", "hakf", "sage-husa", "irakf", "rakf"),
            "sins-gps": ("kf", "hakf", "irakf"),
        },
        _plain_kf_gain,
    ),
    Trick(
        "selection-cache",
        "linalg.selection (cached by H's content)",
        {"cv2d": ("kf", "huber-kf", "irakf"), "sins-gps": ("kf", "hakf")},
        _plain_selection,
    ),
    Trick(
        "bcast-view",
        "linalg.bcast (zero-stride view built directly)",
        {"cv2d": ("huber-kf", "hakf", "irakf", "svd-ukf"), "gps-ins-rtk": ("svd-ukf", "mfukf")},
        _plain_bcast,
    ),
    Trick(
        "chi2-table",
        "linalg.chi2_threshold (cached table)",
        {"cv2d": ("chi2-kf", "mfukf"), "gps-ins-rtk": ("mfukf",)},
        _plain_chi2,
    ),
    Trick(
        "quad-shortcuts",
        "linalg.quad (closed form / LDLᵀ / Cholesky instead of LU)",
        {"cv2d": ("chi2-kf",), "sins-gps": ("chi2-kf",), "pseudorange": ("chi2-kf",)},
        _plain_quad,
    ),
    Trick(
        "select-none-masks",
        "linalg.select (no np.where while every channel is present / every run iterates)",
        {"cv2d": ("vb-akf", "hakf", "sage-husa"), "sins-gps": ("vb-akf",)},
        _plain_select,
    ),
    Trick(
        "ukf-linear-closed-form",
        "ukf.linear_time_update/linear_moments (a linear model's UT in closed form, batched; "
        "without: the compiled one-run sigma-point steps)",
        {"cv2d": ("svd-ukf", "mfukf"), "gps-ins-rtk": ("svd-ukf", "mfukf", "nnmfukf")},
        _plain_linear_ut,
        need=1.5,
    ),
    Trick(
        "ukf-linear-cholesky",
        "ukf.linear_sqrt (Cholesky instead of the SVD factor for a linear model)",
        {"cv2d": ("svd-ukf",), "gps-ins-rtk": ("svd-ukf", "mfukf")},
        _plain_linear_sqrt,
    ),
    Trick(
        "kf-batched",
        "filters.kalman (the KF family's batched predict/update; without: the compiled one-run KF "
        "step of benchmarks/kf_paths.py, which also times the sizes of issue 23)",
        {"cv2d": ("kf", "huber-kf", "vb-akf", "hakf"), "sins-gps": ("kf", "huber-kf", "vb-akf", "hakf")},
        _plain_kf_batched,
        need=1.5,
    ),
    Trick(
        "recorder-nees",
        "experiment._Recorder._nees (the NEES per epoch on each P, no stacked copy of the P's)",
        {"sins-gps-200": ("kf", "hakf", "oracle-kf"), "cv2d": ("kf", "hakf")},
        _plain_recorder_nees,
        recorded=True,
    ),
    Trick(
        "oracle-shared-R",
        "kalman.true_R (the oracle's R, and so its P, shared by the runs while their true R are equal)",
        {"sins-gps-200-clean": ("oracle-kf",), "sins-gps-200": ("oracle-kf",)},
        _plain_oracle_shared_R,
        recorded=True,
    ),
]


# ------------------------------------------------------------------------------ timing
@functools.cache
def simulated(scenario: str, runs: int, epochs: int, spec: tuple = ()):
    """The plan and the simulated batch of a scenario (one per process; benchmarks/kf_paths.py too);
    ``spec``: (field, value) pairs of the ExperimentSpec beside its defaults.
    """
    from navlab.experiment import ExperimentSpec, plan

    p = plan(ExperimentSpec(scenario=scenario, filters=("kf",), runs=runs, epochs=epochs, **dict(spec)))
    return p, p.scenario.simulate(p.schedule, p.outliers, range(runs), 1)


def case_data(case: str):
    return simulated(*CASES[case])


def time_steps(p, data, key: str, P0_per_run: bool = False) -> float:
    """CPU seconds per run-step of ``key``'s predict/update loop on a simulated batch (``P0_per_run``:
    P0 given to the filter as one copy per run, not shared).
    """
    from navlab.filters import make_filter

    f = make_filter(key, p.scenario.filter_defaults.get(key, {}))
    P0 = np.array(np.broadcast_to(data.P0, (data.B, *data.P0.shape[-2:]))) if P0_per_run else data.P0
    st = f.init(data.model, data.x0, P0)
    t0 = time.process_time()
    with np.errstate(all="ignore"):
        for k in range(1, data.K + 1):
            st = f.predict(data.model, st, k)
            st, _ = f.update(data.model, st, k, data.z[:, k], data.side(k))
    return (time.process_time() - t0) / (data.B * data.K)


def time_filter(case: str, key: str, recorded: bool = False) -> float:
    """CPU seconds per run-step of ``key``'s predict/update loop on the case (``recorded``: the
    shared time loop with its recorder, :func:`navlab.experiment.run_filters`).
    """
    if not recorded:
        return time_steps(*case_data(case), key)
    from navlab.experiment import run_filters
    from navlab.filters import make_filter

    p, data = case_data(case)
    f = make_filter(key, p.scenario.filter_defaults.get(key, {}))
    t0 = time.process_time()
    with np.errstate(all="ignore"):
        run_filters(data, [f])
    return (time.process_time() - t0) / (data.B * data.K)


def measure(trick: Trick, rounds: int) -> list[tuple[str, str, float, float, float]]:
    """Per (case, filter): best time with and without the trick, and the median of the paired
    ratios with/without (each round measures both back to back, in alternating order).
    """
    rows = []
    for case, keys in trick.uses.items():
        for key in keys:
            time_filter(case, key, trick.recorded)  # warm up (first-call costs, caches)
            ons, offs = [], []
            for r in range(rounds):
                for plain in (r % 2 == 1, r % 2 == 0):
                    if plain:
                        with trick.plain():
                            offs.append(time_filter(case, key, trick.recorded))
                    else:
                        ons.append(time_filter(case, key, trick.recorded))
            ratio = float(np.median(np.array(ons) / np.array(offs)))
            rows.append((case, key, min(ons), min(offs), ratio))
    return rows


def joseph_worth(rounds: int) -> list[tuple[str, str, float, float, float]]:
    """The Joseph form from U and S (linalg.joseph_from_gain) against the textbook
    (I − K H) P (I − K H)ᵀ + K R Kᵀ, which needs H and R the filters no longer hand it: timed as
    a kernel on each case's shapes and put against the filter's time per run-step (one call per
    update).
    """
    from navlab.linalg import joseph_from_gain, mT, sym

    def textbook(P, K, H, R):
        IKH = np.eye(P.shape[-1]) - K @ H
        return sym(IKH @ P @ mT(IKH) + K @ R @ mT(K))

    rows = []
    for case, key in (
        ("cv2d", "kf"),
        ("cv2d", "huber-kf"),
        ("sins-gps", "huber-kf"),
        ("gps-ins-rtk", "hakf"),
    ):
        _, data = case_data(case)
        B, n, m = data.B, data.x0.shape[1], data.z.shape[2]
        rng = np.random.default_rng(0)
        A = rng.standard_normal((B, n, n))
        P = A @ mT(A) + np.eye(n)
        H, R = np.eye(n)[:m], np.eye(m)
        U = P @ H.T
        S = H @ U + R
        K = U @ np.linalg.inv(S)

        def t(fn, reps=200):
            best = float("inf")
            for _ in range(rounds):
                t0 = time.process_time()
                for _ in range(reps):
                    fn()
                best = min(best, (time.process_time() - t0) / reps)
            return best

        fast, slow = t(lambda: joseph_from_gain(P, K, U, S)), t(lambda: textbook(P, K, H, R))  # noqa: B023
        step = time_filter(case, key) * B  # the filter's time per epoch (all runs)
        rows.append((case, key, step / B, (step + slow - fast) / B, (slow - fast) / (step + slow - fast)))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--trick", help="comma-separated trick names (default: all)")
    ap.add_argument("--list", action="store_true", help="list the tricks and exit")
    a = ap.parse_args()
    if a.list:
        for t in TRICKS:
            print(f"{t.name:>24}  {t.where}")
        print(f"{'joseph-expansion':>24}  linalg.joseph_from_gain (a kernel timing)")
        return
    want = set(a.trick.split(",")) if a.trick else None
    if not want or "joseph-expansion" in want:
        print("\njoseph-expansion: linalg.joseph_from_gain (kernel timed on the case's shapes)")
        print(f"{'case':>12} {'filter':>14} {'with':>9} {'without':>9} {'worth':>7}")
        for case, key, on, off, worth in joseph_worth(a.rounds):
            print(f"{case:>12} {key:>14} {1e6 * on:9.2f} {1e6 * off:9.2f} {100 * worth:6.1f}%", flush=True)
    print(f"CPU µs per run-step (best of {a.rounds}); worth = 1 − median(with/without) over the rounds")
    for t in TRICKS:
        if want and t.name not in want:
            continue
        print(f"\n{t.name}: {t.where}")
        print(f"{'case':>12} {'filter':>14} {'with':>9} {'without':>9} {'worth':>7} {'speed-up':>9}")
        best = -1.0
        for case, key, on, off, ratio in measure(t, a.rounds):
            best = max(best, 1.0 - ratio)
            line = f"{case:>12} {key:>14} {1e6 * on:9.2f} {1e6 * off:9.2f} {100 * (1.0 - ratio):6.1f}%"
            print(f"{line} {1.0 / ratio:8.2f}x", flush=True)
        up = 1.0 / (1.0 - best)
        verdict = "keep" if up >= t.need else f"below {t.need:.3g}x"
        print(f"{'':>12} {'max worth':>14} {'':>19} {100 * best:6.1f}% {up:8.2f}x  {verdict}", flush=True)


if __name__ == "__main__":
    main()

"""The KF family's batched numpy update against the compiled one-run KF step (issue 23).

Issue 23: a batched numpy path stays only where a benchmark a user waits for shows it ≥ 1.5×
faster than the one-run textbook step compiled and looped over the runs. The KF family's predict
(``Filter.predict``: F P Fᵀ + Q on a P kept unbatched while it is shared by the runs) and
measurement update (``KalmanUpdate.update``: U = P Hᵀ by indexing, the closed-form S⁻¹ for m ≤ 3,
the Joseph form from U and S) are such a batched path. This script writes the KF's predict and
update for ONE run (:func:`kf_predict_one`, :func:`kf_update_one`, one equation a line), loops
them over the runs with :class:`navlab.jit.RunStep`, swaps them into the filters
(:func:`compiled_kf`: the predict, and steps 3–6 of the update; a robust or adaptive filter keeps
its own ``innovation`` and ``noise`` steps) and times both paths on the same simulated batch,
round after round in alternating order, in one process (CPU time, BLAS on one thread).

    python benchmarks/kf_paths.py [--rounds 5] [--case NAME,...]

Prints, per case and filter, the CPU µs per run-step of the batched path and of three compiled
one-run steps (best round): ``textbook`` (the Joseph form (I − K H) P (I − K H)ᵀ + K R Kᵀ as
written), ``expanded`` (the Joseph form expanded from U = P Hᵀ and S, the algebra the batched path
uses) and ``loops`` (predict and the expanded update in plain loops with few temporary arrays:
numba allocates every array expression, which dominates the first two at n = 4), and the speed-up
compiled/batched (best-round ratio / median of the paired per-round ratios): a median ≥ 1.5
against every compiled step means the batched path earns its place. Not a test: read the figures.
tests/unit/test_kf_paths.py checks that each compiled step computes what the batched path does.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # before numpy
    os.environ.setdefault(_var, "1")

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, no install

import numpy as np  # noqa: E402

from navlab.filters.base import Filter, StepOut, flag_fix  # noqa: E402
from navlab.filters.kalman import KalmanUpdate  # noqa: E402
from navlab.jit import Kernel, RunStep  # noqa: E402
from navlab.linalg import CHOLESKY_LOWER, CHOLESKY_SOLVE, batched, cholesky_lower, cholesky_solve  # noqa: E402

# name: (scenario, runs, epochs, filters, P0 per run)
CASES = {
    "cv2d-100": ("cv2d", 100, 100, ("kf", "huber-kf", "vb-akf", "hakf"), False),
    "cv2d-10000": ("cv2d", 10_000, 20, ("kf",), False),
    "sins-gps-50": ("sins-gps", 50, 150, ("kf", "huber-kf", "vb-akf", "hakf"), False),
    "sins-gps-250": ("sins-gps", 250, 150, ("kf", "huber-kf", "vb-akf", "hakf"), False),
    "sins-gps-50-P0": ("sins-gps", 50, 150, ("kf",), True),
    "sins-gps-250-P0": ("sins-gps", 250, 150, ("kf",), True),
}


# ------------------------------------------------------------------------------ the one-run steps
def mm(A, B):  # pragma: no cover - compiled by numba
    """The product A B of two small matrices by plain loops (numba's ``@`` calls BLAS: for the
    KF's 2×2 … 15×15 matrices its call costs more than the arithmetic).
    """
    B = np.ascontiguousarray(B)  # rows of B contiguous (Fᵀ, Hᵀ …): the inner loop vectorises
    C = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for c in range(A.shape[1]):
            a = A[i, c]
            for j in range(B.shape[1]):
                C[i, j] += a * B[c, j]
    return C


def mv(A, x):  # pragma: no cover - compiled by numba
    """The product A x of a small matrix and a vector by plain loops."""
    y = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        for c in range(A.shape[1]):
            y[i] += A[i, c] * x[c]
    return y


MM, MV = Kernel(mm), Kernel(mv)


def kf_predict_one(x, P, F, Q):  # pragma: no cover - compiled by numba
    """§1.1 steps 1–2 for ONE run: x⁻ = F x⁺, P⁻ = F P⁺ Fᵀ + Q (symmetrised)."""
    x = mv(F, x)  # 1  x⁻ = F x⁺
    P = mm(mm(F, P), F.T) + Q  # 2  P⁻ = F P⁺ Fᵀ + Q
    return x, 0.5 * (P + P.T)  # symmetrised (§0.2 rule 1)


def masked(nu, H, R):  # pragma: no cover - compiled by numba
    """A missing channel (ν_i NaN) as :func:`navlab.linalg.mask_missing` has it: a zero row of H,
    ν_i = 0 and a unit, uncorrelated R_ii (its gain column is zero). Returns H, ν, R masked.
    """
    m = nu.shape[0]
    ok = np.isfinite(nu)
    o = np.where(ok, 1.0, 0.0)
    return H * o.reshape((m, 1)), np.where(ok, nu, 0.0), R * np.outer(o, o) + np.diag(1.0 - o)


def gain(A, S, w):  # pragma: no cover - compiled by numba
    """4  K = A S⁻¹ (A = P⁻ Hᵀ) by S = L Lᵀ, a zero column where the weight w_i is 0, and whether S
    needed jitter (§0.2 rule 3: 1e-12·trace(S)/m·I, flag 9).
    """
    n, m = A.shape
    L = np.empty((m, m))
    fixed = not cholesky_lower(S, L)  # S = L Lᵀ
    if fixed:
        cholesky_lower(S + max(1e-12 * np.trace(S) / m, 1e-300) * np.eye(m), L)
    K = np.empty((n, m))
    for i in range(n):  # row i of K: S Kᵢᵀ = Aᵢᵀ
        y = A[i].copy()
        cholesky_solve(L, y)
        K[i] = y * np.where(w != 0.0, 1.0, 0.0)  # a rejected channel: zero column
    return K, fixed


MASKED, GAIN = Kernel(masked), Kernel(gain, uses=(CHOLESKY_LOWER, CHOLESKY_SOLVE))


def kf_update_one(x, P, nu, w, R, H):  # pragma: no cover - compiled by numba
    """§1.1 steps 3–6 for ONE run, from ν = z − h(x⁻) (NaN: channel missing, :func:`masked`) and
    weights w (0 rejects a channel: zero gain column). Returns x⁺, P⁺, the masked ν, S, the masked
    R and whether S needed jitter.
    """
    n = P.shape[0]
    Hm, v, Rm = masked(nu, H, R)
    S = mm(mm(Hm, P), Hm.T) + Rm  # 3  S = H P⁻ Hᵀ + R
    S = 0.5 * (S + S.T)
    K, fixed = gain(mm(P, Hm.T), S, w)  # 4  K = P⁻ Hᵀ S⁻¹
    x = x + mv(K, v)  # 5  x⁺ = x⁻ + K ν
    A = np.eye(n) - mm(K, Hm)
    P = mm(mm(A, P), A.T) + mm(mm(K, Rm), K.T)  # 6  P⁺ = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ
    return x, 0.5 * (P + P.T), v, S, Rm, fixed


def kf_update_one_expanded(x, P, nu, w, R, H):  # pragma: no cover - compiled by numba
    """:func:`kf_update_one` with the Joseph form expanded from U = P⁻ Hᵀ and S (the algebra of
    the batched path's ``joseph_from_gain``: n×m products instead of n×n×n ones).
    """
    Hm, v, Rm = masked(nu, H, R)
    U = mm(P, Hm.T)  # U = P⁻ Hᵀ
    S = mm(Hm, U) + Rm  # 3  S = H P⁻ Hᵀ + R
    S = 0.5 * (S + S.T)
    K, fixed = gain(U, S, w)  # 4  K = U S⁻¹
    x = x + mv(K, v)  # 5  x⁺ = x⁻ + K ν
    P = P - mm(U, K.T) - mm(K, U.T) + mm(mm(K, S), K.T)  # 6  Joseph form = P − U Kᵀ − K Uᵀ + K S Kᵀ
    return x, 0.5 * (P + P.T), v, S, Rm, fixed


def kf_predict_lean(x, P, F, Q):  # pragma: no cover - compiled by numba
    """:func:`kf_predict_one` in plain loops, no temporary arrays but the result's and one work
    matrix: what a compiled step costs once numba's per-array allocations are gone.
    """
    n = x.shape[0]
    xo, T, A, Po = np.zeros(n), np.zeros((n, n)), np.empty((n, n)), np.empty((n, n))
    for i in range(n):
        for c in range(n):
            a = F[i, c]
            xo[i] += a * x[c]  # 1  x⁻ = F x⁺
            for j in range(n):
                T[i, j] += a * P[c, j]  # T = F P⁺
    for i in range(n):
        for j in range(n):
            s = 0.0
            for c in range(n):
                s += T[i, c] * F[j, c]
            A[i, j] = s + Q[i, j]  # 2  P⁻ = F P⁺ Fᵀ + Q
    for i in range(n):  # symmetrised
        for j in range(n):
            Po[i, j] = 0.5 * (A[i, j] + A[j, i])
    return xo, Po


def kf_update_lean(x, P, nu, w, R, H):  # pragma: no cover - compiled by numba
    """:func:`kf_update_one_expanded` in plain loops (the Joseph form from U and S in one pass
    over P, as ``linalg._joseph_runs``), few temporary arrays.
    """
    n, m = P.shape[0], nu.shape[0]
    v, o, y = np.empty(m), np.empty(m), np.empty(m)
    Rm, S, L = np.empty((m, m)), np.empty((m, m)), np.empty((m, m))
    U, K, W = np.empty((n, m)), np.empty((n, m)), np.empty((n, m))
    for k in range(m):  # a missing channel: ν_k = 0, a zero row of H, a unit uncorrelated R_kk
        o[k] = 1.0 if np.isfinite(nu[k]) else 0.0
        v[k] = nu[k] if o[k] == 1.0 else 0.0
    for k in range(m):
        for q in range(m):
            Rm[k, q] = R[k, q] * (o[k] * o[q]) + ((1.0 - o[k]) if k == q else 0.0)
    for i in range(n):  # U = P⁻ Hᵀ
        for k in range(m):
            s = 0.0
            for c in range(n):
                s += P[i, c] * (H[k, c] * o[k])
            U[i, k] = s
    for k in range(m):  # 3  S = H P⁻ Hᵀ + R, symmetrised
        for q in range(m):
            s = 0.0
            for c in range(n):
                s += (H[k, c] * o[k]) * U[c, q]
            L[k, q] = s + Rm[k, q]
    for k in range(m):
        for q in range(m):
            S[k, q] = 0.5 * (L[k, q] + L[q, k])
    fixed = not cholesky_lower(S, L)
    if fixed:  # §0.2 rule 3: jitter 1e-12·trace(S)/m·I (flag 9)
        cholesky_lower(S + max(1e-12 * np.trace(S) / m, 1e-300) * np.eye(m), L)
    for i in range(n):  # 4  K = U S⁻¹, row by row; a rejected channel: zero column
        for k in range(m):
            y[k] = U[i, k]
        cholesky_solve(L, y)
        for k in range(m):
            K[i, k] = y[k] if w[k] != 0.0 else 0.0
    xo = np.empty(n)
    for i in range(n):  # 5  x⁺ = x⁻ + K ν
        s = 0.0
        for k in range(m):
            s += K[i, k] * v[k]
        xo[i] = x[i] + s
    for i in range(n):  # W = K S − U
        for k in range(m):
            s = -U[i, k]
            for q in range(m):
                s += K[i, q] * S[q, k]
            W[i, k] = s
    A, Po = np.empty((n, n)), np.empty((n, n))
    for i in range(n):  # 6  P⁺ = P⁻ − U Kᵀ + K Wᵀ (the Joseph form, expanded)
        for j in range(n):
            s = P[i, j]
            for k in range(m):
                s += K[i, k] * W[j, k] - U[i, k] * K[j, k]
            A[i, j] = s
    for i in range(n):
        for j in range(n):
            Po[i, j] = 0.5 * (A[i, j] + A[j, i])
    return xo, Po, v, S, Rm, fixed


KF_PREDICT = RunStep(kf_predict_one, n_runs=2, outs=((0, float), (1, float)), uses=(MM, MV))
KF_UPDATE = RunStep(
    kf_update_one,
    n_runs=5,
    outs=((0, float), (1, float), (2, float), (4, float), (4, float), (None, bool)),
    uses=(MM, MV, MASKED, GAIN),
)
KF_UPDATE_EXPANDED = RunStep(
    kf_update_one_expanded,
    n_runs=5,
    outs=((0, float), (1, float), (2, float), (4, float), (4, float), (None, bool)),
    uses=(MM, MV, MASKED, GAIN),
)
KF_PREDICT_LEAN = RunStep(kf_predict_lean, n_runs=2, outs=((0, float), (1, float)))
KF_UPDATE_LEAN = RunStep(
    kf_update_lean,
    n_runs=5,
    outs=((0, float), (1, float), (2, float), (4, float), (4, float), (None, bool)),
    uses=(CHOLESKY_LOWER, CHOLESKY_SOLVE),
)
_STEP = [KF_PREDICT, KF_UPDATE]  # the steps compiled_kf swaps in


def _per_run(A: np.ndarray, B: int) -> np.ndarray:
    return np.ascontiguousarray(batched(np.asarray(A, dtype=float), B))


def predict(self, model, state, k):
    """``Filter.predict`` by the compiled one-run step (a linear model)."""
    B = state.x.shape[0]
    x, P = _STEP[0]((state.x, _per_run(state.P, B)), (model.F(k), model.Q(k)))
    return state._replace(x=x, P=P)


def update(self, model, state, k, z, side):
    """``KalmanUpdate.update`` with steps 3–6 by the compiled one-run step.

    The KF (nominal R, no noise step) runs the one-run step from ν = z − h(x⁻) alone; a robust or
    adaptive filter keeps its batched ``innovation`` and ``noise`` steps (its weights, R̃ …).
    """
    B, m = z.shape
    if type(self).noise is KalmanUpdate.noise and type(self).innovation is KalmanUpdate.innovation:
        H, nu = model.H(state.x, k), z - model.h(state.x, k)
        x, P, nu, S, R, fixed = _STEP[1](
            (state.x, _per_run(state.P, B), nu, np.ones((B, m)), _per_run(model.R0, B)), (H,)
        )
        flags = flag_fix(np.zeros(z.shape, dtype=np.int8), fixed)
        out = StepOut(x=x, P=P, innov=nu, S=S, R_used=R, R_hat=None, weights=None, flags=flags, stats={})
        return state._replace(x=x, P=P), out
    pr = self.innovation(model, state, k, z, side)
    nz = self.noise(model, state, pr, z)
    pr = pr if nz.prior is None else nz.prior
    nu = np.where(pr.mk.ok, pr.mk.nu if nz.nu is None else nz.nu, np.nan)
    w = np.ones((B, m)) if nz.weights is None else nz.weights
    x, P, _, S, _, fixed = _STEP[1]((pr.x, _per_run(pr.P, B), nu, w, _per_run(nz.R, B)), (pr.H,))
    return self.finish(model, state, k, z, pr, nz, (x, P, S, fixed))


@contextlib.contextmanager
def compiled_kf(step: RunStep = KF_UPDATE, predict_step: RunStep = KF_PREDICT) -> Iterator[None]:
    """Within the block the KF family predicts and updates by the compiled one-run steps."""
    saved = Filter.__dict__["predict"], KalmanUpdate.__dict__["update"], list(_STEP)
    Filter.predict, KalmanUpdate.update, _STEP[:] = predict, update, [predict_step, step]
    try:
        yield
    finally:
        Filter.predict, KalmanUpdate.update, _STEP[:] = saved


# ------------------------------------------------------------------------------ timing
def time_filter(case: str, key: str) -> float:
    """CPU seconds per run-step of ``key``'s predict/update loop on the case (benchmarks/tricks.py's loop)."""
    from tricks import simulated, time_steps  # beside this script

    scenario, runs, epochs, _, P0_per_run = CASES[case]
    return time_steps(*simulated(scenario, runs, epochs), key, P0_per_run)


# the compiled (update, predict) steps
PATHS = {
    "textbook": (KF_UPDATE, KF_PREDICT),
    "expanded": (KF_UPDATE_EXPANDED, KF_PREDICT),
    "loops": (KF_UPDATE_LEAN, KF_PREDICT_LEAN),
}


def measure(case: str, key: str, rounds: int) -> dict[str, list[float]]:
    """CPU seconds per run-step of the batched path and of each compiled step, per round.

    Each round times every path back to back, the order rotated from round to round.
    """
    paths = ["batched", *PATHS]

    def run(path: str) -> float:
        if path == "batched":
            return time_filter(case, key)
        with compiled_kf(*PATHS[path]):
            return time_filter(case, key)

    for path in paths:  # warm up (first-call costs, caches, compiles)
        run(path)
    times: dict[str, list[float]] = {path: [] for path in paths}
    for r in range(rounds):
        for path in paths[r % len(paths) :] + paths[: r % len(paths)]:
            times[path].append(run(path))
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--case", help=f"comma-separated cases (default: all of {', '.join(CASES)})")
    a = ap.parse_args()
    cases = a.case.split(",") if a.case else list(CASES)
    print(f"load average {os.getloadavg()[0]:.2f}; CPU µs per run-step (best of {a.rounds} rounds)")
    print("speed-up = compiled/batched: best-round ratio / median of the paired per-round ratios;")
    print("the batched path keeps its place where it is ≥ 1.5× faster than the compiled step (issue 23)")
    cols = "".join(f" {p:>9} {'speed-up':>13}" for p in PATHS)
    print(f"{'case':>16} {'filter':>9} {'P0':>7} {'batched':>9}{cols}  verdict")
    for case in cases:
        for key in CASES[case][3]:
            t = {p: np.array(v) for p, v in measure(case, key, a.rounds).items()}
            bat = t["batched"]
            line = f"{case:>16} {key:>9} {'per run' if CASES[case][4] else 'as is':>7} {1e6 * bat.min():9.2f}"
            meds = []
            for p in PATHS:
                best, med = t[p].min() / bat.min(), float(np.median(t[p] / bat))
                meds.append(med)
                line += f" {1e6 * t[p].min():9.2f} {best:5.2f}x/{med:5.2f}x"
            verdict = "batched keeps" if min(meds) >= 1.5 else "below 1.5x"
            print(f"{line}  {verdict}", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

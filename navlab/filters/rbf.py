"""Batched Gaussian radial-basis-function network (ALGORITHMS.md §6.2; S2 eqs. 14–15), pure numpy.

B independent networks are trained at once (one per Monte Carlo run), each on its own masked set of
samples, so nothing loops over runs:

1. z-score inputs and targets (per network, over its admissible samples);
2. nearest-neighbour clustering for the centres (S2: 最近邻聚类), radius adjusted ×/÷ 1.25 until
   J_min ≤ J ≤ J_max;
3. one shared width s_w per network chosen on a grid s_w ∈ r·{0.25 … 4} by the RMSE on the last
   20 % (chronological) of the samples, with centres and weights from the first 80 % (navlab's
   stand-in for S2's per-node widths tuned by a genetic algorithm, §10 item 24);
4. output weights by ridge least squares with a bias column, on all samples (centres redone on all
   samples); the hold-out RMSE of step 3 in physical units is kept as σ_NN.

Padded arrays: centres (B, J_max, d) with a mask; a run with fewer than ``min_samples`` admissible
samples stays untrained (``trained`` False). The least-squares systems of steps 3 and 4 are solved
for groups of runs with the same number of centres, each at its own size (:func:`by_centres`):
the padded systems were 6× the work of the reproduction's training (5.9 s → 0.9 s for 133 runs of
gps-ins-rtk), and a run's network is the same bit for bit in any batch (tested).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from navlab.errors import NavlabError
from navlab.linalg import SERIAL_GEMM, Array, mT

WIDTH_GRID = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0)


@dataclass(frozen=True)
class RBFNet:
    """B trained networks.

    Shapes: C (B, J, d), cmask (B, J), s_w (B, p) (width per output; all equal unless
    ``per_output``), W (B, J+1[+d], p): kernels, [linear tail,] bias; lin_on (B, p) which outputs
    use the linear tail (their other tail weights are exactly 0).
    """

    C: Array
    cmask: Array
    s_w: Array
    W: Array
    mu_u: Array
    sd_u: Array
    mu_y: Array
    sd_y: Array
    sigma_nn: Array  # (B, p) hold-out RMSE, physical units
    train_rmse: Array  # (B, p) fit RMSE on all training samples, physical units
    trained: Array  # (B,) bool
    n_centres: Array  # (B,) int
    linear: bool = False  # W has linear-tail rows (navlab option)
    lin_on: Array | None = None
    u_lo: Array | None = None  # (B, d) standardised input range of the training set; inputs are
    u_hi: Array | None = None  # clipped to it before evaluation (None: no clipping)

    def predict(self, u: Array) -> Array:
        """ŷ(u) for u (B, d) or (B, N, d) -> (B, p) or (B, N, p); NaN for untrained networks."""
        single = u.ndim == 2
        U = u[:, None, :] if single else u
        Us = (U - self.mu_u[:, None, :]) / self.sd_u[:, None, :]
        if self.u_lo is not None:
            Us = np.clip(Us, self.u_lo[:, None, :], self.u_hi[:, None, :])
        p = self.W.shape[2]
        d2 = sq_dist(Us, self.C)  # shared by the outputs' designs
        if np.all(self.s_w == self.s_w[:, :1]):
            Ys = mm(design(Us, self.C, self.cmask, self.s_w[:, 0], self.linear, d2=d2), self.W)
        else:
            Ys = np.concatenate(
                [
                    mm(
                        design(Us, self.C, self.cmask, self.s_w[:, j], self.linear, d2=d2),
                        self.W[..., j : j + 1],
                    )
                    for j in range(p)
                ],
                axis=-1,
            )
        Y = Ys * self.sd_y[:, None, :] + self.mu_y[:, None, :]
        Y = np.where(self.trained[:, None, None], Y, np.nan)
        return Y[:, 0] if single else Y


def mm(A: Array, B: Array) -> Array:
    """A @ B (stacked) in pieces of at most SERIAL_GEMM multiply-adds per matrix product.

    Splits the contraction (sums the partial products: the same sums, in another order) when the
    output is small, else the rows of A. Exactly ``A @ B`` up to round-off.
    """
    M, K = A.shape[-2:]
    N = B.shape[-1]
    if M * N * K <= SERIAL_GEMM:
        return A @ B
    if M * N * 8 <= SERIAL_GEMM:
        kc = SERIAL_GEMM // (M * N)
        out = A[..., :kc] @ B[..., :kc, :]
        for s in range(kc, K, kc):
            out += A[..., s : s + kc] @ B[..., s : s + kc, :]
        return out
    mc = max(1, SERIAL_GEMM // (N * K))
    return np.concatenate([mm(A[..., s : s + mc, :], B) for s in range(0, M, mc)], axis=-2)


def sq_dist(U: Array, C: Array) -> Array:
    """‖U_i − C_j‖² for U (B, N, d), C (B, J, d) -> (B, N, J), clipped at 0."""
    d2 = np.sum(U**2, -1)[:, :, None] + np.sum(C**2, -1)[:, None, :] - 2.0 * mm(U, mT(C))
    return np.maximum(d2, 0.0)


def design(
    Us: Array,
    C: Array,
    cmask: Array | None,
    s_w: Array,
    linear: bool = False,
    lin_on: Array | None = None,
    d2: Array | None = None,
) -> Array:
    """Φ (B, N, J+1[+d]): Gaussian kernels exp(−‖u − C_j‖²/(2 s_w²)) (S2 eq. 14), the inputs
    themselves if ``linear`` (a linear tail; zeroed for runs where ``lin_on`` (B,) is False) and a
    column of ones (the bias, last). ``cmask`` (B, J): the centres that exist (None: all of them);
    ``d2``: ``sq_dist(Us, C)`` if already computed.
    """
    d2 = sq_dist(Us, C) if d2 is None else d2
    K = np.exp(-d2 / (2.0 * s_w[:, None, None] ** 2))
    if cmask is not None:
        K *= cmask[:, None, :]
    tail = Us if lin_on is None else Us * lin_on[:, None, None]
    parts = [K, tail] if linear else [K]
    return np.concatenate([*parts, np.ones((*K.shape[:2], 1))], axis=-1)


def cluster(U: Array, mask: Array, r: Array, j_max: int) -> tuple[Array, Array, Array]:
    """Nearest-neighbour clustering of the masked samples, in order (§6.2 step 1).

    First sample → first centre; each next sample joins its nearest centre (running mean) unless
    it is farther than r, then it opens a new centre. At most ``j_max`` centres: when full, a far
    sample joins its nearest centre and ``overflow`` is set (radius too small).

    Returns C (B, j_max, d), cmask (B, j_max), overflow (B,).
    """
    B, N, d = U.shape
    # slot j_max is a scratch centre: runs whose sample i is not admissible "update" it, so every
    # step updates one slot per run without boolean indexing; its ‖C‖² stays +inf (never nearest)
    C = np.zeros((B, j_max + 1, d))
    S = np.zeros((B, j_max + 1, d))
    cnt = np.zeros((B, j_max + 1))
    C2 = np.full((B, j_max + 1), np.inf)  # ‖C_j‖²; +inf for centres not opened (d² = +inf)
    J = np.zeros(B, dtype=int)
    overflow = np.zeros(B, dtype=bool)
    rows = np.arange(B)
    r2 = r**2
    U2 = np.sum(U**2, axis=-1)
    jt = 1  # centres that exist somewhere (at least 1 column so argmin is defined)
    for i in range(N):
        valid = mask[:, i]
        if not valid.any():
            continue
        u = U[:, i]
        d2 = U2[:, i, None] + C2[:, :jt] - 2.0 * (C[:, :jt] @ u[:, :, None])[..., 0]
        j = np.argmin(d2, axis=1)
        far = d2[rows, j] > r2
        room = j_max > J
        new = valid & far & room
        overflow |= valid & far & ~room
        jn = np.where(valid, np.where(new, J, j), j_max)
        S[rows, jn] += u
        cnt[rows, jn] += 1.0
        c = S[rows, jn] / cnt[rows, jn][:, None]
        C[rows, jn] = c
        C2[rows, jn] = np.sum(c * c, axis=-1)
        C2[:, j_max] = np.inf
        if new.any():
            J = J + new
            jt = max(jt, int(J.max()))
    cmask = np.arange(j_max)[None, :] < J[:, None]
    return C[:, :j_max], cmask, overflow


def cluster_adaptive(
    U: Array, mask: Array, r0: Array, j_min: int, j_max: int, max_iter: int = 40
) -> tuple[Array, Array, Array]:
    """Clustering with the radius adjusted (×1.25 too many, ÷1.25 too few) until J_min ≤ J ≤ J_max.

    J_min is lowered to the number of admissible samples where there are fewer. Returns C, cmask, r.
    """
    r = np.array(r0, dtype=float)
    need = np.minimum(j_min, mask.sum(axis=1))
    done = need < 1  # nothing to cluster
    last = np.zeros(U.shape[0], dtype=int)  # last adjustment: +1 grew r, −1 shrank r
    C = cmask = None
    for _ in range(max_iter):
        C1, m1, over = cluster(U, mask, r, j_max)
        J = m1.sum(axis=1)
        if C is None:
            C, cmask = C1, m1
        upd = ~done
        C = np.where(upd[:, None, None], C1, C)
        cmask = np.where(upd[:, None], m1, cmask)
        too_many = over & upd
        too_few = (need > J) & upd
        # a radius that flips between too many and too few centres: keep the current clustering
        flip = (too_many & (last < 0)) | (too_few & (last > 0))
        done |= upd & ((~too_many & ~too_few) | flip)
        if done.all():
            break
        step = np.where(too_many, 1, np.where(too_few, -1, 0)) * ~done
        last = np.where(step != 0, step, last)
        r = np.where(step > 0, r * 1.25, np.where(step < 0, r / 1.25, r))
    return C, cmask, r


def ridge(Phi: Array, Y: Array, rows: Array, lam: float) -> Array:
    """W = argmin ‖Φ W − Y‖² + λ‖W‖² over the rows marked True (B, N) (§6.2 step 3)."""
    Pm = Phi * rows[:, :, None]
    PmT = mT(Pm)
    G = mm(PmT, Pm) + lam * np.eye(Phi.shape[-1])
    return np.linalg.solve(G, mm(PmT, Y))


def _gather_rows(Us: Array, Ys: Array, rows: Array, size: int) -> tuple[Array, Array, Array]:
    """The rows marked True of each network, moved to the front in chronological order.

    Returns U (B, size, d), Y (B, size, p) and ok (B, size) (False: padding, zero in U and Y);
    ``size`` is the most rows ANY network trained on this buffer can have (from the buffer length
    alone): the size of a run's systems must not depend on the other runs of its batch. Sized to
    the most rows of any run of the batch, the sums of the ridge products ran in a different
    order when the runs were chunked differently, and the width search's choice could flip: a
    run's NNMFUKF estimate moved by up to 5e-2 relative between one chunk of 6 runs and two of 3.
    """
    order = np.argsort(~rows, axis=1, kind="stable")[:, :size]
    ok = np.take_along_axis(rows, order, axis=1)
    U = np.take_along_axis(Us, order[..., None], axis=1) * ok[..., None]
    Y = np.take_along_axis(Ys, order[..., None], axis=1) * ok[..., None]
    return U, Y, ok


def split_sizes(N: int, holdout: float) -> tuple[int, int]:
    """The most fit and hold-out rows of a network trained on a buffer of N samples (any number
    n ≤ N of them admissible, the first ⌊(1 − holdout)·n⌋ for the fit).
    """
    n = np.arange(N + 1)
    n_fit = fit_rows(n, holdout)
    return int(n_fit.max()), int((n - n_fit).max())


def fit_rows(n: Array, holdout: float) -> Array:
    """How many of a network's n admissible samples (the first, chronologically) it fits on."""
    return np.floor((1.0 - holdout) * n).astype(int)


def by_centres(cm: Array) -> list[tuple[Array, int]]:
    """The runs grouped by their own number of centres: [(run indices, J)] for the centre masks
    ``cm`` (B, J_max) (a run's centres come first). Each group's systems are solved at their own
    size J, not padded to J_max: the same numbers for a run whatever its batch, and on the
    gps-ins-rtk scenario (J ≈ 30–70 of J_max = 100) a sixth of the padded work (measured).
    """
    J = cm.sum(axis=1)
    return [(np.flatnonzero(np.equal(J, j)), int(j)) for j in np.unique(J)]


def width_search(
    Us: Array,
    Ys: Array,
    fit: Array,
    val: Array,
    C: Array,
    cm: Array,
    r: Array,
    grid: tuple[float, ...],
    lin_opts: tuple[bool, ...],
    tail: bool,
    lam: float,
    sizes: tuple[int, int],
) -> tuple[list[Array], list[Array]]:
    """Hold-out score of every (linear tail, width) candidate of §6.2 step 2, in the order
    ``for lo in lin_opts for g in grid``: RMSE (B, p) on the ``val`` rows of the ridge fit on the
    ``fit`` rows with kernel width r·g, and the hold-out residuals (B, sizes[1], p).

    The same numbers as ``design`` + ``ridge`` per candidate (tests/unit/test_nnmfukf.py compares
    them), arranged to cost less: the runs are taken in groups of equal centre count
    (:func:`by_centres`), each at its own size; the fit and hold-out rows are gathered once (at
    most ``sizes`` = :func:`split_sizes` rows; the ridge sums run over the fit rows only, padding
    rows are exact zeros); the squared distances are computed once; and without a linear tail
    (lo False) the Gram matrix and right-hand side are those of the tail candidate with the tail
    rows and columns zeroed (exactly what zero tail columns give), so one Gram matrix per width
    serves both.
    """
    Uf, Yf, okf = _gather_rows(Us, Ys, fit, sizes[0])
    Uv, Yv, okv = _gather_rows(Us, Ys, val, sizes[1])
    n_cand = len(lin_opts) * len(grid)
    B, p = Us.shape[0], Ys.shape[2]
    scores = [np.empty((B, p)) for _ in range(n_cand)]
    resid = [np.empty((B, sizes[1], p)) for _ in range(n_cand)]
    for i, J in by_centres(cm):
        group = _width_search_group(
            Uf[i], Yf[i], okf[i], Uv[i], Yv[i], okv[i], C[i, :J], r[i], grid, lin_opts, tail, lam
        )
        for c, (score, E) in enumerate(group):
            scores[c][i], resid[c][i] = score, E
    return scores, resid


def _width_search_group(
    Uf, Yf, okf, Uv, Yv, okv, C, r, grid, lin_opts, tail, lam
) -> list[tuple[Array, Array]]:
    """:func:`width_search` for runs whose J centres C (b, J, d) all exist: [(RMSE, residuals)]
    per candidate, in its order.
    """
    J = C.shape[1]
    d = Uf.shape[2]
    nt = d if tail else 0
    n_col = J + nt + 1
    eye = lam * np.eye(n_col)
    d2f = np.where(~okf[:, :, None], np.inf, sq_dist(Uf, C))  # padding rows: kernel exactly 0
    d2v = sq_dist(Uv, C)
    res: dict[tuple[bool, float], tuple[Array, Array]] = {}
    # design matrices allocated once: the tail and bias columns do not depend on the width
    Phf = np.empty((*d2f.shape[:2], n_col))
    Phf[..., J : J + nt] = Uf[..., :nt] if tail else 0.0
    Phf[..., -1] = okf
    Phv = np.empty((*d2v.shape[:2], n_col))
    Phv[..., J : J + nt] = Uv[..., :nt] if tail else 0.0
    Phv[..., -1] = 1.0
    nd2f, nd2v = -d2f, -d2v
    Kf, Kv = Phf[..., :J], Phv[..., :J]
    for g in grid:
        h = 2.0 * (r * g)[:, None, None] ** 2
        np.exp(np.divide(nd2f, h, out=Kf), out=Kf)  # exp(−d²/(2 s_w²)) in place
        np.exp(np.divide(nd2v, h, out=Kv), out=Kv)
        PhfT = mT(Phf)
        G = mm(PhfT, Phf)
        rhs = mm(PhfT, Yf)
        for lo in lin_opts:
            if tail and not lo:
                G0, rhs0 = G.copy(), rhs.copy()
                G0[:, J : J + nt] = 0.0
                G0[:, :, J : J + nt] = 0.0
                rhs0[:, J : J + nt] = 0.0
                W = np.linalg.solve(G0 + eye, rhs0)  # tail weights exactly 0
            else:
                W = np.linalg.solve(G + eye, rhs)
            E = mm(Phv, W) - Yv
            res[(lo, g)] = (_masked_rmse(E, okv), E)
    return [res[(lo, g)] for lo in lin_opts for g in grid]


def _masked_rmse(E: Array, rows: Array) -> Array:
    """Per-output RMSE over masked rows: E (B, N, p), rows (B, N) -> (B, p) (NaN if no rows)."""
    n = rows.sum(axis=1)[:, None]
    ss = np.sum(E**2 * rows[:, :, None], axis=1)
    return np.sqrt(np.divide(ss, n, out=np.full(ss.shape, np.nan), where=n > 0))


def _fit_outputs(
    Us: Array,
    Ys: Array,
    C: Array,
    cm: Array,
    s_w: Array,
    lin: Array,
    rows: Array,
    lam: float,
    linear: bool,
) -> tuple[Array, Array]:
    """Ridge weights (B, J_max+1[+d], p) with a width s_w (B, p) and tail flag lin (B, p) per
    output; residuals on every sample. Solved per group of equal centre count at its own size
    (:func:`by_centres`); the weights of a run's absent centres are exactly 0.
    """
    B, N, p = Ys.shape
    J_max = C.shape[1]
    nt = Us.shape[2] if linear else 0
    W = np.zeros((B, J_max + nt + 1, p))
    E = np.empty((B, N, p))
    for i, J in by_centres(cm):
        Wg, E[i] = _fit_group(Us[i], Ys[i], C[i, :J], s_w[i], lin[i], rows[i], lam, linear)
        W[i, :J], W[i, J_max:] = Wg[:, :J], Wg[:, J:]
    return W, E


def _fit_group(Us, Ys, C, s_w, lin, rows, lam, linear) -> tuple[Array, Array]:
    """:func:`_fit_outputs` for runs whose centres C (b, J, d) all exist."""
    p = Ys.shape[2]
    d2 = sq_dist(Us, C)
    if np.all(s_w == s_w[:, :1]) and np.all(lin == lin[:, :1]):  # one design for every output
        Phi = design(Us, C, None, s_w[:, 0], linear, lin[:, 0], d2)
        W = ridge(Phi, Ys, rows, lam)
        return W, mm(Phi, W) - Ys
    Ws, Es = [], []
    for j in range(p):
        Phi = design(Us, C, None, s_w[:, j], linear, lin[:, j], d2)
        Wj = ridge(Phi, Ys[..., j : j + 1], rows, lam)
        Ws.append(Wj)
        Es.append(mm(Phi, Wj) - Ys[..., j : j + 1])
    return np.concatenate(Ws, axis=-1), np.concatenate(Es, axis=-1)


def train(
    U: Array,
    Y: Array,
    mask: Array,
    *,
    j_min: int = 10,
    j_max: int = 100,
    r0: float | None = None,
    lam: float = 1e-6,
    holdout: float = 0.2,
    min_samples: int = 20,
    width_grid: tuple[float, ...] = WIDTH_GRID,
    s_w: Array | None = None,
    linear: bool | str = False,
    per_output: bool = False,
    lin_on: Array | None = None,
    clip: bool = True,
) -> RBFNet:
    """Train B networks on samples U (B, N, d) → Y (B, N, p) where ``mask`` (B, N) is True.

    Samples are in chronological order. ``s_w`` given ((B,) or (B, p)): skip the width search
    (online refits; then ``lin_on`` (B, p) too). ``linear``: add a linear tail to the output layer
    (True), or let the hold-out choose per output between with and without it ("auto");
    ``per_output``: choose the width separately for each output; ``clip``: clip inputs to the
    training range when predicting (a guard against extrapolation, e.g. an IMU input disturbed far
    beyond anything seen in training). These are navlab options, not S2.
    """
    U = np.asarray(U, dtype=float)
    Y = np.asarray(Y, dtype=float)
    mask = np.asarray(mask, dtype=bool) & np.all(np.isfinite(U), -1) & np.all(np.isfinite(Y), -1)
    if U.ndim != 3 or Y.ndim != 3 or U.shape[:2] != Y.shape[:2] or mask.shape != U.shape[:2]:
        raise NavlabError("RBF training data must be U (B, N, d), Y (B, N, p) and a (B, N) mask")
    if not 1 <= j_min <= j_max:
        raise NavlabError(f"RBF network: need 1 ≤ J_min ≤ J_max, got {j_min}, {j_max}")
    B, _N, d = U.shape
    p = Y.shape[2]
    n = mask.sum(axis=1)
    trained = n >= max(min_samples, 2)
    m = mask[:, :, None]
    nn = np.maximum(n, 1)[:, None]
    mu_u = np.sum(np.where(m, U, 0.0), 1) / nn
    mu_y = np.sum(np.where(m, Y, 0.0), 1) / nn
    sd_u = np.sqrt(np.sum(np.where(m, (U - mu_u[:, None]) ** 2, 0.0), 1) / nn)
    sd_y = np.sqrt(np.sum(np.where(m, (Y - mu_y[:, None]) ** 2, 0.0), 1) / nn)
    sd_u = np.where(sd_u > 1e-12 * (1 + np.abs(mu_u)), sd_u, 1.0)  # constant inputs: no scaling
    sd_y = np.where(sd_y > 1e-12 * (1 + np.abs(mu_y)), sd_y, 1.0)
    Us = np.where(m, (U - mu_u[:, None]) / sd_u[:, None], 0.0)
    Ys = np.where(m, (Y - mu_y[:, None]) / sd_y[:, None], 0.0)
    r_init = np.full(B, 0.5 * np.sqrt(d) if r0 is None else float(r0))

    # chronological split of each network's own admissible samples
    rank = np.cumsum(mask, axis=1) - 1
    n_fit = fit_rows(n, holdout)
    fit = mask & (rank < n_fit[:, None])
    val = mask & ~fit
    tail = bool(linear)  # "auto" and True both carry tail rows
    lin_opts = (False, True) if linear == "auto" else (bool(linear),)
    if s_w is None:
        C, cm, r = cluster_adaptive(Us, fit, r_init, j_min, j_max)
        sizes = split_sizes(U.shape[1], holdout)
        scores, E_val = width_search(Us, Ys, fit, val, C, cm, r, width_grid, lin_opts, tail, lam, sizes)
        best = np.full((B, p), np.inf)
        s_best = np.repeat(r[:, None], p, axis=1)
        l_best = np.full((B, p), lin_opts[0])
        E_best = np.zeros_like(E_val[0])
        for c, (lo, g) in enumerate((lo, g) for lo in lin_opts for g in width_grid):
            score = scores[c]  # (B, p), standardised
            if not per_output:
                score = np.repeat(np.mean(score, axis=1, keepdims=True), p, axis=1)
            score = np.where(np.isfinite(score), score, np.inf)
            better = score < best
            best = np.where(better, score, best)
            s_best = np.where(better, (r * g)[:, None], s_best)
            l_best = np.where(better, lo, l_best)
            # the winner's hold-out residuals (the fit with s_best, l_best redone gives these)
            E_best = np.where(better[:, None, :], E_val[c], E_best)
        ok_v = np.arange(E_best.shape[1])[None, :] < val.sum(axis=1)[:, None]
        sigma_nn = _masked_rmse(E_best, ok_v) * sd_y
        s_w, lin_on = s_best, l_best
    else:
        s_w = np.broadcast_to(np.asarray(s_w, dtype=float).reshape(B, -1), (B, p)).copy()
        lin_on = np.full((B, p), tail) if lin_on is None else np.asarray(lin_on, dtype=bool)
        sigma_nn = np.full((B, p), np.nan)
    C, cm, _ = cluster_adaptive(Us, mask, r_init, j_min, j_max)
    W, E = _fit_outputs(Us, Ys, C, cm, s_w, lin_on, mask, lam, tail)
    train_rmse = _masked_rmse(E, mask) * sd_y
    sigma_nn = np.where(np.isfinite(sigma_nn), sigma_nn, train_rmse)
    return RBFNet(
        C=C,
        cmask=cm,
        s_w=s_w,
        W=W,
        mu_u=mu_u,
        sd_u=sd_u,
        mu_y=mu_y,
        sd_y=sd_y,
        sigma_nn=sigma_nn,
        train_rmse=train_rmse,
        trained=trained,
        n_centres=cm.sum(axis=1),
        linear=tail,
        lin_on=lin_on,
        u_lo=np.min(np.where(m, Us, np.inf), axis=1) if clip else None,
        u_hi=np.max(np.where(m, Us, -np.inf), axis=1) if clip else None,
    )

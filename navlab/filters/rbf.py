"""Gaussian radial-basis-function network (ALGORITHMS.md §6.2; S2 eqs. 14–15).

One network is trained on one run's admissible samples, in chronological order, one step of
§6.2 a line (:func:`train_one`): inputs and targets z-scored, then

1. nearest-neighbour clustering for the centres (S2: 最近邻聚类), radius adjusted ×/÷ 1.25 until
   J_min ≤ J ≤ J_max (:func:`cluster`, :func:`cluster_adaptive`);
2. one shared width s_w chosen on a grid s_w ∈ r·{0.25 … 4} by the RMSE on the last 20 %
   (chronological) of the samples, with centres and weights from the first 80 % (navlab's
   stand-in for S2's per-node widths tuned by a genetic algorithm, §10 item 24;
   :func:`width_search`);
3. output weights by ridge least squares with a bias column, on all samples (centres redone on all
   samples; :func:`fit_weights`);
4. the hold-out RMSE of step 2 in physical units kept as σ_NN.

:func:`train` trains the B networks of a Monte Carlo batch (one per run) one run at a time, so a
run's network is the same bit for bit in any batch, and pads them into one :class:`RBFNet`
(centres to J_max) for the batched prediction. The clustering, a loop over the samples, is
compiled (:mod:`navlab.jit`); the same Python is the fallback.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass

import numpy as np

from navlab.errors import NavlabError
from navlab.jit import Kernel, carray
from navlab.linalg import SERIAL_GEMM, Array, mT

WIDTH_GRID = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0)


@dataclass(frozen=True)
class RBFNet:
    """B trained networks.

    Shapes: C (B, J, d), cmask (B, J), s_w (B, p) (width per output; all equal unless
    ``per_output``), W (B, J+1[+d], p): kernels, [linear tail,] bias (the rows of absent centres
    and the tail rows of outputs without a tail are exactly 0); lin_on (B, p) which outputs use
    the linear tail.
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
        d2 = sq_dist(Us, self.C)  # shared by the outputs' designs
        p = self.W.shape[2]  # one design for all outputs if their widths are equal, else one each
        outs = [slice(None)] if np.all(self.s_w == self.s_w[:, :1]) else [slice(j, j + 1) for j in range(p)]
        Ys = np.concatenate(
            [mm(design(Us, self.C, self.s_w[:, o][:, 0], self.linear, d2), self.W[..., o]) for o in outs], -1
        )
        Y = Ys * self.sd_y[:, None, :] + self.mu_y[:, None, :]
        Y = np.where(self.trained[:, None, None], Y, np.nan)
        return Y[:, 0] if single else Y


def mm(A: Array, B: Array) -> Array:
    """A @ B (stacked or not) in pieces of at most SERIAL_GEMM multiply-adds per matrix product.

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
    """‖U_i − C_j‖² for U (..., N, d), C (..., J, d) -> (..., N, J), clipped at 0."""
    d2 = np.sum(U**2, -1)[..., :, None] + np.sum(C**2, -1)[..., None, :] - 2.0 * mm(U, mT(C))
    return np.maximum(d2, 0.0)


def design(Us: Array, C: Array, s_w: Array | float, linear: bool, d2: Array | None = None) -> Array:
    """Φ (..., N, J+1[+d]): the Gaussian kernels exp(−‖u − C_j‖²/(2 s_w²)) (S2 eq. 14), the
    inputs themselves if ``linear`` (a linear tail) and a column of ones (the bias, last).
    ``d2``: ``sq_dist(Us, C)`` if already computed.
    """
    d2 = sq_dist(Us, C) if d2 is None else d2
    K = np.exp(-d2 / (2.0 * np.asarray(s_w)[..., None, None] ** 2))
    return np.concatenate([K, *([Us] if linear else []), np.ones((*K.shape[:-1], 1))], axis=-1)


def ridge(Phi: Array, Y: Array, lam: float) -> Array:
    """W = argmin ‖Φ W − Y‖² + λ‖W‖² (§6.2 step 3), by the normal equations."""
    return np.linalg.solve(mm(Phi.T, Phi) + lam * np.eye(Phi.shape[1]), mm(Phi.T, Y))


def cluster(U: Array, r: float, j_max: int) -> tuple[Array, int, bool]:
    """Nearest-neighbour clustering of one run's samples U (n, d), in order (§6.2 step 1).

    First sample → first centre; each next sample joins its nearest centre (running mean) unless
    it is farther than r, then it opens a new centre. At most ``j_max`` centres: when full, a far
    sample joins its nearest centre and ``overflow`` is set (radius too small).

    Returns C (j_max, d) (the first J rows are the centres), J, overflow.
    """
    n, d = U.shape
    C = np.zeros((j_max, d))
    S = np.zeros((j_max, d))  # running sums
    count = np.zeros(j_max)
    J = 0
    overflow = False
    for i in range(n):
        j, best = 0, np.inf  # the nearest centre j* and ‖u − C_j*‖²
        for c in range(J):
            d2 = 0.0
            for k in range(d):
                d2 += (U[i, k] - C[c, k]) ** 2
            if d2 < best:
                j, best = c, d2
        if best > r * r:  # farther than r from every centre: a new one
            if j_max > J:
                j, J = J, J + 1
            else:
                overflow = True
        S[j] += U[i]
        count[j] += 1.0
        C[j] = S[j] / count[j]
    return C, J, overflow


CLUSTER = Kernel(cluster)


def cluster_adaptive(U: Array, r: float, j_min: int, j_max: int, max_iter: int = 40) -> tuple[Array, float]:
    """Centres C (J, d) of one run's samples U (n, d) with the radius adjusted (×1.25 too many,
    ÷1.25 too few) until J_min ≤ J ≤ J_max, and that radius r. J_min is lowered to n where n is
    smaller; a radius that flips between too many and too few keeps the current clustering.
    """
    run = CLUSTER.get() or cluster
    need, last = min(j_min, len(U)), 0  # last: +1 grew r, −1 shrank r
    U = carray(U)
    for _ in range(max_iter):
        C, J, too_many = run(U, r, j_max)
        too_few = need > J
        if not (too_many or too_few) or (too_many and last < 0) or (too_few and last > 0):
            break
        last = 1 if too_many else -1
        r = r * 1.25 if too_many else r / 1.25
    return C[:J], r


# one run's network (the fields of RBFNet without the batch axis; W (J+1[+d], p))
Network = namedtuple("Network", "C s_w lin_on W mu_u sd_u mu_y sd_y sigma_nn train_rmse u_lo u_hi")


def zscore(X: Array) -> tuple[Array, Array, Array]:
    """(X − μ)/σ per column, μ, σ (σ = 1 for a constant column: no scaling)."""
    mu = np.sum(X, axis=0) / len(X)
    sd = np.sqrt(np.sum((X - mu) ** 2, axis=0) / len(X))
    sd = np.where(sd > 1e-12 * (1 + np.abs(mu)), sd, 1.0)
    return (X - mu) / sd, mu, sd


def width_search(Us, Ys, C, r, grid, lin_opts, lam, per_output, n_fit) -> tuple[Array, Array, Array]:
    """§6.2 step 2: (s_w, linear tail on, hold-out RMSE) per output (p,) of the candidate, in the
    order ``for lo in lin_opts for g in grid``, with the least hold-out RMSE on samples n_fit…
    of the ridge fit on samples …n_fit (its mean over the outputs unless ``per_output``; the
    first candidate on ties).
    """
    p = Ys.shape[1]
    d2f, d2v = sq_dist(Us[:n_fit], C), sq_dist(Us[n_fit:], C)  # the same for every candidate
    best, s_w, lin, rmse = np.full(p, np.inf), np.full(p, r), np.full(p, lin_opts[0]), np.full(p, np.nan)
    for lo in lin_opts:
        for g in grid:
            W = ridge(design(Us[:n_fit], C, r * g, lo, d2f), Ys[:n_fit], lam)
            e = np.sqrt(np.mean((mm(design(Us[n_fit:], C, r * g, lo, d2v), W) - Ys[n_fit:]) ** 2, axis=0))
            score = e if per_output else np.full(p, np.mean(e))
            better = np.where(np.isfinite(score), score, np.inf) < best
            best[better], s_w[better], lin[better], rmse[better] = score[better], r * g, lo, e[better]
    return s_w, lin, rmse


def fit_weights(Us, Ys, C, s_w, lin, lam, tail) -> tuple[Array, Array]:
    """§6.2 step 3: ridge weights W (J+1[+d], p) on all samples, one design per group of outputs
    of equal width and tail flag (tail rows: exactly 0 where off), and the residuals (N, p).
    """
    J, d = C.shape
    W, E = np.zeros((J + (d if tail else 0) + 1, Ys.shape[1])), np.empty_like(Ys)
    d2 = sq_dist(Us, C)
    for s, lo in dict.fromkeys(zip(s_w, lin, strict=True)):
        out = (s_w == s) & (lin == lo)
        Phi = design(Us, C, s, lo, d2)
        Wo = ridge(Phi, Ys[:, out], lam)
        rows = np.r_[: J + (d if lo else 0), -1]  # kernels, [tail,] bias
        W[np.ix_(rows, out)] = Wo
        E[:, out] = mm(Phi, Wo) - Ys[:, out]
    return W, E


def train_one(
    U, Y, *, j_min, j_max, r0, lam, holdout, width_grid, s_w, linear, per_output, lin_on
) -> Network:
    """One network on one run's admissible samples U (n, d) → Y (n, p), chronological (see
    :func:`train` for the options; ``s_w``, ``lin_on`` (p,) or None).
    """
    Us, mu_u, sd_u = zscore(U)  # standardised units from here on
    Ys, mu_y, sd_y = zscore(Y)
    sigma_nn = np.full(Y.shape[1], np.nan)
    if s_w is None:
        n_fit = int(np.floor((1.0 - holdout) * len(U)))  # the first 80 % fit, the last 20 % score
        C, r = cluster_adaptive(Us[:n_fit], r0, j_min, j_max)
        lin_opts = (False, True) if linear == "auto" else (bool(linear),)
        s_w, lin_on, sigma_nn = width_search(Us, Ys, C, r, width_grid, lin_opts, lam, per_output, n_fit)
    C, _ = cluster_adaptive(Us, r0, j_min, j_max)  # centres redone on all samples
    W, E = fit_weights(Us, Ys, C, s_w, lin_on, lam, bool(linear))
    train_rmse = np.sqrt(np.mean(E**2, axis=0)) * sd_y
    sigma_nn = np.where(np.isfinite(sigma_nn), sigma_nn * sd_y, train_rmse)
    return Network(C, s_w, lin_on, W, mu_u, sd_u, mu_y, sd_y, sigma_nn, train_rmse, Us.min(0), Us.max(0))


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
    beyond anything seen in training). These are navlab options, not S2. A run with fewer than
    ``min_samples`` admissible samples is not ``trained`` (its network predicts NaN).
    """
    U = np.asarray(U, dtype=float)
    Y = np.asarray(Y, dtype=float)
    mask = np.asarray(mask, dtype=bool) & np.all(np.isfinite(U), -1) & np.all(np.isfinite(Y), -1)
    if U.ndim != 3 or Y.ndim != 3 or U.shape[:2] != Y.shape[:2] or mask.shape != U.shape[:2]:
        raise NavlabError("RBF training data must be U (B, N, d), Y (B, N, p) and a (B, N) mask")
    if not 1 <= j_min <= j_max:
        raise NavlabError(f"RBF network: need 1 ≤ J_min ≤ J_max, got {j_min}, {j_max}")
    B, _, d = U.shape
    p = Y.shape[2]
    tail = bool(linear)
    r0 = 0.5 * np.sqrt(d) if r0 is None else float(r0)
    search = s_w is None
    if search:  # what a run without two admissible samples keeps
        s_w, lin_on = np.full((B, p), r0), np.full((B, p), linear is True)
    else:
        s_w = np.broadcast_to(np.asarray(s_w, dtype=float).reshape(B, -1), (B, p))
        lin_on = np.full((B, p), tail) if lin_on is None else np.asarray(lin_on, dtype=bool)
    opts = dict(j_min=j_min, j_max=j_max, r0=r0, lam=lam, holdout=holdout, width_grid=width_grid)
    opts.update(linear=linear, per_output=per_output)
    nets = [
        train_one(U[b, m], Y[b, m], s_w=None if search else s_w[b], lin_on=lin_on[b], **opts)
        if m.sum() >= 2
        else _no_network(d, p, tail, s_w[b], lin_on[b])
        for b, m in enumerate(mask)
    ]
    J = np.array([len(net.C) for net in nets])
    C = np.zeros((B, j_max, d))
    W = np.zeros((B, j_max + (d if tail else 0) + 1, p))
    for b, net in enumerate(nets):  # padded: absent centres have zero weights
        C[b, : J[b]], W[b, : J[b]], W[b, j_max:] = net.C, net.W[: J[b]], net.W[J[b] :]
    field = {
        name: np.stack([getattr(net, name) for net in nets]) for name in Network._fields if name not in "CW"
    }
    field.update(C=C, W=W, lin_on=field["lin_on"].astype(bool))
    if not clip:
        field.update(u_lo=None, u_hi=None)
    return RBFNet(
        **field,
        cmask=np.arange(j_max)[None, :] < J[:, None],
        trained=mask.sum(axis=1) >= max(min_samples, 2),
        n_centres=J,
        linear=tail,
    )


def _no_network(d: int, p: int, tail: bool, s_w: Array, lin_on: Array) -> Network:
    """The network of a run without two admissible samples: no centres, zero weights (untrained)."""
    W, nan = np.zeros(((d if tail else 0) + 1, p)), np.full(p, np.nan)
    u, y = (np.zeros(d), np.ones(d)), (np.zeros(p), np.ones(p))  # (μ, σ)
    return Network(np.zeros((0, d)), s_w, lin_on, W, *u, *y, nan, nan, np.zeros(d), np.zeros(d))

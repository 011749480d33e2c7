"""Monte Carlo statistics: confidence intervals over runs, paired comparisons, Holm's correction.

The rules are those of the project's statistics spec (STATISTICS.md, shipped as
docs/STATISTICS.md):

* The unit of replication is the RUN: runs are independent, the epochs inside a run are not.
  Every interval here resamples runs, never epochs.
* A metric is written as a function of per-run statistics: an :class:`Estimator` holds the
  per-run arrays (one row per run) and knows how to evaluate the metric with run weights, so a
  bootstrap resample of the runs is one matrix product ``W @ A`` (``W`` the B × N multinomial
  resample counts) — no Python loop per resample.
* Every filter of an experiment is evaluated with the SAME resample weights (one
  :class:`Resampler` per set of runs), which makes a paired comparison free:
  Δ* = metric_A(W) − metric_B(W).
* Intervals are 95 % bias-corrected and accelerated (BCa) bootstrap intervals (B = 2000
  resamples from a seeded generator; acceleration from the leave-one-run-out jackknife),
  *expanded* for small run counts (Hesterberg 2015: the nominal normal quantile is
  √(N/(N−1))·t_{N−1, 0.975} instead of 1.96). Measured over 200 repeats of a 20-run experiment
  with a known truth (tests/unit/test_stats.py), the plain percentile interval covered the pooled
  RMSE in 89.5 % and the mean of the per-epoch RMSE (a biased statistic at small N) in 87.5 %;
  the expanded BCa interval covers both in ≥ 92 %. At and above :data:`DELTA_FROM` runs:
  delta-method (normal) intervals from the per-run influence values, accurate there and nearly
  free (quantiles keep the bootstrap, in blocks of resamples so memory stays bounded). Which
  one was used is returned with every estimate (``method``). With fewer than
  :data:`MIN_RUNS` runs there is no interval.
* Paired p-values: one bootstrap, inverted for both — the p-value is the largest α whose
  (expanded BCa) (1 − α) interval, from the same replicates and quantiles, still holds 0, so
  p < 0.05 exactly when the 95 % interval excludes 0, a bias-corrected maximum included
  (:func:`_inverted_p`; for the plain percentile interval this is the spec's
  ``2·min(P*(Δ ≤ 0), P*(Δ ≥ 0))``); where no level holds 0 it is below the bootstrap's
  resolution and reported as the bound :func:`floor_p` ("p < …", ``at_floor``), never 0.
  Delta: ``p = 2 Φ(−|Δ|/se)``. A run lost by one filter of a pair is scored as its loss
  (:func:`with_losses`, docs/STATISTICS.md §5).
  Several filters against one reference: Holm's step-down correction (:func:`holm`).

References: Efron & Tibshirani, *An Introduction to the Bootstrap*, 1993 (ch. 13–14);
T. C. Hesterberg, "What teachers should know about the bootstrap", The American Statistician
69(4), 2015 (the expanded percentile interval); S. Holm, Scand. J. Statist. 6, 1979.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri, stdtr, stdtrit

Array = np.ndarray

N_BOOT = 2000  # bootstrap resamples
LEVEL = 0.95  # two-sided confidence level
ALPHA = 1.0 - LEVEL  # family-wise error rate of the paired verdicts (Holm)
MIN_RUNS = 10  # fewer runs: no interval ("too few runs for an interval")
DELTA_FROM = 1000  # this many runs or more: delta-method intervals
PSI_CACHE_RUNS = 100_000  # above: influence values are not kept (Estimator.psi)
BLOCK = 250  # resamples per block where the bootstrap runs at large N
Z = 1.959963984540054  # Φ⁻¹(0.975)

TOO_FEW = f"too few runs for an interval (< {MIN_RUNS})"


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its 95 % interval (NaN bounds where there is none, with ``note``)."""

    value: float
    lo: float = float("nan")
    hi: float = float("nan")
    method: str = ""  # "bootstrap", "delta" or "" (no interval)
    note: str = ""

    @property
    def has_ci(self) -> bool:
        return bool(np.isfinite(self.lo) and np.isfinite(self.hi))


@dataclass(frozen=True)
class Comparison:
    """A paired difference Δ = A − B (or a relative one) with its interval and p-value."""

    value: float
    lo: float
    hi: float
    p_value: float
    method: str
    n_runs: int
    note: str = ""
    at_floor: bool = False  # the bootstrap's resolution: no resample on the other side of 0

    @property
    def p_text(self) -> str:
        """'p = 0.012', or 'p < 0.0011' where no resample fell on the other side of 0."""
        return format_p(self.p_value, self.at_floor)


class Estimator:
    """A metric as a function of per-run statistics (a row per run).

    Subclasses implement :meth:`point` (the value from run weights ``w`` (N,), all ones for the
    sample itself), :meth:`boot` (the values for a block of resample weights ``W`` (b, N)) and,
    where a delta-method interval exists, :meth:`influence` (per-run influence values ψ (N,)
    with Σψ = 0, such that the estimate's variance is Σψ²/N²).
    """

    n: int  # runs
    smooth = True  # a smooth function of run means: the BCa acceleration applies

    def point(self) -> float:
        raise NotImplementedError

    def boot(self, W: Array) -> Array:
        raise NotImplementedError

    def influence(self) -> Array | None:
        return None

    def psi(self) -> Array | None:
        """:meth:`influence`, computed once per estimator (the delta method and every paired
        comparison of this estimator reuse it) up to ``PSI_CACHE_RUNS`` runs; beyond, computed
        again at each use (O(N), cheap beside the runs; cached, one (N,) array per metric and
        filter held 450 bytes per run for two filters: 0.45 GB at a million runs).
        """
        if self.n > PSI_CACHE_RUNS:
            return self.influence()
        if "_psi" not in self.__dict__:
            self.__dict__["_psi"] = self.influence()
        return self.__dict__["_psi"]


def _safe_div(a: Array, b: Array) -> Array:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(b > 0, a / np.where(b > 0, b, 1.0), np.nan)


class Ratio(Estimator):
    """``f(Σ_r num_r / Σ_r den_r)`` with f = scale·x or scale·√x.

    Pooled RMSE over runs and epochs (num = the run's sum of squared errors, den = its epoch
    count, √), ANEES/ANIS (sums and counts of the finite NEES/NIS entries), rates in % (hits and
    opportunities, scale 100), the R̂ error (sum of |σ̂/σ − 1| and count, scale 100).
    """

    def __init__(self, num: Array, den: Array, *, sqrt: bool = False, scale: float = 1.0) -> None:
        self.num = np.asarray(num, dtype=float)
        self.den = np.asarray(den, dtype=float)
        self.sqrt, self.scale = sqrt, float(scale)
        self.n = int(self.num.shape[0])

    def _f(self, r: Array) -> Array:
        return self.scale * (np.sqrt(r) if self.sqrt else r)

    def point(self) -> float:
        return float(self._f(_safe_div(self.num.sum(), self.den.sum())))

    def boot(self, W: Array) -> Array:
        return self._f(_safe_div(W @ self.num, W @ self.den))

    def influence(self) -> Array | None:
        D = self.den.sum()
        if not D > 0:
            return None
        R = self.num.sum() / D
        dbar = D / self.n
        lin = (self.num - R * self.den) / dbar  # influence of the ratio itself
        if self.sqrt:
            if not R > 0:
                return None
            return self.scale * lin / (2.0 * np.sqrt(R))
        return self.scale * lin


class MeanSqrtRatio(Estimator):
    """``scale · mean_k √(Σ_r num_rk / Σ_r den_rk)`` over the epochs k with data.

    The mean over epochs of the per-epoch Monte Carlo RMSE (num = squared errors (N, K),
    den = 1 where the run counts at epoch k; ``den=None``: every run counts at every epoch).
    """

    def __init__(self, num: Array, den: Array | None = None, *, scale: float = 1.0) -> None:
        self.num = np.asarray(num)
        self.den = None if den is None else np.asarray(den, dtype=float)
        self.scale = float(scale)
        self.n = int(self.num.shape[0])

    def _f(self, N: Array, D: Array) -> Array:
        r = np.sqrt(_safe_div(N, D))
        ok = np.isfinite(r)
        cnt = ok.sum(axis=-1)
        total = np.where(ok, r, 0.0).sum(axis=-1)
        return self.scale * np.where(cnt > 0, total / np.maximum(cnt, 1), np.nan)

    def _den(self, W: Array | None) -> Array:
        """Σ_r w_r den_rk: (K,) for the sample, (b, K) for resample weights W (b, N)."""
        if self.den is not None:
            return self.den.sum(axis=0) if W is None else W @ self.den
        K = self.num.shape[1]
        if W is None:
            return np.full(K, float(self.n))
        return np.broadcast_to(W.sum(axis=1)[:, None], (W.shape[0], K))

    def _totals(self) -> Array:
        """Σ_r num_rk, (K,): computed once (the point value and the influence values use it)."""
        if "_totals_k" not in self.__dict__:
            self.__dict__["_totals_k"] = self.num.sum(axis=0, dtype=float)
        return self.__dict__["_totals_k"]

    def point(self) -> float:
        return float(self._f(self._totals(), self._den(None)))

    def boot(self, W: Array) -> Array:
        return self._f(W @ self.num, self._den(W))

    def influence(self) -> Array | None:
        D = self._den(None)
        keep = D > 0
        if not keep.any():
            return None
        R = self._totals()[keep] / D[keep]
        if not (R > 0).all():
            return None
        dbar = D[keep] / self.n
        c = 1.0 / (2.0 * np.sqrt(R) * dbar)
        num = self.num if keep.all() else self.num[:, keep]
        # ψ_r ∝ Σ_k (num_rk − R_k den_rk) c_k, as num @ c − den @ (R c): one pass over the (N, K)
        # per-epoch errors and no temporary of their size (equal to round-off)
        den_rc = np.dot(R, c) if self.den is None else self.den[:, keep] @ (R * c)
        return self.scale * (num @ c - den_rc) / keep.sum()


class MaxSqrtRatio(MeanSqrtRatio):
    """``scale · max_k √(Σ_r num_rk / Σ_r den_rk)``: the peak of the per-epoch Monte Carlo RMSE.

    Not smooth (the epoch of the peak can change between resamples): bootstrap only, bias
    corrected but without the jackknife acceleration (meaningless for a maximum).
    """

    smooth = False

    def _f(self, N: Array, D: Array) -> Array:
        r = np.sqrt(_safe_div(N, D))
        r = np.where(np.isfinite(r), r, -np.inf)
        out = r.max(axis=-1)
        return self.scale * np.where(np.isfinite(out), out, np.nan)

    def influence(self) -> Array | None:
        return None


class Quantile(Estimator):
    """The ``q``-quantile of every finite value of every run pooled (values (N, K), NaN = none).

    E.g. the median horizontal error over all epochs and runs. Bootstrap only (no delta form):
    the runs' values are sorted once, then each resample is a weighted quantile (cumulative run
    weights along the sorted values). Not smooth: bias corrected, no jackknife acceleration.
    """

    smooth = False

    def __init__(self, values: Array, q: float) -> None:
        v = np.asarray(values, dtype=float)
        self.values = v  # the per-run values (a loss rule fills a lost run's: with_losses)
        self.n = int(v.shape[0])
        self.q = float(q)
        run = np.broadcast_to(np.arange(self.n)[:, None], v.shape)
        ok = np.isfinite(v)
        order = np.argsort(v[ok], kind="stable")
        self.sorted = v[ok][order]
        self.run = run[ok][order]
        self.per_run = ok.sum(axis=1).astype(float)  # finite values per run

    def _wq(self, w: Array) -> Array:
        """Weighted q-quantile for weights w (b, N) on runs: the lower weighted quantile."""
        if self.sorted.size == 0:
            return np.full(w.shape[0], np.nan)
        cw = np.cumsum(w[:, self.run], axis=1)  # (b, M)
        total = cw[:, -1:]
        idx = np.argmax(cw >= self.q * total, axis=1)
        out = self.sorted[idx]
        return np.where(total[:, 0] > 0, out, np.nan)

    def point(self) -> float:
        if self.sorted.size == 0:
            return float("nan")
        # the usual (interpolated) quantile; the resamples take the weighted lower quantile, which
        # differs by less than one gap between neighbouring values
        return float(np.quantile(self.sorted, self.q))

    def boot(self, W: Array) -> Array:
        return self._wq(W)


class _Combined(Estimator):
    """op(a, b) of two estimators over the SAME runs (paired): Δ = a − b or (a − b)/b."""

    def __init__(self, a: Estimator, b: Estimator, relative: bool) -> None:
        if a.n != b.n:
            raise ValueError("a paired comparison needs the same runs for both estimators")
        self.a, self.b, self.relative, self.n = a, b, relative, a.n
        self.smooth = a.smooth and b.smooth

    def _op(self, va, vb):
        with np.errstate(divide="ignore", invalid="ignore"):
            return (va - vb) / vb if self.relative else va - vb

    def point(self) -> float:
        return float(self._op(self.a.point(), self.b.point()))

    def boot(self, W: Array) -> Array:
        return self._op(self.a.boot(W), self.b.boot(W))

    def influence(self) -> Array | None:
        ia, ib = self.a.psi(), self.b.psi()
        if ia is None or ib is None:
            return None
        if not self.relative:
            return ia - ib
        va, vb = self.a.point(), self.b.point()
        if not vb:
            return None
        return (ia - (va / vb) * ib) / vb


def _worst(values: Array, sign: int) -> Array:
    """Per column, the worst finite value (max where lower is better), NaN where none."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an epoch no run reached: NaN
        return np.nanmax(values, axis=0) if sign > 0 else np.nanmin(values, axis=0)


def with_losses(
    a: Estimator, b: Estimator, lost_a: Array, lost_b: Array, sign: int
) -> tuple[Estimator, Estimator]:
    """The estimators ``a`` and ``b`` (over the same runs) with each one's LOST runs (diverged)
    scored as the worst per-run value of the pair (docs/STATISTICS.md §5, the loss rule).

    The composite strategy (ICH E9(R1)): losing a run is part of the outcome, and its worst
    form — the lost run takes, for that filter, the worst value any run of either filter
    reached (per epoch for per-epoch statistics), ``sign`` +1 where lower is better, −1 where
    higher is. So a lost run ranks last for its filter (a loss, or a tie where both lost it),
    whatever the share of lost runs; the penalty is bounded by what was observed (one lost run
    cannot make an interval infinite), and with no lost run the estimators are ``a`` and ``b``.
    """
    la, lb = np.asarray(lost_a, dtype=bool), np.asarray(lost_b, dtype=bool)
    if not (la.any() or lb.any()):
        return a, b
    if type(a) is not type(b):
        raise TypeError("a paired comparison needs estimators of the same statistic")
    if isinstance(a, Ratio):
        with np.errstate(divide="ignore", invalid="ignore"):
            ra, rb = a.num / a.den, b.num / b.den
        vals = np.concatenate([ra[~la & (a.den > 0)], rb[~lb & (b.den > 0)]])
        vals = vals[np.isfinite(vals)]
        if not vals.size:
            return a, b
        key = sign * (a.scale if a.scale else 1.0)
        worst = float(vals.max() if key > 0 else vals.min())
        den = np.maximum(a.den, b.den)  # a lost run's counts: the pair's fuller one

        def fill(e: Ratio, lost: Array) -> Ratio:
            num, d = e.num.copy(), e.den.copy()
            d[lost] = den[lost]
            num[lost] = worst * d[lost]
            return Ratio(num, d, sqrt=e.sqrt, scale=e.scale)

        return fill(a, la), fill(b, lb)
    if isinstance(a, MeanSqrtRatio):  # the maximum too: per epoch, the pair's worst error
        fa = np.asarray(a.num, dtype=float)
        fb = np.asarray(b.num, dtype=float)
        da = np.ones_like(fa) if a.den is None else a.den
        db = np.ones_like(fb) if b.den is None else b.den
        with np.errstate(divide="ignore", invalid="ignore"):
            ra = np.where(~la[:, None] & (da > 0), fa / np.where(da > 0, da, 1.0), np.nan)
            rb = np.where(~lb[:, None] & (db > 0), fb / np.where(db > 0, db, 1.0), np.nan)
        both = np.concatenate([ra, rb])
        both = np.where(np.isfinite(both), both, np.nan)
        worst = _worst(both, sign)

        def fill_k(e: MeanSqrtRatio, f: Array, lost: Array) -> MeanSqrtRatio:
            f = f.copy()
            if e.den is None:
                f[lost] = worst
                return type(e)(f, scale=e.scale)
            d = e.den.copy()
            d[lost] = 1.0
            f[lost] = worst
            return type(e)(f, d, scale=e.scale)

        return fill_k(a, fa, la), fill_k(b, fb, lb)
    if isinstance(a, Quantile):
        va, vb = a.values.copy(), b.values.copy()
        both = np.concatenate([np.where(la[:, None], np.nan, va), np.where(lb[:, None], np.nan, vb)])
        worst = _worst(both, sign)
        va[la], vb[lb] = worst, worst
        return Quantile(va, a.q), Quantile(vb, b.q)
    raise TypeError(f"no loss rule for {type(a).__name__}")


@functools.lru_cache(maxsize=256)
def expanded_tail(n: int, level: float = LEVEL) -> float:
    """Tail probability α′/2 of the expanded percentile interval for ``n`` runs (module note)."""
    if n < 2:
        return (1.0 - level) / 2.0
    z = np.sqrt(n / (n - 1.0)) * stdtrit(n - 1, 0.5 + level / 2.0)
    return float(ndtr(-z))


def expanded_p(p: float, n: int) -> float:
    """The percentile p-value mapped through the expansion (p < 1 − level ⇔ 0 outside the CI)."""
    if n < 2 or p >= 1.0:
        return min(1.0, p)
    return _alpha(ndtri(1.0 - p / 2.0), n)


def resample_counts(n: int, size: int, rng: np.random.Generator) -> Array:
    """``size`` multinomial resamples of ``n`` runs: counts (size, n), each row sums to n."""
    idx = rng.integers(0, n, size=(size, n))
    flat = (idx + (np.arange(size) * n)[:, None]).ravel()
    return np.bincount(flat, minlength=size * n).reshape(size, n).astype(float)


class Resampler:
    """Resample weights shared by every estimator over one set of ``n`` runs.

    The weights are drawn in blocks of :data:`BLOCK` resamples, each block from its own stream
    ``SeedSequence([seed, n, block])``, so they are the same whatever is asked first, and the
    memory stays bounded (B × N floats never exist at once). Estimates from one resampler are
    therefore paired: Δ*_b = A*_b − B*_b uses the same resample b for both.
    """

    def __init__(self, n: int, seed: int = 0, n_boot: int = N_BOOT) -> None:
        self.n, self.seed, self.n_boot = int(n), int(seed), int(n_boot)
        self._cache: list[Array] | None = None
        # the weights of a small experiment are kept (every estimator of every filter reuses them)
        self._keep = self.n * self.n_boot <= 4_000_000

    def blocks(self) -> Iterator[Array]:
        """The resample counts, block by block (b, n)."""
        if self._cache is not None:
            yield from self._cache
            return
        out = []
        for j, start in enumerate(range(0, self.n_boot, BLOCK)):
            size = min(BLOCK, self.n_boot - start)
            rng = np.random.default_rng(np.random.SeedSequence([self.seed, self.n, j]))
            W = resample_counts(self.n, size, rng)
            if self._keep:
                out.append(W)
            yield W
        if self._keep:
            self._cache = out

    def _cached(self, est: Estimator, what: str, make) -> Array:
        cache = est.__dict__.setdefault("_resampled", {})
        key = (what, self.seed, self.n, self.n_boot)
        if key not in cache:
            cache[key] = make()
        return cache[key]

    def replicates(self, est: Estimator) -> Array:
        """The estimator's value on every resample (n_boot,), computed once per estimator."""
        if isinstance(est, _Combined):
            return self._cached(est, "boot", lambda: est._op(self.replicates(est.a), self.replicates(est.b)))
        return self._cached(est, "boot", lambda: np.concatenate([est.boot(W) for W in self.blocks()]))

    def jackknife(self, est: Estimator) -> Array:
        """Leave-one-run-out values (n,), for the BCa acceleration."""
        if isinstance(est, _Combined):
            return self._cached(est, "jack", lambda: est._op(self.jackknife(est.a), self.jackknife(est.b)))
        return self._cached(est, "jack", lambda: est.boot(1.0 - np.eye(self.n)))

    def method(self, est: Estimator) -> str:
        if self.n < MIN_RUNS:
            return ""
        if self.n >= DELTA_FROM and est.psi() is not None:
            return "delta"
        return "bootstrap"

    def _bca(self, est: Estimator, v: float) -> tuple[Array, float, float] | None:
        """(finite replicates, bias correction z0, acceleration a), or None if undefined."""
        t = self.replicates(est)
        t = t[np.isfinite(t)]
        if t.size < 0.9 * self.n_boot:
            return None
        tiny = 1e-9 * max(1.0, abs(v))  # round-off: a statistic that does not vary at all
        if np.ptp(t) <= tiny:
            return t, 0.0, 0.0
        below = float(np.mean(t < v) + 0.5 * np.mean(t == v))
        z0 = float(ndtri(np.clip(below, 0.5 / self.n_boot, 1.0 - 0.5 / self.n_boot)))
        if not est.smooth:  # a maximum or a quantile: bias-corrected percentile, no acceleration
            return t, z0, 0.0
        j = self.jackknife(est)
        j = j[np.isfinite(j)]
        d = j.mean() - j if j.size else np.zeros(1)
        ss = float((d**2).sum())
        acc = float((d**3).sum() / (6.0 * ss**1.5)) if np.sqrt(ss) > tiny else 0.0
        return t, z0, acc

    def estimate(self, est: Estimator) -> Estimate:
        """The value with its 95 % interval (see the module note for the method)."""
        if est.n != self.n:
            raise ValueError(f"estimator over {est.n} runs, resampler over {self.n}")
        v = est.point()
        how = self.method(est)
        if not how:
            return Estimate(v, note=TOO_FEW)
        if not np.isfinite(v):
            return Estimate(v, note="no value")
        if how == "delta":
            psi = est.psi()
            se = float(np.sqrt(np.sum(psi**2)) / self.n)
            return Estimate(v, v - Z * se, v + Z * se, "delta")
        got = self._bca(est, v)
        if got is None:
            return Estimate(v, note="the metric is undefined on too many resamples")
        t, z0, acc = got
        zc = -float(ndtri(expanded_tail(self.n)))
        qs = [_bca_level(z0, acc, -zc), _bca_level(z0, acc, zc)]
        lo, hi = np.quantile(t, qs)
        return Estimate(v, float(lo), float(hi), "bootstrap")

    def compare(self, a: Estimator, b: Estimator, relative: bool = False) -> Comparison:
        """Paired Δ = a − b (``relative``: (a − b)/b) over this resampler's runs."""
        d = _Combined(a, b, relative)
        e = self.estimate(d)
        if not e.method:
            return Comparison(e.value, e.lo, e.hi, float("nan"), "", self.n, e.note)
        if e.method == "delta":
            psi = d.psi()
            se = float(np.sqrt(np.sum(psi**2)) / self.n)
            return Comparison(e.value, e.lo, e.hi, _normal_p(e.value, se), "delta", self.n)
        t, z0, acc = self._bca(d, e.value)
        if np.ptp(t) <= 1e-9 * max(1.0, abs(e.value)) and abs(e.value) <= 1e-9:
            return Comparison(e.value, e.lo, e.hi, 1.0, "bootstrap", self.n)  # the same twice
        p, floor = _inverted_p(np.sort(t), z0, acc, self.n)
        return Comparison(e.value, e.lo, e.hi, p, "bootstrap", self.n, at_floor=floor)


def _zero_positions(t: Array) -> tuple[float, float]:
    """Where 0 sits in the sorted replicates ``t`` as a position of ``np.quantile``'s linear
    interpolation (position = level · (B − 1)): (the last position whose quantile is ≤ 0, the
    first whose quantile is ≥ 0); ±inf where the quantile never gets there.
    """
    B = t.size
    j = int(np.searchsorted(t, 0.0, side="right")) - 1  # last t ≤ 0
    if j < 0:
        hi = -np.inf
    elif j == B - 1:
        hi = np.inf
    else:
        hi = j + (0.0 - t[j]) / (t[j + 1] - t[j])
    i = int(np.searchsorted(t, 0.0, side="left"))  # first t ≥ 0
    if i == B:
        lo = np.inf
    elif i == 0:
        lo = -np.inf
    else:
        lo = (i - 1) + (0.0 - t[i - 1]) / (t[i] - t[i - 1])
    return hi, lo


def _alpha(z: float, n: int) -> float:
    """The two-sided level 1 − coverage of the expanded interval with nominal quantile ``z``
    (the inverse of ``−ndtri(expanded_tail(n, 1 − α))``).
    """
    if n < 2:
        return float(2.0 * ndtr(-z))
    return float(2.0 * stdtr(n - 1, -(z * np.sqrt((n - 1.0) / n))))


def floor_p(n: int, n_boot: int = N_BOOT) -> float:
    """The smallest p a bootstrap of ``n_boot`` resamples resolves: one resample in ``n_boot``
    on the other side of 0 in a percentile interval (2/B two-sided), expanded for ``n`` runs.
    A p at this floor is a bound ("p < …").
    """
    return _alpha(float(ndtri(1.0 - 1.0 / n_boot)), n)


Z_MAX = 40.0  # nominal quantiles beyond this: every interval level the bootstrap can express


def _inverted_p(t: Array, z0: float, acc: float, n: int) -> tuple[float, bool]:
    """The paired p-value as the inversion of the very interval :meth:`Resampler.estimate`
    reports: p = the largest α whose (1 − α) interval still holds 0, so p < 0.05 exactly when the
    95 % interval excludes 0 (a bias-corrected maximum too). Where no interval level holds 0 (no
    resample on the other side, or a bias correction that pushes every level past it) the p is
    below the bootstrap's resolution: :func:`floor_p`, flagged as a bound.
    """
    B = t.size
    hi0, lo0 = _zero_positions(t)

    def holds(z: float) -> bool:  # 0 inside the interval of nominal quantile z
        lo = _bca_level(z0, acc, -z) * (B - 1)
        hi = _bca_level(z0, acc, z) * (B - 1)
        return lo <= hi0 and hi >= lo0

    if holds(0.0):
        return 1.0, False
    if not holds(Z_MAX):
        return min(floor_p(n, B), ALPHA / 2), True
    a, b = 0.0, Z_MAX  # holds(a) False, holds(b) True: bisect to the boundary
    for _ in range(80):
        m = 0.5 * (a + b)
        if holds(m):
            b = m
        else:
            a = m
    if holds(-float(ndtri(expanded_tail(n)))):  # the 95 % interval holds 0: p ≥ its α
        return max(_alpha(a, n), ALPHA), False
    return min(_alpha(b, n), np.nextafter(ALPHA, 0.0)), False


def _bca_level(z0: float, acc: float, z: float) -> float:
    """BCa quantile level for a nominal normal quantile z (Efron & Tibshirani 1993, §14.3)."""
    u = z0 + z
    den = 1.0 - acc * u
    if den <= 0.0:  # past the pole of the acceleration: the level saturates (monotone in z)
        return 1.0 if u > 0 else 0.0
    return float(ndtr(z0 + u / den))


def _normal_p(value: float, se: float) -> float:
    """Two-sided normal p-value of ``value`` with standard error ``se``."""
    if se > 0:
        return float(2.0 * ndtr(-abs(value) / se))
    return 1.0 if value == 0 else 0.0  # no run-to-run variation of the difference at all


def holm(p_values: dict[str, float]) -> dict[str, float]:
    """Holm's step-down adjusted p-values (family-wise error control), NaN entries kept NaN."""
    items = sorted(((p, k) for k, p in p_values.items() if np.isfinite(p)))
    m = len(items)
    out = {k: float("nan") for k in p_values}
    running = 0.0
    for i, (p, k) in enumerate(items):
        running = max(running, min(1.0, (m - i) * p))
        out[k] = running
    return out


def holm_bounds(
    p_values: dict[str, float], bounds: dict[str, bool]
) -> tuple[dict[str, float], dict[str, bool]]:
    """:func:`holm` of p-values some of which are bounds (a p at the bootstrap's floor): the
    adjusted values, and which of them are bounds — those whose step-down maximum is a bound's
    multiple (Holm's adjusted p grows with every raw p, so a bound in gives a bound out).
    """
    items = sorted(((p, k) for k, p in p_values.items() if np.isfinite(p)))
    m = len(items)
    out = {k: float("nan") for k in p_values}
    bound = {k: False for k in p_values}
    running, running_bound = 0.0, False
    for i, (p, k) in enumerate(items):
        term = min(1.0, (m - i) * p)
        if term > running or (term == running and not bounds.get(k, False)):
            running, running_bound = term, bool(bounds.get(k, False)) and term < 1.0
        out[k], bound[k] = running, running_bound
    return out, bound


def format_p(p: float, at_floor: bool = False) -> str:
    """'p = 0.012'; 'p < …' at the bootstrap's resolution floor (never 'p = 0')."""
    if not np.isfinite(p):
        return ""
    if at_floor:  # a bound: rounded up, so the printed bound still holds
        mag = 10.0 ** (np.floor(np.log10(p)) - 1) if p > 0 else 1.0
        return f"p < {np.ceil(p / mag - 1e-9) * mag:.2g}"
    if p < 1e-4:
        return "p < 0.0001"
    text = f"{p:.2g}" if p < 0.01 else f"{p:.2f}"
    for digits in (3, 4, 5):  # never a rounding onto the verdicts' α: 0.0496 is not "p = 0.05"
        if not math.isclose(float(text), ALPHA) or math.isclose(p, ALPHA):
            break
        text = f"{p:.{digits}g}"
    return f"p = {text}"


def sig3(x: float) -> str:
    """Three significant figures for display ('' for NaN)."""
    if x is None or not np.isfinite(x):
        return ""
    if x == 0:
        return "0"
    mag = int(np.floor(np.log10(abs(x))))
    if -3 <= mag < 5:
        return f"{x:.{max(0, 2 - mag)}f}"
    return f"{x:.3g}"


def mean_ci(values: Array) -> Estimate:
    """Mean of independent values (e.g. one statistic per seed set) with a t interval."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return Estimate(float("nan"), note="no value")
    m = float(v.mean())
    if v.size < 2:
        return Estimate(m, note="one value: no interval")
    se = float(v.std(ddof=1) / np.sqrt(v.size))
    h = float(stdtrit(v.size - 1, 0.5 + LEVEL / 2)) * se
    return Estimate(m, m - h, m + h, "t")

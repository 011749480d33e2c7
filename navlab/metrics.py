"""Metrics of ALGORITHMS.md §9 with their uncertainty: RMSE (per epoch, pooled, mean of per-epoch),
ANEES/ANIS with χ² bands, R̂ error, outlier detection rates, numerical fixes, divergence.

How a number is made (the statistics spec, docs/STATISTICS.md):

* Every metric is a function of per-run statistics (:class:`RunStats`: the run's sum of squared
  errors over the analysis window, its NEES/NIS sums and counts, its flag counts, …), so its 95 %
  interval resamples runs (:mod:`navlab.stats`) and a difference between two filters is paired.
* **Divergence** (the rule is stated in every table's footnote, :data:`DIVERGENCE_RULE`): a run
  is diverged for a filter when its state or covariance becomes non-finite, or when inside the
  analysis window its position error exceeds the scenario's bound (default 100 × the largest
  nominal measurement σ) or its NEES exceeds 10⁶. The experiment recorder marks it
  (:attr:`navlab.experiment.FilterRun.diverged_at`).
* **Every filter is judged on the same runs.** A filter that diverges in at most 5 % of the runs
  is *reliable*; the *common runs* are those where every reliable filter is valid, and every
  reliable filter's table values are computed over them (counted). A paired comparison does not
  leave a lost run out: it is a loss for the filter that lost it (:data:`LOSS_RULE`), the Δ over
  the runs both kept shown beside. A filter that diverges in more than 5 % is reported as "diverges in k of N
  runs", ranks below every reliable filter whatever its numbers, and its metrics are computed over
  the common runs it survived, labelled so.
* Skipped non-finite entries (NEES, NIS, R̂ ratios) are counted and reported beside the metric.
* The per-run statistics are computed on epoch-major arrays (:func:`epoch_major`, the layout the
  experiment records in): each run's sums add its epochs in epoch order, the same bits whatever
  the layout or chunking the arrays came in (tests/unit/test_metrics.py). The one speed trick
  of this module, kept because it pays: mixing layouts made every elementwise step a transposing
  pass (benchmarks/throughput.py prints the metrics' share of the whole pipeline; the one-pass
  influence values of :class:`navlab.stats.MeanSqrtRatio` serve the same end).
* The R̂ error compares R̂ with the variance the noise was actually drawn from: on clean epochs
  (the headline ``rhat_err_pct``; the oracle reads 0) and, separately, on contaminated ones.
  Detection and false-alarm rates count outlier decisions only (flag codes 1–5); an R̂ held at its
  band (code 6, filters that estimate R) and numerical fixes (code 9) are rates of their own,
  ``band_pct`` and ``numfix_pct``.

:func:`summarize` turns :class:`navlab.experiment.Results` into the tidy table every output uses
(CLI ``--format json|csv``, the app's downloads, sweeps); :func:`compare` adds the paired
differences against a reference filter.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from navlab import stats as S
from navlab.errors import NavlabError
from navlab.linalg import Array, chi2_ppf

if TYPE_CHECKING:
    from navlab.experiment import FilterRun, Results
    from navlab.scenarios.base import MetricGroup

RELIABLE_SHARE = 0.05  # a filter diverging in more runs than this share is "unreliable"
NEES_BOUND = 1e6  # NEES above this at any window epoch: diverged
BOUND_SIGMAS = 100.0  # default position-error bound: this many nominal measurement σ
OUTLIER_CODES = (1, 2, 3, 4, 5)  # flag codes that are outlier decisions (ALGORITHMS.md §0.3)
NUMFIX_CODE = 9
BAND_CODE = 6  # R̂ held at a bound of its band [r_min, r_max] × R0 (not an outlier decision)
FLAG_SHOW_PCT = 1.0  # R̂ at its band, numerical fixes: pointed out above this share of entries (%)
DIVERGENCE_RULE = (
    "a run is diverged for a filter when its state becomes non-finite, or inside the analysis "
    "window its position error exceeds {bound} or its NEES exceeds 1e6; every filter diverging in "
    "at most 5 % of the runs is judged on the runs where all of them are valid (the common runs), "
    "a filter diverging more often ranks below them and is judged on the common runs it survived"
)
COLUMNS = [
    "filter",
    "label",
    "metric",
    "value",
    "unit",
    "ci_lo",
    "ci_hi",
    "ci_method",
    "runs_used",
    "note",
]
LOSS_RULE = (
    "in a paired comparison a run lost (diverged) by one filter counts as a loss for it: its value "
    "there is the worst any run of either filter reached (per epoch for per-epoch metrics), so "
    "diverging can never help; Δ, its interval and the test are over every run, the Δ over the "
    "runs both kept is shown beside"
)
DIFF_COLUMNS = [
    "vs",
    "p_value",
    "p_bound",  # "<": the p is at the bootstrap's floor, a bound (no resample beyond 0)
    "p_holm",
    "p_holm_bound",
    "verdict",
    "common_value",  # Δ over the runs both filters kept (no loss scored), with its interval
    "common_ci_lo",
    "common_ci_hi",
    "common_runs",
]


# --------------------------------------------------------------------------- array helpers


def timed_from(K: int) -> int:
    """The first epoch a filter's clock counts (:attr:`FilterRun.runtime_s`): epoch 1 carries
    one-off start-up (a compiled kernel loaded or compiled, lazy imports, first-touch memory),
    which would be charged to the first filter of a run alone, so epochs 2 … K are timed (all of a
    one-epoch run).
    """
    return 2 if K >= 2 else 1


def timed_steps(B: int, K: int) -> int:
    """How many run·steps a batch of B runs of K epochs times (:func:`timed_from`)."""
    return max(B * (K - timed_from(K) + 1), 1)


@functools.lru_cache(maxsize=1024)
def chi2_band(dof: int, runs: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided band of an average over ``runs`` of χ²(dof) variables: χ²(N·dof)/N quantiles.

    Bar-Shalom, Li & Kirubarajan 2001, ch. 5 (e.g. dof 4, N 100 → [3.46, 4.57]).
    """
    a = (1.0 - level) / 2.0
    N = max(int(runs), 1)
    return float(chi2_ppf(a, N * dof) / N), float(chi2_ppf(1 - a, N * dof) / N)


def sq_error(x_hat: Array, x_true: Array, group: MetricGroup) -> Array:
    """Squared error norm over the group's components, in display units: (B, K+1)."""
    i = list(group.idx)
    if i == list(range(i[0], i[-1] + 1)):  # consecutive components: a view, not a gathered copy
        i = slice(i[0], i[-1] + 1)
    with np.errstate(over="ignore", invalid="ignore"):  # a diverged run's inf stays inf
        e = (x_hat[..., i] - x_true[..., i]) * group.scale
        return np.sum(e**2, axis=-1)


def rmse_per_epoch(sq: Array, ok_runs: Array | None = None) -> Array:
    """RMSE_k = sqrt(mean over runs of the squared error) (K+1,) — the curve the papers plot."""
    if ok_runs is not None:
        sq = sq[ok_runs]
    if sq.shape[0] == 0:
        return np.full(sq.shape[1], np.nan)
    return np.sqrt(np.mean(sq, axis=0))


def pooled_rmse(sq: Array, window: Array, ok_runs: Array | None = None) -> float:
    """sqrt(mean over epochs in ``window`` and runs of the squared error)."""
    if ok_runs is not None:
        sq = sq[ok_runs]
    sel = sq[:, window]
    return float(np.sqrt(np.mean(sel))) if sel.size else float("nan")


def mean_of_rmse(sq: Array, window: Array, ok_runs: Array | None = None) -> float:
    """Mean over epochs in ``window`` of the per-epoch RMSE (some papers report this)."""
    r = rmse_per_epoch(sq, ok_runs)[window]
    return float(np.mean(r)) if r.size else float("nan")


def error_quantiles(sq: Array, q: tuple[float, ...] = (0.1, 0.9), ok_runs: Array | None = None):
    """Per-epoch quantiles over runs of the error norm (spread band for plots): (len(q), K+1)."""
    if ok_runs is not None:
        sq = sq[ok_runs]
    return np.quantile(np.sqrt(sq), q, axis=0)


def _pick(a: Array, runs: Array | None) -> Array:
    """``a[runs]`` for a bool mask of runs; ``a`` itself (no copy) when it keeps every run."""
    return a if runs is None or runs.all() else a[runs]


def average_over_runs(v: Array, ok_runs: Array | None = None) -> Array:
    """Per-epoch mean over runs of the finite entries (ANEES ε̄_k or ANIS), (K+1,)."""
    v = _pick(v, ok_runs)
    finite = np.isfinite(v)
    n = finite.sum(axis=0)
    total = np.where(finite, v, 0.0).sum(axis=0)
    return np.divide(total, n, out=np.full(v.shape[1:], np.nan), where=n > 0)


# --------------------------------------------------------------------------- scenario metrics


@dataclass(frozen=True)
class QuantileMetric:
    """A scenario-specific metric: the ``q``-quantile, pooled over window epochs and runs, of a
    per-run per-epoch error ``sample(x_hat (B, K+1, n), data) -> (B, K+1)`` (e.g. the median
    horizontal error of the real recordings). Its interval resamples runs.
    """

    sample: Callable[[Array, Any], Array]
    q: float
    unit: str = "m"
    help: str = ""


# --------------------------------------------------------------------------- divergence


def divergence_bound(data: Any) -> tuple[str, float] | None:
    """(group, bound in its display unit) of the error-bound divergence rule, or None.

    The scenario's own bound (``ScenarioData.divergence_bound``, metres of the ``pos`` group) if
    it states one, else 100 × the largest nominal measurement σ on the ``pos`` group.
    """
    if not getattr(data, "has_truth", False) or "pos" not in data.groups:
        return None
    bound = getattr(data, "divergence_bound", None)
    if bound is None:
        R0 = np.asarray(data.model.R0, dtype=float)
        sig = float(np.sqrt(np.max(np.diag(R0)))) if R0.size else 0.0
        if not sig > 0:
            return None
        bound = BOUND_SIGMAS * sig
    return "pos", float(bound)


def rule_text(data: Any) -> str:
    """The divergence rule with this experiment's bound, for footnotes."""
    b = divergence_bound(data)
    what = f"{b[1]:.4g} {data.groups[b[0]].unit}" if b else "(no truth: no error bound)"
    return DIVERGENCE_RULE.format(bound=what)


# --------------------------------------------------------------------------- per-run statistics


@dataclass(eq=False)
class RunStats:
    """Per-run statistics of one filter over the analysis window; every array has a row per run.

    ``sq`` (per-epoch squared errors, for the mean of the per-epoch RMSE) and ``samples`` (for
    quantile metrics) are per run and epoch; everything else is one number per run.
    """

    key: str
    label: str
    diverged: Array  # (B,) bool
    runtime_s: float
    epochs: int  # window epochs
    sse: dict[str, Array] = field(default_factory=dict)  # group -> (B,)
    sq: dict[str, Array] = field(default_factory=dict)  # group -> (B, Kw)
    sums: dict[str, Array] = field(default_factory=dict)  # name -> (B,): see run_stats
    samples: dict[str, Array] = field(default_factory=dict)  # quantile metric -> (B, Kw)
    estimates_R: bool = False

    @staticmethod
    def concat(parts: list[RunStats]) -> RunStats:
        """The statistics of consecutive chunks of runs as one (a summary run)."""
        out = RunStats.allocate(parts[0], sum(p.diverged.shape[0] for p in parts))
        at = 0
        for p in parts:
            out.put(at, p)
            at += p.diverged.shape[0]
        return out

    @staticmethod
    def allocate(like: RunStats, runs: int) -> RunStats:
        """Room for ``runs`` runs of statistics shaped like ``like`` (a chunk's), filled by
        :meth:`put`: a summary run's chunks are written in place, never concatenated (which
        would hold every chunk twice: 146 MB more at a million runs of two filters).
        """
        room = lambda d: {k: np.empty((runs, *v.shape[1:]), v.dtype) for k, v in getattr(like, d).items()}  # noqa: E731
        return dataclasses.replace(
            like,
            diverged=np.zeros(runs, dtype=bool),
            runtime_s=0.0,
            sse=room("sse"),
            sq=room("sq"),
            sums=room("sums"),
            samples=room("samples"),
        )

    def put(self, at: int, part: RunStats) -> None:
        """Write the statistics of the chunk ``part`` at runs ``at …`` (see :meth:`allocate`)."""
        end = at + part.diverged.shape[0]
        self.diverged[at:end] = part.diverged
        self.runtime_s += part.runtime_s
        for d in ("sse", "sq", "sums", "samples"):
            for k, v in getattr(part, d).items():
                getattr(self, d)[k][at:end] = v

    def compact(self, keep_epochs: bool) -> RunStats:
        """For a summary run: float32 per-run numbers, and the per-epoch arrays only if kept."""
        f32 = lambda d: {k: v.astype(np.float32) for k, v in d.items()}  # noqa: E731
        return dataclasses.replace(
            self,
            sse=f32(self.sse),
            sums=f32(self.sums),
            sq=f32(self.sq) if keep_epochs else {},
            samples=f32(self.samples) if keep_epochs else {},
        )


def epoch_major(a: Array) -> Array:
    """``a`` (B, K, …) as a view of an epoch-major (K, B, …) array — the layout the experiment
    records the filters' outputs in (navlab.experiment._Recorder) — copied only if it is not one.

    The per-run statistics are computed on this one layout: elementwise arithmetic between two
    arrays of different layouts is a strided, transposing pass (benchmarks/throughput.py times the
    metrics), and a sum over the
    epochs then adds them in epoch order whatever the layout the arrays came in.
    """
    return np.ascontiguousarray(a.swapaxes(0, 1)).swapaxes(0, 1)


def per_run(a: Array, where: Array | None = None) -> Array:
    """Σ over the epochs, then the channels, of each run: (B, Kw[, m]) → (B,) floats; with
    ``where``, of the entries where it is True only (the sum of ``np.where(where, a, 0)``, the
    same bits, without that temporary array).

    Two single-axis sums: on an epoch-major boolean array one sum over both axes is a slow strided
    pass.
    """
    s = a.sum(axis=1) if where is None else np.add.reduce(a, axis=1, where=where)
    return (s.sum(axis=1) if s.ndim > 1 else s).astype(float)


def _window_masks(data: Any) -> dict[str, Any]:
    """What every filter's statistics share (made once per data object, epoch-major): the
    window's truth, its measurement masks and their per-run counts.
    """
    cache = data.__dict__.get("_window_masks")
    if cache is None:
        W = np.asarray(data.window, dtype=bool)
        idx = np.flatnonzero(W)
        if idx.size and idx[-1] - idx[0] + 1 == idx.size:  # contiguous: a slice (views, no copies)
            W = slice(int(idx[0]), int(idx[-1]) + 1)
        present = epoch_major(np.isfinite(data.z[:, W]))  # (B, Kw, m): a measurement exists
        mask = epoch_major(np.asarray(data.outlier_mask[:, W], dtype=bool)) & present
        clean = present & ~mask

        def count(a: Array) -> Array:  # per run; shared by every filter's RunStats: read-only
            c = per_run(a)
            c.flags.writeable = False
            return c

        cache = {
            "W": W,
            "present": present,
            "measured": present.any(axis=2),  # (B, Kw)
            "mask": mask,
            "clean": clean,
            "x_true": epoch_major(data.x_true[:, W]) if data.has_truth else None,
            "counts": {"contaminated": count(mask), "clean": count(clean), "entries": count(present)},
        }
        data.__dict__["_window_masks"] = cache
    return cache


def run_stats(data: Any, fr: FilterRun) -> RunStats:
    """The per-run statistics of filter run ``fr`` on ``data`` (window ``data.window``)."""
    dm = _window_masks(data)
    W, present, mask, clean = dm["W"], dm["present"], dm["mask"], dm["clean"]
    B = data.B
    st = RunStats(
        key=fr.key,
        label=fr.label,
        diverged=np.asarray(fr.diverged, dtype=bool),
        runtime_s=float(fr.runtime_s),
        epochs=int(present.shape[1]),
        estimates_R=fr.R_hat is not None,
    )
    s = st.sums
    with np.errstate(over="ignore", invalid="ignore"):  # diverged runs hold inf/NaN: excluded later
        if data.has_truth:
            e2 = epoch_major(fr.x[:, W]) - dm["x_true"]  # (B, Kw, n): every component once
            e2 *= e2
            for g, group in data.groups.items():
                i0, *rest = group.idx
                sq = e2[..., i0] + e2[..., rest[0]] if rest else e2[..., i0].copy(order="K")  # epoch-major
                for i in rest[1:]:
                    sq += e2[..., i]
                if group.scale != 1.0:
                    sq *= group.scale**2
                st.sq[g] = sq
                st.sse[g] = sq.sum(axis=1)
        for name, v, where in (("nees", fr.nees, None), ("nis", fr.nis, dm["measured"])):
            if name == "nees" and not data.has_truth:
                continue
            v = epoch_major(v[:, W])
            fin = np.isfinite(v)
            s[f"{name}_sum"] = per_run(v, where=fin)
            s[f"{name}_cnt"] = per_run(fin)
            s[f"{name}_skip"] = per_run(~fin if where is None else where & ~fin)
        if "logpdf" in fr.stats:  # the filter's own predictive log density of each measurement
            lp = epoch_major(fr.stats["logpdf"][:, W])
            fin = np.isfinite(lp) & present
            s["lpd_sum"] = per_run(lp, where=fin)
            s["lpd_cnt"] = per_run(fin)
        if fr.R_hat is not None:
            if "R_true" not in dm:
                dm["R_true"] = epoch_major(data.R_true[:, W])
            err = np.abs(np.sqrt(epoch_major(fr.R_hat[:, W]) / dm["R_true"]) - 1.0)
            fin = np.isfinite(err)
            for part, sel in (("clean", clean), ("cont", mask)):
                s[f"rhat_{part}_sum"] = per_run(err, where=sel & fin)
                s[f"rhat_{part}_cnt"] = per_run(sel & fin)
            s["rhat_skip"] = per_run(present & ~fin)
        flags = epoch_major(fr.flags[:, W])
        decided = (flags >= OUTLIER_CODES[0]) & (flags <= OUTLIER_CODES[-1])  # codes 1–5
        s["detected"] = per_run(decided & mask)
        s["false_alarm"] = per_run(decided & clean)
        s["numfix"] = per_run((flags == NUMFIX_CODE) & present)
        if fr.R_hat is not None:  # a filter that estimates R (those with a band flag code 6)
            s["band"] = per_run((flags == BAND_CODE) & present)
        s.update(dm["counts"])
        for name, m in data.extras.get("metrics", {}).items():
            if isinstance(m, QuantileMetric):
                st.samples[name] = np.asarray(m.sample(fr.x, data), dtype=float)[:, W]
    assert all(v.shape[0] == B for v in s.values())
    return st


# --------------------------------------------------------------------------- judged runs


@dataclass(frozen=True)
class Paired:
    """A paired comparison under the loss rule (``c``), the same over the runs both filters kept
    (``common``), the unit and a note on the lost runs.
    """

    c: S.Comparison
    common: S.Comparison
    unit: str
    note: str = ""


@dataclass(frozen=True)
class Judgement:
    """Which runs each filter is judged on (module note): valid, reliable, common, judged."""

    n_runs: int
    valid: dict[str, Array]  # key -> (B,) bool: the filter did not diverge
    reliable: dict[str, bool]
    common: Array  # (B,) bool: valid for every reliable filter
    judged: dict[str, Array]  # key -> (B,) bool

    def lost(self, key: str) -> int:
        return int((~self.valid[key]).sum())


def judge(diverged: dict[str, Array]) -> Judgement:
    """The judged runs of every filter from its per-run divergence flags."""
    keys = list(diverged)
    B = int(next(iter(diverged.values())).shape[0]) if keys else 0
    valid = {k: ~np.asarray(diverged[k], dtype=bool) for k in keys}
    reliable = {k: int((~valid[k]).sum()) <= RELIABLE_SHARE * B for k in keys}
    common = np.ones(B, dtype=bool)
    for k in keys:
        if reliable[k]:
            common &= valid[k]
    judged = {k: common if reliable[k] else common & valid[k] for k in keys}
    return Judgement(B, valid, reliable, common, judged)


# --------------------------------------------------------------------------- estimators


def estimators(st: RunStats, data: Any, runs: Array) -> dict[str, tuple[S.Estimator, str]]:
    """The headline metrics of one filter as estimators over the runs ``runs`` (bool mask).

    Returns {metric: (estimator, unit)} for every metric that applies to this filter and data.
    """
    out: dict[str, tuple[S.Estimator, str]] = {}
    s = {k: _pick(v, runs) for k, v in st.sums.items()}
    n_ep = np.full(int(runs.sum()), float(st.epochs))
    for g, group in data.groups.items() if data.has_truth else ():
        out[f"rmse_{g}"] = (S.Ratio(_pick(st.sse[g], runs), n_ep, sqrt=True), group.unit)
        if g in st.sq:  # per-epoch errors (not kept by a large summary run)
            out[f"mean_rmse_{g}"] = (S.MeanSqrtRatio(_pick(st.sq[g], runs)), group.unit)
    for name, extra in data.extras.get("metrics", {}).items():
        if isinstance(extra, QuantileMetric) and name in st.samples:
            out[name] = (S.Quantile(_pick(st.samples[name], runs), extra.q), extra.unit)
    if "nees_sum" in s:
        out["anees"] = (S.Ratio(s["nees_sum"], s["nees_cnt"]), "")
    out["anis"] = (S.Ratio(s["nis_sum"], s["nis_cnt"]), "")
    if "lpd_sum" in s:
        out["nlpd"] = (S.Ratio(s["lpd_sum"], s["lpd_cnt"], scale=-1.0), "nats")
    if st.estimates_R:
        out["rhat_err_pct"] = (S.Ratio(s["rhat_clean_sum"], s["rhat_clean_cnt"], scale=100.0), "%")
        if s["rhat_cont_cnt"].sum() > 0:
            out["rhat_err_contaminated_pct"] = (
                S.Ratio(s["rhat_cont_sum"], s["rhat_cont_cnt"], scale=100.0),
                "%",
            )
    if any_outliers(data):
        out["detected_pct"] = (S.Ratio(s["detected"], s["contaminated"], scale=100.0), "%")
        out["false_alarm_pct"] = (S.Ratio(s["false_alarm"], s["clean"], scale=100.0), "%")
    out["numfix_pct"] = (S.Ratio(s["numfix"], s["entries"], scale=100.0), "%")
    if "band" in s:
        out["band_pct"] = (S.Ratio(s["band"], s["entries"], scale=100.0), "%")
    return out


def any_outliers(data: Any) -> bool:
    """Whether any measurement of the experiment is contaminated."""
    known = getattr(data, "any_outliers", None)
    return bool(data.outlier_mask.any()) if known is None else bool(known)


# the metrics after the errors in every table: consistency, the truth-free score, R̂, flags
QUALITY_METRICS = (
    "anees",
    "anis",
    "nlpd",
    "rhat_err_pct",
    "detected_pct",
    "false_alarm_pct",
    "band_pct",
    "numfix_pct",
)


def direction(metric: str) -> int:
    """+1 where lower is better, −1 where higher is better, 0 where neither (consistency)."""
    if metric.startswith(("rmse_", "mean_rmse_", "rhat_err", "h_err", "false_alarm", "numfix", "nlpd")):
        return 1
    if metric.startswith("detected"):
        return -1
    return 0


# --------------------------------------------------------------------------- the summary


def window_text(data: Any) -> str:
    """The analysis window in words: 'epochs 1–100, t = 1–100 s, 100 epochs'."""
    W = np.asarray(data.window, dtype=bool)
    idx = np.flatnonzero(W)
    if not idx.size:
        return "empty analysis window"
    k0, k1 = int(idx[0]), int(idx[-1])
    t = np.asarray(data.t)
    span = f"epochs {k0}–{k1}"
    if idx.size != k1 - k0 + 1:
        span += " (not contiguous)"
    return f"{span}, t = {t[k0]:.4g}–{t[k1]:.4g} s, {idx.size} epochs"


def row(key, label, metric, value, unit="", est: S.Estimate | None = None, runs_used=None, note=""):
    r = dict(filter=key, label=label, metric=metric, value=float(value), unit=unit)
    has = est is not None and est.has_ci
    r["ci_lo"] = est.lo if has else np.nan
    r["ci_hi"] = est.hi if has else np.nan
    r["ci_method"] = est.method if has else ""
    r["runs_used"] = np.nan if runs_used is None else int(runs_used)
    notes = [n for n in (note, "" if est is None else est.note) if n]
    r["note"] = "; ".join(notes)
    return r


class Summary:
    """The metrics of one experiment, computed once and on demand (cached on the Results).

    Point values of every metric are cheap; an interval costs one bootstrap (or delta) per
    filter and metric, so it is computed when a table asks for that metric and then kept, and
    the paired comparisons reuse each filter's resample replicates.
    """

    def __init__(self, res: Results | Any) -> None:
        self.res = res
        data = res.data
        self.data = data
        self.seed = int(res.spec.seed)
        # a summary run (navlab.experiment.SummaryResults) brings its per-run statistics and
        # has no per-epoch arrays; full results have both
        self.arrays = not hasattr(res, "stats")
        self.stats = res.stats if not self.arrays else {k: run_stats(data, fr) for k, fr in res.runs.items()}
        self.judgement = judge({k: st.diverged for k, st in self.stats.items()})
        self.rule = rule_text(data)
        self.window = window_text(data)
        self._resamplers: dict[int, S.Resampler] = {}
        self._est: dict[tuple[str, bytes], dict[str, tuple[S.Estimator, str]]] = {}
        self._ci: dict[tuple[str, str], S.Estimate] = {}
        self._rep: dict[tuple[str, str, bytes], Array] = {}
        self._paired: dict[tuple[str, str, str], Paired | None] = {}

    def resampler(self, n: int) -> S.Resampler:
        if n not in self._resamplers:
            self._resamplers[n] = S.Resampler(n, self.seed)
        return self._resamplers[n]

    def estimators(self, key: str, runs: Array) -> dict[str, tuple[S.Estimator, str]]:
        ck = (key, np.packbits(runs).tobytes())
        if ck not in self._est:
            self._est[ck] = estimators(self.stats[key], self.data, runs)
        return self._est[ck]

    def metrics_of(self, key: str) -> dict[str, tuple[S.Estimator, str]]:
        return self.estimators(key, self.judgement.judged[key])

    def estimate(self, key: str, metric: str) -> S.Estimate:
        """The metric of filter ``key`` on its judged runs, with its 95 % interval."""
        ck = (key, metric)
        if ck not in self._ci:
            est, _unit = self.metrics_of(key)[metric]
            if est.n == 0:
                self._ci[ck] = S.Estimate(float("nan"), note="no run to judge")
            else:
                self._ci[ck] = self.resampler(est.n).estimate(est)
        return self._ci[ck]

    def comparison(self, key: str, ref: str, metric: str) -> tuple[S.Comparison, str] | None:
        """Paired Δ = metric(key) − metric(ref) under the loss rule (:meth:`paired`)."""
        got = self.paired(key, ref, metric)
        return None if got is None else (got.c, got.unit)

    def paired(self, key: str, ref: str, metric: str) -> Paired | None:
        """Paired Δ = metric(key) − metric(ref) over EVERY run, a run lost by one of the two
        scored as its loss (:data:`LOSS_RULE`, :func:`navlab.stats.with_losses`), and the Δ over
        the runs both are judged on beside. Metrics without a direction (consistency) have no
        worst value: their Δ is over the judged runs alone.
        """
        ck = (key, ref, metric)
        if ck not in self._paired:
            self._paired[ck] = self._make_paired(key, ref, metric)
        return self._paired[ck]

    def _make_paired(self, key: str, ref: str, metric: str) -> Paired | None:
        jd = self.judgement
        runs = jd.judged[key] & jd.judged[ref]
        n = int(runs.sum())
        ea = self.estimators(key, runs).get(metric)
        eb = self.estimators(ref, runs).get(metric)
        if ea is None or eb is None or n == 0:
            return None
        common = self.resampler(n).compare(ea[0], eb[0])
        d = direction(metric)
        lost_a, lost_b = ~jd.valid[key], ~jd.valid[ref]
        if d == 0 or (runs.all() and not (lost_a.any() or lost_b.any())):
            return Paired(common, common, ea[1], "")
        every = np.ones(jd.n_runs, dtype=bool)
        fa = self.estimators(key, every).get(metric)
        fb = self.estimators(ref, every).get(metric)
        if fa is None or fb is None:
            return Paired(common, common, ea[1], "")
        a, b = S.with_losses(fa[0], fb[0], lost_a, lost_b, d)
        c = self.resampler(jd.n_runs).compare(a, b)
        lost = [f"{int(m.sum())} runs lost by {k}" for k, m in ((key, lost_a), (ref, lost_b)) if m.any()]
        note = (
            "; ".join(lost) + ": scored as the worst run of the pair (a loss)"
            if lost
            else f"over all {jd.n_runs} runs"
        )
        return Paired(c, common, ea[1], note)

    def rows(self, metrics: list[str] | None = None) -> pd.DataFrame:
        """Tidy rows (:data:`COLUMNS`): every metric of every filter, with intervals for the
        ``metrics`` named (all when None) and point values for the rest.
        """
        res, data, jd = self.res, self.data, self.judgement
        rows: list[dict] = []
        for key, st in self.stats.items():
            fr = res.runs[key]
            runs = jd.judged[key]
            n = int(runs.sum())
            lost = jd.lost(key)
            label_note = "" if jd.reliable[key] else f"on the {n} common runs it survived"
            for metric, (est, unit) in self.metrics_of(key).items():
                if metrics is None or metric in metrics:
                    e = self.estimate(key, metric)
                else:
                    e = S.Estimate(est.point() if n else float("nan"), note="")
                rows.append(row(key, fr.label, metric, e.value, unit, e, n, label_note))
            for name, skipped in (("nees_skipped", "nees_skip"), ("nis_skipped", "nis_skip")):
                if skipped in st.sums:
                    rows.append(row(key, fr.label, name, st.sums[skipped][runs].sum(), "entries"))
            if st.estimates_R:
                skip = st.sums["rhat_skip"][runs].sum()
                rows.append(row(key, fr.label, "rhat_skipped", skip, "entries"))
            dofs = {"anees": _n_states(data), "anis": _n_channels(data)} if data.has_truth else {}
            dofs.setdefault("anis", _n_channels(data))
            curves = _consistency_curves(res, key, runs) if self.arrays else {}
            for name, dof in dofs.items():
                lo, hi = chi2_band(dof, n)
                rows.append(row(key, fr.label, f"{name}_band_lo", lo))
                rows.append(row(key, fr.label, f"{name}_band_hi", hi))
                if name in curves:  # needs the per-epoch averages (not in a summary run)
                    avg = curves[name]
                    fin = np.isfinite(avg)
                    inside = float(np.mean((avg[fin] >= lo) & (avg[fin] <= hi))) if fin.any() else np.nan
                    rows.append(row(key, fr.label, f"{name}_in_band_pct", 100 * inside, "%", runs_used=n))
            for name, extra in data.extras.get("metrics", {}).items() if self.arrays else ():
                if not isinstance(extra, QuantileMetric):  # a plain function: point value only
                    fn, unit = extra
                    v = fn(fr.x, data, runs) if n else float("nan")
                    rows.append(row(key, fr.label, name, v, unit, None, n, "no interval (point metric)"))
            note = "" if lost == 0 else _lost_note(jd, key)
            rows.append(row(key, fr.label, "diverged", lost, "runs", note=note))
            rows.append(row(key, fr.label, "runs", data.B, "runs"))
            rows.append(row(key, fr.label, "runs_judged", n, "runs"))
            B, K = data.B, data.K
            steps = timed_steps(B, K)
            us = 1e6 * st.runtime_s / steps
            rows.append(row(key, fr.label, "us_per_run_step", us, "µs"))
            rate = steps / st.runtime_s if st.runtime_s > 0 else np.nan
            rows.append(row(key, fr.label, "steps_per_s", rate, "1/s"))
        return pd.DataFrame(rows, columns=COLUMNS)


def summary(res: Results) -> Summary:
    """The :class:`Summary` of ``res`` (made once per Results object)."""
    sm = res.__dict__.get("_summary")
    if sm is None:
        sm = Summary(res)
        res.__dict__["_summary"] = sm
    return sm


def _lost_note(jd: Judgement, key: str) -> str:
    lost, n = jd.lost(key), jd.n_runs
    if jd.reliable[key]:
        return f"{lost} of {n} runs lost (left out for every filter)"
    return f"diverges in {lost} of {n} runs: ranks below every filter that does not"


def _n_states(data: Any) -> int:
    return int(getattr(data, "n", None) or data.x0.shape[1])


def _n_channels(data: Any) -> int:
    return int(getattr(data, "m", None) or data.z.shape[2])


def _consistency_curves(res: Results, key: str, runs: Array) -> dict[str, Array]:
    """Per-epoch ANEES/ANIS over the judged runs in the window."""
    fr, data = res.runs[key], res.data
    W = _window_masks(data)["W"]  # a slice where the window is contiguous: views, no copies
    out = {}
    if data.has_truth:
        out["anees"] = average_over_runs(fr.nees[:, W], runs)
    out["anis"] = average_over_runs(fr.nis[:, W], runs)
    return out


def summarize(res: Results, metrics: list[str] | None = None) -> pd.DataFrame:
    """Tidy table: one row per filter and metric (:data:`COLUMNS`) with the intervals of
    ``metrics`` (default: every metric). :func:`navlab.tables.summary_rows` appends the paired
    rows against a reference filter.
    """
    return summary(res).rows(metrics)


# --------------------------------------------------------------------------- paired comparison


def compare(
    res: Results, ref: str, metrics: Sequence[str], among: Sequence[str] | None = None
) -> pd.DataFrame:
    """Paired differences of every other filter (of ``among``, default all) against ``ref``
    (rows ``<metric>_diff``; Holm's correction is across those filters).

    For each filter A ≠ ref and metric of ``metrics``: Δ = metric(A) − metric(ref) over every run,
    a run lost by one of the two scored as its loss (:data:`LOSS_RULE`; with no run lost and the
    common runs all runs, Δ is the difference of the table's values), its 95 % interval and
    p-value (paired bootstrap over runs, the p the inversion of that interval, or the delta
    method at ≥ 1000 runs; ``p_bound`` "<" where it is at the bootstrap's floor), Holm-adjusted
    across the other filters (``p_holm``, ``p_holm_bound``), a verdict: ``better`` / ``worse``
    (adjusted p < 0.05, by the metric's direction and the side of 0 the interval lies on) or
    ``indistinguishable`` at this run count, and beside it Δ over the runs both kept
    (``common_*``, no loss scored). A filter that diverges in more than 5 % of the runs is
    ``worse`` than a reliable reference whatever Δ (and the reverse).
    """
    if ref not in res.runs:
        raise NavlabError(
            f"--compare-to '{ref}' is not one of the filters in this run: {', '.join(res.runs)}"
        )
    sm = summary(res)
    jd = sm.judgement
    rows: list[dict] = []
    for metric in metrics:
        part: list[dict] = []
        pvals: dict[str, float] = {}
        bounds: dict[str, bool] = {}
        for key in res.runs:
            if key == ref or (among is not None and key not in among):
                continue
            got = sm.paired(key, ref, metric)
            if got is None:
                continue
            pvals[key], bounds[key] = got.c.p_value, got.c.at_floor
            part.append(diff_row(key, res.runs[key].label, metric, got, ref))
        adj, adj_bound = S.holm_bounds(pvals, bounds)
        for r in part:
            key = r["filter"]
            r["p_holm"] = adj.get(key, np.nan)
            r["p_holm_bound"] = "<" if adj_bound.get(key) else ""
            r["verdict"], extra = verdict(metric, r, jd, key, ref)
            if extra:
                r["note"] = "; ".join(x for x in (r["note"], extra) if x)
        rows += part
    return pd.DataFrame(rows, columns=COLUMNS + DIFF_COLUMNS)


def diff_row(key: str, label: str, metric: str, got: Paired, vs: str) -> dict:
    """The ``<metric>_diff`` row of a paired comparison (before Holm's correction and verdict)."""
    c, cc = got.c, got.common
    note = "; ".join(x for x in (c.note, got.note) if x)
    r = row(key, label, f"{metric}_diff", c.value, got.unit, None, c.n_runs, note)
    r.update(ci_lo=c.lo, ci_hi=c.hi, ci_method=c.method, vs=vs, p_value=c.p_value)
    r["p_bound"] = "<" if c.at_floor else ""
    r.update(common_value=cc.value, common_ci_lo=cc.lo, common_ci_hi=cc.hi, common_runs=cc.n_runs)
    return r


def verdict(metric: str, r: dict, jd: Judgement, key: str, ref: str) -> tuple[str, str]:
    if jd.reliable[ref] and not jd.reliable[key]:
        return "worse", f"{key} diverges in {jd.lost(key)} of {jd.n_runs} runs"
    if jd.reliable[key] and not jd.reliable[ref]:
        return "better", f"{ref} diverges in {jd.lost(ref)} of {jd.n_runs} runs"
    d = direction(metric)
    p = r.get("p_holm", np.nan)
    if not r["ci_method"] or not np.isfinite(p):
        return "", "no test (too few runs)"
    if d == 0:
        return "", "no direction: consistency is judged against its χ² band"
    # the side of 0 the interval lies on (a test p < 0.05 means it excludes 0): never the point
    # estimate against its own interval (a bias-corrected interval need not hold it)
    side = 1.0 if r["ci_lo"] > 0 else (-1.0 if r["ci_hi"] < 0 else np.sign(r["value"]))
    if p < S.ALPHA and side * d < 0:
        return "better", ""
    if p < S.ALPHA and side * d > 0:
        return "worse", ""
    return "indistinguishable", "indistinguishable at this run count"


def headline_table(res: Results) -> pd.DataFrame:
    """Wide numeric table for display: one row per filter (label), columns the headline metrics."""
    df = summary(res).rows(metrics=[])
    wanted = [f"rmse_{g}" for g in res.data.groups]
    wanted += list(res.data.extras.get("metrics", {}))
    wanted += [*QUALITY_METRICS, "diverged", "us_per_run_step"]
    df = df[df.metric.isin(wanted)]
    wide = df.pivot_table(index="label", columns="metric", values="value", sort=False, dropna=False)
    return wide[[c for c in wanted if c in wide.columns]]

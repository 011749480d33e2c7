"""Metrics of ALGORITHMS.md §9: RMSE (per epoch, pooled, windowed), ANEES/ANIS with χ² bands,
R̂ error against the true R(t), detection rates, divergence, runtime.

Pure functions of arrays plus :func:`summarize`, which turns :class:`navlab.experiment.Results`
into a tidy table (one row per filter and metric). Diverged runs (non-finite state) are counted
and excluded from every other metric.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from scipy.stats import chi2

from navlab.linalg import Array
from navlab.scenarios.base import MetricGroup

if TYPE_CHECKING:
    from navlab.experiment import FilterRun, Results


def chi2_band(dof: int, runs: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided band of an average over ``runs`` of χ²(dof) variables: χ²(N·dof)/N quantiles.

    Bar-Shalom, Li & Kirubarajan 2001, ch. 5 (e.g. dof 4, N 100 → [3.46, 4.57]).
    """
    a = (1.0 - level) / 2.0
    N = max(int(runs), 1)
    return float(chi2.ppf(a, N * dof) / N), float(chi2.ppf(1 - a, N * dof) / N)


def sq_error(x_hat: Array, x_true: Array, group: MetricGroup) -> Array:
    """Squared error norm over the group's components, in display units: (B, K+1)."""
    e = (x_hat[..., list(group.idx)] - x_true[..., list(group.idx)]) * group.scale
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


def average_over_runs(v: Array, ok_runs: Array | None = None) -> Array:
    """Per-epoch mean over runs (ANEES ε̄_k or ANIS), (K+1,)."""
    if ok_runs is not None:
        v = v[ok_runs]
    finite = np.isfinite(v)
    n = finite.sum(axis=0)
    total = np.where(finite, v, 0.0).sum(axis=0)
    return np.divide(total, n, out=np.full(v.shape[1:], np.nan), where=n > 0)


def consistency(v: Array, dof: int, window: Array, ok_runs: Array) -> dict[str, float]:
    """Time-averaged ANEES/ANIS, its per-epoch 95 % band and the fraction of epochs inside."""
    avg = average_over_runs(v, ok_runs)[window]
    lo, hi = chi2_band(dof, int(ok_runs.sum()))
    finite = np.isfinite(avg)
    return {
        "mean": float(np.mean(avg[finite])) if finite.any() else float("nan"),
        "lo": lo,
        "hi": hi,
        "in_band": float(np.mean((avg[finite] >= lo) & (avg[finite] <= hi))) if finite.any() else 0.0,
    }


def rhat_error_pct(R_hat: Array, R_schedule: Array, window: Array, ok_runs: Array) -> float:
    """Mean |σ̂/σ − 1| in % over epochs in ``window``, runs and channels (σ from the schedule)."""
    with np.errstate(all="ignore"):
        ratio = np.sqrt(R_hat[ok_runs][:, window]) / np.sqrt(R_schedule[window])[None]
    ratio = ratio[np.isfinite(ratio)]
    return float(100 * np.mean(np.abs(ratio - 1))) if ratio.size else float("nan")


def flag_rates(fr: FilterRun, mask: Array, window: Array, ok_runs: Array) -> dict[str, float]:
    """Share of contaminated entries the filter flagged (any code ≠ 0) and of clean ones."""
    flags = fr.flags[ok_runs][:, window] != 0
    m = mask[ok_runs][:, window]
    return {
        "detected_pct": float(100 * flags[m].mean()) if m.any() else float("nan"),
        "false_alarm_pct": float(100 * flags[~m].mean()) if (~m).any() else float("nan"),
    }


def summarize(res: Results) -> pd.DataFrame:
    """Tidy table with columns filter, label, metric, value, unit."""
    data = res.data
    rows: list[tuple[str, str, str, float, str]] = []
    n = data.x0.shape[1]
    m = data.z.shape[2]
    W = data.window
    B, K = data.B, data.K
    for key, fr in res.runs.items():
        ok = ~fr.diverged
        add = lambda metric, value, unit="", key=key, label=fr.label: rows.append(  # noqa: E731
            (key, label, metric, float(value), unit)
        )
        if data.has_truth:
            for g, group in data.groups.items():
                sq = sq_error(fr.x, data.x_true, group)
                add(f"rmse_{g}", pooled_rmse(sq, W, ok), group.unit)
                add(f"mean_rmse_{g}", mean_of_rmse(sq, W, ok), group.unit)
            c = consistency(fr.nees, n, W, ok)
            add("anees", c["mean"])
            add("anees_band_lo", c["lo"])
            add("anees_band_hi", c["hi"])
            add("anees_in_band_pct", 100 * c["in_band"], "%")
        c = consistency(fr.nis, m, W, ok)
        add("anis", c["mean"])
        add("anis_band_lo", c["lo"])
        add("anis_band_hi", c["hi"])
        add("anis_in_band_pct", 100 * c["in_band"], "%")
        if fr.R_hat is not None:
            add("rhat_err_pct", rhat_error_pct(fr.R_hat, data.R_schedule, W, ok), "%")
        if data.outlier_mask.any():
            r = flag_rates(fr, data.outlier_mask, W, ok)
            add("detected_pct", r["detected_pct"], "%")
            add("false_alarm_pct", r["false_alarm_pct"], "%")
        # scenario-specific metrics (real data): data.extras["metrics"] = {name: (fn, unit)},
        # fn(x_hat (B, K+1, n), data, ok_runs) -> float
        for name, (fn, unit) in data.extras.get("metrics", {}).items():
            add(name, fn(fr.x, data, ok), unit)
        add("diverged", int((~ok).sum()), "runs")
        add("runs", B, "runs")
        add("us_per_run_step", 1e6 * fr.runtime_s / max(B * K, 1), "µs")
        add("steps_per_s", B * K / fr.runtime_s if fr.runtime_s > 0 else float("nan"), "1/s")
    return pd.DataFrame(rows, columns=["filter", "label", "metric", "value", "unit"])


def headline_table(res: Results) -> pd.DataFrame:
    """Wide table for display: one row per filter, columns the headline metrics."""
    df = summarize(res)
    wanted = [f"rmse_{g}" for g in res.data.groups]
    wanted += list(res.data.extras.get("metrics", {}))
    wanted += [
        "anees",
        "anis",
        "rhat_err_pct",
        "detected_pct",
        "false_alarm_pct",
        "diverged",
        "us_per_run_step",
    ]
    df = df[df.metric.isin(wanted)]
    wide = df.pivot_table(index="label", columns="metric", values="value", sort=False)
    return wide[[c for c in wanted if c in wide.columns]]

"""Plotly figure builders and display tables: pure functions of results (no streamlit).

Rules followed (ECOSYSTEM.md §A3): numpy arrays (float32) rather than lists, so plotly ≥ 6 sends
base64 typed arrays; long series are decimated to about ``MAX_POINTS`` points per trace (by
stride, except outlier marks which keep the per-bucket maximum); Monte Carlo clouds are shown as a
central line plus a quantile band (``fill="tonexty"``), never one trace per run; WebGL
(``Scattergl``) is used only for long series so a page stays under the browser's WebGL-context
cap. Runs whose state became non-finite ("diverged") are excluded from every curve and reported in
the legend; a filter that diverged in every run is listed as diverged, never drawn as NaN.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import plotly.graph_objects as go

from navlab.metrics import (
    average_over_runs,
    chi2_band,
    error_quantiles,
    headline_table,
    rmse_per_epoch,
    sq_error,
)
from navlab.ui.colors import TRUTH_COLOR, filter_colors, rgba

if TYPE_CHECKING:
    from navlab.experiment import FilterRun, Results

MAX_POINTS = 2000  # points per trace after decimation
GL_ABOVE = 1000  # use WebGL traces above this many points
BAND = (0.1, 0.9)  # default spread band: 10 %–90 % of runs
F32 = np.float32

# --------------------------------------------------------------------------- helpers


def decimation(n: int, max_points: int = MAX_POINTS) -> slice:
    """Stride slice keeping at most about ``max_points`` of ``n`` samples (last one kept)."""
    step = max(1, int(np.ceil(n / max_points)))
    return slice(None, None, step)


def bucket_max(v: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Per-bucket maximum (indices of bucket starts, maxima): spikes survive decimation."""
    n = v.shape[0]
    step = max(1, int(np.ceil(n / max_points)))
    if step == 1:
        return np.arange(n), v
    pad = (-n) % step
    vv = np.concatenate([v, np.full(pad, -np.inf)]).reshape(-1, step)
    return np.arange(0, n, step), vv.max(axis=1)


def _scatter(n: int) -> type:
    return go.Scattergl if n > GL_ABOVE else go.Scatter


def _f32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=F32)


def nan_quantiles(v: np.ndarray, qs: Sequence[float]) -> np.ndarray:
    """Quantiles over axis 0 ignoring NaN; all-NaN columns give NaN without a warning."""
    if np.isfinite(v).all():
        return np.quantile(v, list(qs), axis=0)  # np.nanquantile is ~10x slower
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanquantile(v, list(qs), axis=0)


def judged(res: Results, key: str) -> np.ndarray:
    """The runs filter ``key`` is judged on (navlab.metrics: the common runs of the reliable
    filters), so every curve is drawn over the same runs as the table's numbers.
    """
    from navlab.metrics import summary

    return summary(res).judgement.judged[key]


def ok_runs(fr: FilterRun) -> np.ndarray:
    """Runs that did not diverge (finite state throughout)."""
    return ~np.asarray(fr.diverged)


def divergence_note(fr: FilterRun) -> str:
    """'' if no run diverged, else e.g. '3/100 runs diverged' (first at k = 17)."""
    bad = int(np.sum(fr.diverged))
    if bad == 0:
        return ""
    first = int(np.min(fr.diverged_at[fr.diverged_at >= 0]))
    return f"{bad}/{fr.diverged.shape[0]} runs diverged (first at epoch {first})"


def _legend_name(fr: FilterRun) -> str:
    bad = int(np.sum(fr.diverged))
    n = fr.diverged.shape[0]
    if bad == 0:
        return fr.label
    if bad == n:
        return f"{fr.label} — diverged in all {n} runs"
    return f"{fr.label} ({bad}/{n} diverged, excluded)"


def _diverged_stub(traces: list, fr: FilterRun, color: str, **axes) -> None:
    """A legend entry with no data for a filter that diverged in every run."""
    traces.append(
        go.Scatter(
            x=np.zeros(0, F32),
            y=np.zeros(0, F32),
            mode="lines",
            name=_legend_name(fr),
            line={"color": color, "dash": "dot"},
            legendgroup=fr.key,
            hoverinfo="skip",
            **axes,
        )
    )


def add_band(
    traces: list,
    x: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    color: str,
    group: str,
    name: str = "",
    alpha: float = 0.18,
    showlegend: bool = False,
    **axes,
) -> None:
    """A translucent band between ``lo`` and ``hi`` (two traces, filled to the next).

    ``axes`` may name subplot axes (``xaxis="x2", yaxis="y2"``).
    """
    sl = decimation(x.shape[0])
    cls = _scatter(x[sl].shape[0])
    common = {
        "mode": "lines",
        "line": {"width": 0, "color": color},
        "legendgroup": group,
        "hoverinfo": "skip",
        **axes,
    }
    traces.append(cls(x=_f32(x[sl]), y=_f32(hi[sl]), showlegend=False, **common))
    traces.append(
        cls(
            x=_f32(x[sl]),
            y=_f32(lo[sl]),
            fill="tonexty",
            fillcolor=rgba(color, alpha),
            name=name,
            showlegend=showlegend,
            **common,
        )
    )


def add_line(
    traces: list,
    x: np.ndarray,
    y: np.ndarray,
    name: str,
    color: str,
    group: str | None = None,
    dash: str | None = None,
    width: float = 2.0,
    showlegend: bool = True,
    **axes,
) -> None:
    """One decimated line trace from numpy arrays."""
    sl = decimation(x.shape[0])
    cls = _scatter(x[sl].shape[0])
    traces.append(
        cls(
            x=_f32(x[sl]),
            y=_f32(y[sl]),
            mode="lines",
            name=name,
            legendgroup=group or name,
            line={"color": color, "dash": dash, "width": width},
            showlegend=showlegend,
            **axes,
        )
    )


def _base_layout(title: str, height: int) -> dict:
    return {
        "title": {"text": title, "x": 0, "xanchor": "left", "font": {"size": 15}},
        "height": height,
        "margin": {"l": 60, "r": 20, "t": 60, "b": 45},
        "hovermode": "x unified",
        "legend": {"orientation": "h", "yanchor": "bottom", "y": 1.02, "xanchor": "right", "x": 1},
    }


def _figure(
    traces: list, title: str, x_title: str, y_title: str, log_y: bool = False, height: int = 380
) -> go.Figure:
    """One figure from all traces at once (much cheaper than trace-by-trace ``add_trace``)."""
    layout = _base_layout(title, height)
    layout["xaxis"] = {"title": {"text": x_title}}
    layout["yaxis"] = {"title": {"text": y_title}, "type": "log" if log_y else "linear"}
    return go.Figure(data=traces, layout=layout)


# --------------------------------------------------------------------------- compare page


def error_vs_time(
    res: Results, group: str, *, log_y: bool = False, band: tuple[float, float] | None = BAND
) -> go.Figure:
    """Per filter: Monte Carlo RMSE per epoch of the ``group`` error norm plus a spread band.

    The band spans the ``band`` quantiles over runs of the per-run error norm.
    """
    data = res.data
    g = data.groups[group]
    colors = filter_colors(list(res.runs))
    traces: list = []
    t = data.t
    for key, fr in res.runs.items():
        ok = judged(res, key)
        c = colors[key]
        if not ok.any():
            _diverged_stub(traces, fr, c)
            continue
        sq = sq_error(fr.x, data.x_true, g)
        if band is not None:
            lo, hi = error_quantiles(sq, band, ok)
            add_band(traces, t, lo, hi, c, key)
        add_line(traces, t, rmse_per_epoch(sq, ok), _legend_name(fr), c, key)
    bt = "" if band is None else f"; band: {int(band[0] * 100)}–{int(band[1] * 100)} % of runs"
    return _figure(
        traces,
        f"{g.label.capitalize()} error — RMSE over {data.B} runs{bt}",
        "time (s)",
        f"{g.label} error ({g.unit})",
        log_y,
    )


def _r_units(data, channel: int, as_std: bool) -> str:
    u = data.channel_units[channel] if channel < len(data.channel_units) else ""
    if as_std:
        return u
    return f"{u}²" if u else ""


def r_vs_rhat(
    res: Results,
    channel: int,
    *,
    log_y: bool = False,
    as_std: bool = False,
    show_used: bool = True,
    band: tuple[float, float] = BAND,
    outlier_strip: bool = False,
    height: int = 400,
) -> go.Figure:
    """True R(t) of the noise schedule beside each filter's R̂ (median and spread over runs).

    Filters without an R̂ show the R they used (dashed median) when ``show_used``. With
    ``outlier_strip`` a lower panel shows, per epoch, the share of runs with an outlier on the
    channel (the outlier epochs marked on the time axis).
    """
    data = res.data
    colors = filter_colors(list(res.runs))
    t = data.t
    tf = lambda v: np.sqrt(np.maximum(v, 0.0)) if as_std else v  # noqa: E731
    traces: list = []
    sym = "σ" if as_std else "R"
    add_line(
        traces, t, tf(data.R_schedule[:, channel]), f"true {sym}(t) (schedule)", TRUTH_COLOR, "truth", width=3
    )
    for key, fr in res.runs.items():
        ok = judged(res, key)
        c = colors[key]
        if not ok.any():
            _diverged_stub(traces, fr, c)
            continue
        est = fr.R_hat is not None
        if not est and not show_used:
            continue
        v = (fr.R_hat if est else fr.R_used)[ok][:, 1:, channel]
        q = nan_quantiles(tf(v), (band[0], 0.5, band[1]))
        if est:
            add_band(traces, t[1:], q[0], q[2], c, key)
            add_line(traces, t[1:], q[1], f"{_legend_name(fr)} {sym}̂ (median)", c, key)
        else:
            add_line(
                traces,
                t[1:],
                q[1],
                f"{_legend_name(fr)} {sym} used (no {sym}̂)",
                c,
                key,
                dash="dash",
                width=1.5,
            )
    name = data.channel_names[channel] if channel < len(data.channel_names) else str(channel)
    units = _r_units(data, channel, as_std)
    y_title = f"{sym} ({units})" if units else sym
    title = f"Channel {name}: true {sym}(t) vs each filter's {sym}̂ (median, {int(band[0] * 100)}–"
    title += f"{int(band[1] * 100)} % band over runs)"
    if not outlier_strip:
        return _figure(traces, title, "time (s)", y_title, log_y, height)
    frac = data.outlier_mask[:, :, channel].mean(axis=0)
    idx, fmax = bucket_max(frac)
    traces.append(
        go.Bar(
            x=_f32(t[idx]),
            y=_f32(fmax),
            name="share of runs with an outlier",
            marker={"color": "#d62728", "line": {"width": 0}},
            legendgroup="outliers",
            xaxis="x",
            yaxis="y2",
        )
    )
    layout = _base_layout(title, height + 90)
    layout.update(
        bargap=0,
        xaxis={"title": {"text": "time (s)"}, "anchor": "y2"},
        yaxis={"title": {"text": y_title}, "type": "log" if log_y else "linear", "domain": [0.27, 1.0]},
        yaxis2={"title": {"text": "outliers"}, "range": [0, 1], "domain": [0.0, 0.2]},
    )
    return go.Figure(data=traces, layout=layout)


def outlier_epochs(res: Results, channel: int, min_share: float = 0.5) -> np.ndarray:
    """Epochs at which at least ``min_share`` of the runs have an outlier on ``channel``."""
    frac = res.data.outlier_mask[:, :, channel].mean(axis=0)
    return np.flatnonzero(frac >= min_share)


def nis_vs_chi2(res: Results, *, log_y: bool = True, level: float = 0.95) -> go.Figure:
    """ANIS per epoch (average NIS over non-diverged runs) against its two-sided χ² band."""
    data = res.data
    colors = filter_colors(list(res.runs))
    t = data.t
    m = data.z.shape[2]
    traces: list = []
    N = None
    for key, fr in res.runs.items():
        ok = judged(res, key)
        c = colors[key]
        if not ok.any():
            _diverged_stub(traces, fr, c)
            continue
        N = int(ok.sum()) if N is None else min(N, int(ok.sum()))
        add_line(traces, t[1:], average_over_runs(fr.nis, ok)[1:], _legend_name(fr), c, key)
    if N:
        lo, hi = chi2_band(m, N, level)
        x = np.array([t[1], t[-1]]) if t.shape[0] > 1 else t
        add_band(
            traces,
            x,
            np.full(x.shape, lo),
            np.full(x.shape, hi),
            TRUTH_COLOR,
            "chi2",
            name=f"χ² {int(level * 100)} % band (dof {m}, {N} runs)",
            alpha=0.12,
            showlegend=True,
        )
        add_line(
            traces, x, np.full(x.shape, float(m)), f"E[NIS] = {m}", TRUTH_COLOR, "chi2", dash="dot", width=1
        )
    return _figure(traces, "Consistency: average NIS over runs vs its χ² band", "time (s)", "ANIS", log_y)


# --------------------------------------------------------------------------- tables


def metric_label(metric: str, res: Results) -> str:
    """Readable column name with unit for a metric key of :func:`navlab.metrics.summarize`."""
    groups = res.data.groups
    for prefix, word in (("mean_rmse_", "mean RMSE"), ("rmse_", "RMSE")):
        if metric.startswith(prefix) and metric[len(prefix) :] in groups:
            g = groups[metric[len(prefix) :]]
            return f"{word} {g.label} ({g.unit})"
    return {
        "anees": "ANEES",
        "anis": "ANIS",
        "rhat_err_pct": "R̂ error (%)",
        "detected_pct": "outliers flagged (%)",
        "false_alarm_pct": "false alarms (%)",
        "diverged": "diverged runs",
        "us_per_run_step": "µs per run·step",
    }.get(metric, metric)


def metric_title(metric: str, unit: str = "") -> str:
    """Readable name of a tidy-table metric without the results at hand (e.g. for sweeps)."""
    names = {
        "anees": "ANEES",
        "anis": "ANIS",
        "rhat_err_pct": "R̂ error",
        "detected_pct": "outliers flagged",
        "false_alarm_pct": "false alarms",
        "diverged": "diverged runs",
    }
    if metric.startswith("mean_rmse_"):
        name = f"mean RMSE {metric[10:].replace('_', ' ')}"
    elif metric.startswith("rmse_"):
        name = f"RMSE {metric[5:].replace('_', ' ')}"
    else:
        name = names.get(metric, metric)
    return f"{name} ({unit})" if unit and unit != "runs" else name


def summary_table(res: Results, groups: Sequence[str] | None = None) -> pd.DataFrame:
    """One row per filter: headline RMSE (for ``groups``), consistency, R̂ error, divergence."""
    wide = headline_table(res)
    if groups is not None:
        drop = [f"rmse_{g}" for g in res.data.groups if g not in groups]
        wide = wide.drop(columns=[c for c in drop if c in wide.columns])
    wide = wide.rename(columns=lambda c: metric_label(c, res))
    wide.index.name = "filter"
    return wide


def rmse_curves(res: Results) -> pd.DataFrame:
    """Tidy per-epoch RMSE of every group and filter (the CSV behind the error plot)."""
    data = res.data
    frames = []
    for key, fr in res.runs.items():
        ok = judged(res, key)
        for gname, g in data.groups.items():
            sq = sq_error(fr.x, data.x_true, g)
            frames.append(
                pd.DataFrame(
                    {
                        "filter": key,
                        "group": gname,
                        "unit": g.unit,
                        "epoch": np.arange(data.K + 1),
                        "t_s": data.t,
                        "rmse": rmse_per_epoch(sq, ok) if ok.any() else np.nan,
                        "runs_used": int(ok.sum()),
                    }
                )
            )
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


# --------------------------------------------------------------------------- sweep page


def sweep_lines(
    df: pd.DataFrame, x_label: str, y_label: str, *, log_x: bool = False, log_y: bool = False
) -> go.Figure:
    """RMSE (or any metric) against the swept value, one line per filter.

    ``df`` columns: ``value`` (swept parameter), ``filter`` (key), ``label``, ``metric_value``
    and, where they exist, ``ci_lo``/``ci_hi``: each point's 95 % interval, drawn as error bars.
    """
    colors = filter_colors(list(df["filter"].unique()))
    traces: list = []
    for key, d in df.groupby("filter", sort=False):
        d = d.sort_values("value")
        y = d["metric_value"].to_numpy(dtype=float)
        err = None
        if {"ci_lo", "ci_hi"} <= set(d.columns):
            lo, hi = d["ci_lo"].to_numpy(dtype=float), d["ci_hi"].to_numpy(dtype=float)
            if np.isfinite(lo).any():
                err = {
                    "type": "data",
                    "symmetric": False,
                    "array": _f32(np.where(np.isfinite(hi), hi - y, 0.0)),
                    "arrayminus": _f32(np.where(np.isfinite(lo), y - lo, 0.0)),
                    "thickness": 1.2,
                    "width": 4,
                }
        traces.append(
            go.Scatter(
                x=d["value"].to_numpy(dtype=float),
                y=_f32(y),
                error_y=err,
                mode="lines+markers",
                name=str(d["label"].iloc[0]),
                legendgroup=str(key),
                line={"color": colors[str(key)], "width": 2},
            )
        )
    fig = _figure(
        traces, f"{y_label} against {x_label} (bars: 95 % intervals over runs)", x_label, y_label, log_y
    )
    fig.update_layout(hovermode="closest", xaxis_type="log" if log_x else "linear")
    return fig


def sweep_heatmap(df: pd.DataFrame, x_label: str, y_label: str) -> go.Figure:
    """Heat map of the metric: filters (rows) × swept values (columns), values written in."""
    piv = df.pivot_table(index="label", columns="value", values="metric_value", sort=False)
    z = piv.to_numpy(dtype=float)
    xs = [f"{v:.4g}" for v in piv.columns]
    text = np.where(np.isfinite(z), np.char.mod("%.3g", np.nan_to_num(z)), "diverged")
    fig = go.Figure(
        go.Heatmap(
            z=z,
            x=xs,
            y=list(piv.index),
            text=text,
            texttemplate="%{text}",
            colorscale="Viridis",
            colorbar={"title": {"text": y_label}},
            hovertemplate="%{y}<br>%{x}: %{z:.4g}<extra></extra>",
        )
    )
    fig.update_layout(
        title={"text": f"{y_label}: filters × {x_label}", "x": 0, "font": {"size": 15}},
        height=140 + 40 * len(piv.index),
        margin={"l": 120, "r": 20, "t": 50, "b": 45},
    )
    fig.update_xaxes(title_text=x_label, type="category")
    return fig


def sweep_heatmap_2d(df: pd.DataFrame, x_label: str, y_label: str, z_label: str, title: str) -> go.Figure:
    """Heat map of one filter's metric over two swept parameters (``param_value`` on x,
    ``param2_value`` on y, ``value`` the metric; ``ci_lo``/``ci_hi`` in the hover).
    """
    piv = df.pivot_table(index="param2_value", columns="param_value", values="value")
    lo = df.pivot_table(index="param2_value", columns="param_value", values="ci_lo").reindex_like(piv)
    hi = df.pivot_table(index="param2_value", columns="param_value", values="ci_hi").reindex_like(piv)
    z = piv.to_numpy(dtype=float)
    text = np.where(np.isfinite(z), np.char.mod("%.3g", np.nan_to_num(z)), "diverged")
    ci = np.array(
        [
            [f"{a:.3g} – {b:.3g}" if np.isfinite(a) else "none" for a, b in zip(ra, rb, strict=True)]
            for ra, rb in zip(lo.to_numpy(dtype=float), hi.to_numpy(dtype=float), strict=True)
        ]
    )
    fig = go.Figure(
        go.Heatmap(
            z=z,
            x=[f"{v:.4g}" for v in piv.columns],
            y=[f"{v:.4g}" for v in piv.index],
            text=text,
            customdata=ci,
            texttemplate="%{text}",
            colorscale="Viridis",
            colorbar={"title": {"text": z_label}},
            hovertemplate="%{x} × %{y}: %{z:.4g} (95 %% interval %{customdata})<extra></extra>".replace(
                "%%", "%"
            ),
        )
    )
    fig.update_layout(
        title={"text": title, "x": 0, "font": {"size": 15}},
        height=160 + 36 * len(piv.index),
        margin={"l": 80, "r": 20, "t": 50, "b": 55},
    )
    fig.update_xaxes(title_text=x_label, type="category")
    fig.update_yaxes(title_text=y_label, type="category")
    return fig


def tune_landscape(
    trials: pd.DataFrame, dims: Sequence, names: Sequence[str], tuned: dict, label: str
) -> go.Figure:
    """A filter's objective over its one or two most influential parameters: every candidate of
    the first successive-halving rung (all on the same training runs), the default and the
    tuned value marked. ``trials`` is :func:`navlab.tune.trials_frame` for this filter.
    """
    by = {d.name: d for d in dims}
    t0 = trials[(trials.rung == 0) & np.isfinite(trials.objective)]
    runs = int(t0.runs.iloc[0]) if len(t0) else 0
    log = {n: by[n].scale == "log" for n in names}
    if len(names) == 1:
        n = names[0]
        x = t0[f"p.{n}"].to_numpy(dtype=float)
        order = np.argsort(x)
        traces = [
            go.Scatter(
                x=x[order],
                y=_f32(t0.objective.to_numpy(dtype=float)[order]),
                mode="markers+lines",
                name=f"candidates ({runs} runs each)",
                line={"color": "#888", "width": 1},
                marker={"size": 8, "color": "#1f77b4"},
            )
        ]
        d0 = t0[t0.candidate == 0]
        if len(d0):
            traces.append(
                go.Scatter(
                    x=[by[n].default],
                    y=[float(d0.objective.iloc[0])],
                    mode="markers",
                    name="default",
                    marker={"size": 13, "symbol": "diamond-open", "color": TRUTH_COLOR},
                )
            )
        hit = t0[np.isclose(t0[f"p.{n}"].to_numpy(dtype=float), tuned[n])]
        if len(hit):
            traces.append(
                go.Scatter(
                    x=[tuned[n]],
                    y=[float(hit.objective.iloc[0])],
                    mode="markers",
                    name="tuned",
                    marker={"size": 15, "symbol": "star", "color": "#d62728"},
                )
            )
        fig = _figure(traces, f"{label}: objective over {n}", n, "objective (training seeds)")
        fig.update_xaxes(type="log" if log[n] else "linear", range=None)
        return fig
    a, b = names[:2]
    traces = [
        go.Scatter(
            x=t0[f"p.{a}"].to_numpy(dtype=float),
            y=t0[f"p.{b}"].to_numpy(dtype=float),
            mode="markers",
            name=f"candidates ({runs} runs each)",
            marker={
                "size": 11,
                "color": _f32(t0.objective.to_numpy(dtype=float)),
                "colorscale": "Viridis",
                "showscale": True,
                "colorbar": {"title": {"text": "objective"}},
            },
            hovertemplate=f"{a} %{{x:.4g}}, {b} %{{y:.4g}}: %{{marker.color:.4g}}<extra></extra>",
        ),
        go.Scatter(
            x=[by[a].default],
            y=[by[b].default],
            mode="markers",
            name="default",
            marker={"size": 14, "symbol": "diamond-open", "color": TRUTH_COLOR},
        ),
        go.Scatter(
            x=[tuned[a]],
            y=[tuned[b]],
            mode="markers",
            name="tuned",
            marker={"size": 16, "symbol": "star", "color": "#d62728"},
        ),
    ]
    fig = _figure(traces, f"{label}: objective over {a} × {b}", a, b)
    fig.update_xaxes(type="log" if log[a] else "linear")
    fig.update_yaxes(type="log" if log[b] else "linear")
    return fig


def schedule_preview(spec, height: int = 220) -> go.Figure:
    """The chosen noise schedule's true σ(t)/σ_nominal over the run (cheap; shown before a run).

    It also makes the browser load plotly.js while the user is still configuring.
    """
    from navlab.experiment import plan

    p = plan(spec)
    K = p.scenario.epochs or 100
    f = p.schedule.std(np.ones(1), K)[:, 0]
    k = np.arange(K + 1, dtype=float)
    traces: list = []
    add_line(traces, k, f, "σ(t) / σ nominal", TRUTH_COLOR, "truth", width=2)
    fig = _figure(
        traces,
        f"Noise schedule '{spec.noise_schedule}': true σ(t) relative to the σ the filters assume",
        "epoch",
        "σ / σ nominal",
        height=height,
    )
    fig.update_layout(showlegend=False, hovermode="closest")
    return fig


# --------------------------------------------------------------------------- filter internals


def internal_stats(res: Results) -> list[str]:
    """Names of the per-step statistics the chosen filters report (fading factors, χ² test
    statistic, VB iterations, replacement flags …), thresholds excluded.
    """
    names = {s for fr in res.runs.values() for s in fr.stats if not s.endswith("_threshold")}
    return sorted(names)


def _per_epoch(v: np.ndarray, channel: int, m: int) -> np.ndarray:
    """(B, K+1[, c]) -> (B, K+1): the chosen channel of a per-channel statistic, else the max."""
    if v.ndim == 3:
        v = v[..., channel] if v.shape[2] == m else np.nanmax(np.where(np.isnan(v), -np.inf, v), -1)
        v = np.where(np.isinf(v), np.nan, v)
    return v


def internals_vs_time(res: Results, stat: str, channel: int = 0, log_y: bool = False) -> go.Figure:
    """Per filter, the median over runs of statistic ``stat`` per epoch (for 0/1 indicators such as
    ``rejected`` or ``replaced``: the share of runs), with ``<stat>_threshold`` dashed if reported.
    """
    data = res.data
    m = data.z.shape[2]
    colors = filter_colors(list(res.runs))
    traces: list = []
    for key, fr in res.runs.items():
        if stat not in fr.stats:
            continue
        ok = judged(res, key)
        v = _per_epoch(np.asarray(fr.stats[stat], dtype=float), channel, m)[ok]
        if not v.size:
            continue
        finite = v[np.isfinite(v)]
        binary = finite.size > 0 and np.isin(finite, (0.0, 1.0)).all()
        y = average_over_runs(v) if binary else nan_quantiles(v, (0.5,))[0]
        add_line(traces, data.t, y, _legend_name(fr), colors[key], key)
        thr = fr.stats.get(f"{stat}_threshold")
        if thr is not None:
            t_y = nan_quantiles(_per_epoch(np.asarray(thr, dtype=float), channel, m)[ok], (0.5,))[0]
            add_line(
                traces,
                data.t,
                t_y,
                f"{key}: threshold",
                colors[key],
                key,
                dash="dash",
                width=1.0,
                showlegend=False,
            )
    return _figure(
        traces,
        f"{stat} per epoch: median over runs (0/1 indicators: share of runs); dashed: the filter's threshold",
        "time (s)",
        stat,
        log_y,
        height=320,
    )

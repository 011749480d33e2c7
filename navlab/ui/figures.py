"""Plotly figure builders and display tables: pure functions of results (no streamlit).

Rules followed (ECOSYSTEM.md §A3): numpy arrays (float32) rather than lists, so plotly ≥ 6 sends
base64 typed arrays; long series are decimated to about ``MAX_POINTS`` points per trace (by
stride, except outlier marks which keep the per-bucket maximum); Monte Carlo clouds are shown as a
central line plus a quantile band (``fill="tonexty"``), never one trace per run; WebGL
(``Scattergl``) is used only for long series so a page stays under the browser's WebGL-context
cap. Runs whose state became non-finite ("diverged") are excluded from every curve and reported in
the legend; a filter that diverged in every run is listed as diverged, never drawn as NaN.

Every chart reads the same way (STYLE.md "Charts that read"; :func:`readable` applies it to any
figure, also those of the Reproduce, Learn and Real data pages): the legend sits below the plot,
anchored to the bottom of the figure, so it can never cover the title or the data at any width
(plotly adds the legend's height to the margin the axes need); the title sits above the plot area
and pushes the top margin; log axes carry one label per decade (1, 10, 100) or 1-2-5 labels,
never one per minor tick; a reference (the true R(t), the χ² band) is drawn in black, last.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import plotly.graph_objects as go

from navlab import pcrb
from navlab.filters import is_oracle
from navlab.metrics import (
    average_over_runs,
    chi2_band,
    error_quantiles,
    headline_table,
    rmse_per_epoch,
    sq_error,
)
from navlab.params import describe
from navlab.stats import TOO_FEW
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
    """Quantiles over axis 0 ignoring NaN (numpy's default linear method); all-NaN columns give
    NaN without a warning.

    Sorting once (NaN last) and interpolating between order statistics gives exactly
    ``np.nanquantile`` at the cost of one ``np.sort`` (np.nanquantile loops per column, ~10x slower).
    """
    v = np.asarray(v, dtype=float)
    if not np.isnan(v).any():
        return np.quantile(v, list(qs), axis=0)
    s = np.sort(v, axis=0)  # NaN sort last
    n = (~np.isnan(v)).sum(axis=0)
    out = np.full((len(qs), *v.shape[1:]), np.nan)
    top = np.maximum(n - 1, 0)
    for i, q in enumerate(qs):
        pos = q * top
        lo = np.floor(pos).astype(int)
        hi = np.minimum(lo + 1, top)
        frac = pos - lo
        a = np.take_along_axis(s, lo[None], axis=0)[0]
        b = np.take_along_axis(s, hi[None], axis=0)[0]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # inf − inf in a column of infs
            val = a + frac * (b - a)
        out[i] = np.where(n > 0, np.where(frac == 0, a, val), np.nan)
    return out


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
    cls: type | None = None,
    **axes,
) -> None:
    """One decimated line trace from numpy arrays (``cls``: force Scatter or Scattergl)."""
    sl = decimation(x.shape[0])
    cls = cls or _scatter(x[sl].shape[0])
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


# ------------------------------------------------------------------------------ chart layout

# Below the plot, anchored to the bottom of the figure (yref "container"): plotly reserves the
# legend's height in addition to the margin the x axis needs, so at any width and any number of
# legend rows the legend covers neither the title, the data nor the axis labels (a legend anchored
# to the plot area, y = 1.02, overlapped the title as soon as it wrapped to a second row).
LEGEND_BELOW: dict = {
    "orientation": "h",
    "xref": "paper",
    "x": 0.0,
    "xanchor": "left",
    "yref": "container",
    "y": 0.0,
    "yanchor": "bottom",
    "font": {"size": 12},
}
# minimal margins: axis labels, the title and the legend push them out as far as they need
MARGIN: dict = {"l": 10, "r": 10, "t": 10, "b": 10, "pad": 0}
SUBTITLE_FONT: dict = {"size": 12, "color": "#555555"}


def title_layout(text: str, subtitle: str = "") -> dict:
    """A title at the figure's left edge, above the plot area, pushing the top margin (so the
    legend, below, and the data never meet it).

    ``subtitle`` (lines separated by ``<br>``) is written under it in smaller grey type, inside
    the title's text: plotly's own ``title.subtitle`` is left out of the title's automargin and
    ran into the plot area.
    """
    if subtitle:
        style = f"font-size:{SUBTITLE_FONT['size']}px;color:{SUBTITLE_FONT['color']}"
        text += "".join(f"<br><span style='{style}'>{line}</span>" for line in subtitle.split("<br>"))
    t = {
        "text": text,
        "x": 0,
        "xref": "container",  # from the figure's left edge: long y tick labels leave it room
        "xanchor": "left",
        "y": 1,
        "yref": "paper",
        "yanchor": "bottom",
        "automargin": True,
        "pad": {"b": 14, "l": 8},
        "font": {"size": 15},
    }
    return t


def _base_layout(title: str, height: int, subtitle: str = "") -> dict:
    return {
        "title": title_layout(title, subtitle),
        "height": height,
        "margin": dict(MARGIN),
        "hovermode": "x unified",
        "legend": dict(LEGEND_BELOW),
    }


NICE = (1.0, 2.0, 5.0)  # the labelled mantissas of a log axis with fewer than LOG_DECADES decades
LOG_DECADES = 2.0  # from this span on, one label per decade


def _nice_log_values(lo: float, hi: float) -> np.ndarray:
    """The 1-2-5 values (×10ⁿ) inside [lo, hi]."""
    d0, d1 = int(np.floor(np.log10(lo))) - 1, int(np.ceil(np.log10(hi))) + 1
    v = np.array([m * 10.0**d for d in range(d0, d1 + 1) for m in NICE])
    return v[(v >= lo * (1 - 1e-9)) & (v <= hi * (1 + 1e-9))]


def log_axis(lo: float, hi: float, pad: float = 0.04) -> dict:
    """Settings of a log axis showing [lo, hi] (> 0): an explicit range (log10 units, ``pad`` of
    the span added either side) and clean ticks.

    Spanning ``LOG_DECADES`` decades or more: one label per decade (``dtick = 1``: 1, 10, 100);
    less: labels at the 1-2-5 values written in full (plotly's own ``"D2"`` writes a bare "2" and
    "5"), the range widened out to the 1-2-5 values on either side of the data (and one more
    step each side while fewer than three values would be labelled).
    """
    lo, hi = float(lo), float(hi)
    if not (np.isfinite(lo) and np.isfinite(hi) and lo > 0):
        return {"type": "log"}
    hi = max(hi, lo)
    span = float(np.log10(hi / lo))
    if span < LOG_DECADES:
        lo = float(_nice_log_values(lo / 10, lo)[-1])
        hi = float(_nice_log_values(hi, hi * 10)[0])
        while _nice_log_values(lo, hi).size < 3:
            lo = float(_nice_log_values(lo / 10, lo * 0.999)[-1])
            hi = float(_nice_log_values(hi * 1.001, hi * 10)[0])
        span = float(np.log10(hi / lo))
    p = pad * span
    out: dict = {"type": "log", "range": [float(np.log10(lo) - p), float(np.log10(hi) + p)]}
    if span >= LOG_DECADES:
        out.update(tickmode="linear", tick0=0, dtick=1)
    else:
        v = _nice_log_values(lo, hi)
        out.update(tickmode="array", tickvals=v.tolist(), ticktext=[f"{x:g}" for x in v])
    return out


def _trace_values(fig: go.Figure, axis_name: str) -> np.ndarray:
    """Every finite y (or x) value of the traces drawn on layout axis ``axis_name`` (e.g. yaxis2)."""
    letter = axis_name[0]
    ref = letter + axis_name[5:]  # yaxis2 -> y2, yaxis -> y
    vals = []
    for tr in fig.data:
        if getattr(tr, f"{letter}axis", None) not in (ref, None if ref == letter else ref):
            continue
        v = getattr(tr, letter, None)
        if v is None or isinstance(v, str):
            continue
        try:
            a = np.asarray(v, dtype=float).ravel()
        except (TypeError, ValueError):
            continue
        vals.append(a[np.isfinite(a)])
    return np.concatenate(vals) if vals else np.zeros(0)


def clean_log_ticks(fig: go.Figure) -> go.Figure:
    """Give every log axis of ``fig`` clean ticks (:func:`log_axis`): from its explicit range if
    it has one, else from the positive values of the traces drawn on it.
    """
    layout = fig.layout
    for name in [k for k in layout.to_plotly_json() if k[:5] in ("xaxis", "yaxis")]:
        ax = layout[name]
        if ax.type != "log" or ax.tickmode is not None:  # not log, or ticks already chosen
            continue
        if ax.range is not None:
            lo, hi = 10.0 ** np.asarray(ax.range, dtype=float)
            settings = log_axis(lo, hi, pad=0.0)
        else:
            v = _trace_values(fig, name)
            v = v[v > 0]
            if not v.size:
                continue
            settings = log_axis(float(v.min()), float(v.max()))
        fig.update_layout({name: settings})
    return fig


def readable(fig: go.Figure, *, title_above: bool = True) -> go.Figure:
    """Apply navlab's chart conventions to any figure, in place (returned for chaining).

    Legend below the plot (:data:`LEGEND_BELOW`), every axis pushing the margins it needs, the
    title (if any) above the plot area pushing the top margin (``title_above``; leave False for
    a figure whose subplot titles sit where a main title would), clean log ticks.
    """
    fig.update_layout(legend=LEGEND_BELOW, margin=MARGIN)
    fig.update_xaxes(automargin=True)
    fig.update_yaxes(automargin=True)
    text = fig.layout.title.text
    if title_above and text:
        fig.update_layout(title=title_layout(text))
    return clean_log_ticks(fig)


def _figure(
    traces: list,
    title: str,
    x_title: str,
    y_title: str,
    log_y: bool = False,
    height: int = 380,
    subtitle: str = "",
) -> go.Figure:
    """One figure from all traces at once (much cheaper than trace-by-trace ``add_trace``)."""
    layout = _base_layout(title, height, subtitle)
    layout["xaxis"] = {"title": {"text": x_title}, "automargin": True}
    layout["yaxis"] = {"title": {"text": y_title}, "type": "log" if log_y else "linear", "automargin": True}
    return clean_log_ticks(go.Figure(data=traces, layout=layout))


# --------------------------------------------------------------------------- compare page


def error_vs_time(
    res: Results,
    group: str,
    *,
    log_y: bool = False,
    band: tuple[float, float] | None = BAND,
    floor: bool = False,
) -> go.Figure:
    """Per filter: Monte Carlo RMSE per epoch of the ``group`` error norm plus a spread band.

    The band spans the ``band`` quantiles over runs of the per-run error norm. ``floor``: the
    posterior Cramér–Rao bound of the error norm per epoch (:mod:`navlab.pcrb`), a dashed black
    line, where the experiment has one.
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
    b = pcrb.bound(res.spec) if floor and data.has_truth else None
    if b is not None:
        per_epoch = np.sqrt(np.einsum("kii->ki", b.P)[:, list(g.idx)].sum(axis=1)) * g.scale
        add_line(traces, t, per_epoch, "floor (PCRB)", "#000000", "pcrb", dash="dash", width=1.5)
    bt = "" if band is None else f"; band: {int(band[0] * 100)}–{int(band[1] * 100)} % of runs"
    return _figure(
        traces,
        f"{g.label.capitalize()} error over time",
        "time (s)",
        f"{g.label} error ({g.unit})",
        log_y,
        subtitle=f"line: RMSE over {data.B} runs{bt}",
    )


def _r_units(data, channel: int, as_std: bool) -> str:
    u = data.channel_units[channel] if channel < len(data.channel_units) else ""
    if as_std:
        return u
    return f"{u}²" if u else ""


def _positive(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=float).ravel()
    return a[np.isfinite(a) & (a > 0)]


def value_range(values: Sequence[np.ndarray], log: bool) -> tuple[float, float] | None:
    """(lo, hi) spanning ``values`` (positive ones on a log axis; from 0 on a linear one)."""
    v = np.concatenate([_positive(a) if log else np.asarray(a, float).ravel() for a in values] or [[]])
    v = v[np.isfinite(v)]
    if not v.size:
        return None
    return (float(v.min()), float(v.max())) if log else (min(0.0, float(v.min())), float(v.max()))


def y_range_layout(lo: float, hi: float, log: bool) -> dict:
    """A y axis showing [lo, hi]: :func:`log_axis`, or a linear range with 10 % headroom."""
    if log:
        return log_axis(lo, hi)
    top = hi + 0.1 * (hi - lo) if hi > lo else hi + 1.0
    return {"type": "linear", "range": [lo, top]}


def truth_line(traces: list, x: np.ndarray, y: np.ndarray, name: str, width: float = 3.0, **kw) -> None:
    """A reference drawn to be unmistakable: black on a white halo (append it LAST: on top).

    ``kw`` goes to :func:`add_line` (subplot axes, ``cls``).
    """
    add_line(traces, x, y, name, "#ffffff", "truth", width=width + 4, showlegend=False, **kw)
    traces[-1].hoverinfo = "skip"
    add_line(traces, x, y, name, TRUTH_COLOR, "truth", width=width, **kw)


SINGLE_PANEL_MAX = 3  # up to this many filters share one R̂ panel; beyond, one panel each
BAND_MAX = 2  # a shared panel draws spread bands for at most this many R̂ estimates
PANEL_HEIGHT = 230  # px per row of small multiples


def _axis_suffix(i: int) -> str:
    """Plotly's axis suffix of panel ``i``: "" for the first, then "2", "3" and so on."""
    return "" if i == 0 else str(i + 1)


def _rhat_traces(
    res: Results, shown: list[str], channel: int, tf, sym: str, band: tuple[float, float], multi: bool
) -> tuple[list, list[np.ndarray], list[np.ndarray]]:
    """Each shown filter's R̂ (median and band) or R used, in its panel, with the true R(t) in each of
    the small multiples: (traces, the clean quantiles that set the y range, those drawn).
    """
    data, t = res.data, res.data.t
    colors = filter_colors(list(res.runs))
    truth = tf(data.R_schedule[:, channel])
    n_est = sum(res.runs[k].R_hat is not None for k in shown)
    traces: list = []
    clean: list[np.ndarray] = [truth]  # what sets the axis range
    drawn: list[np.ndarray] = []  # what is drawn (to tell whether anything is cut off)
    for i, key in enumerate(shown):
        fr = res.runs[key]
        ax = {"xaxis": f"x{_axis_suffix(i if multi else 0)}", "yaxis": f"y{_axis_suffix(i if multi else 0)}"}
        ok = judged(res, key)
        c = colors[key]
        if not ok.any():
            _diverged_stub(traces, fr, c, **ax)
            continue
        est = fr.R_hat is not None
        v = tf((fr.R_hat if est else fr.R_used)[ok][:, 1:, channel])
        q = nan_quantiles(v, (band[0], 0.5, band[1]))
        dirty = data.outlier_mask[ok][:, 1:, channel]
        qc = nan_quantiles(np.where(dirty, np.nan, v), (band[0], 0.5, band[1])) if dirty.any() else q
        if est:
            clean += [qc[0], qc[2]]
            drawn += [q[0], q[2]]
            if multi or n_est <= BAND_MAX:
                add_band(traces, t[1:], q[0], q[2], c, key, **ax)
            add_line(traces, t[1:], q[1], f"{_legend_name(fr)} {sym}̂", c, key, **ax)
        else:
            clean.append(qc[1])
            drawn.append(q[1])
            add_line(
                traces, t[1:], q[1], f"{_legend_name(fr)} {sym} used", c, key, dash="dash", width=1.5, **ax
            )
        if multi:
            truth_line(traces, t, truth, f"true {sym}(t) (schedule)", **ax)
            if i > 0:
                traces[-1].showlegend = False
    return traces, clean, drawn


def _rhat_y_axis(clean: list[np.ndarray], drawn: list[np.ndarray], log_y: bool, sub: str) -> tuple[dict, str]:
    """The shared y axis (range from the clean entries) and the subtitle, told what is cut off."""
    rng = value_range(clean, log_y)
    yaxis: dict = {"automargin": True, "type": "log" if log_y else "linear"}
    if rng is not None:
        yaxis.update(y_range_layout(*rng, log_y))
        top = 10 ** yaxis["range"][1] if log_y else yaxis["range"][1]
        if any((_positive(d) if log_y else np.asarray(d, float)).max(initial=-np.inf) > top for d in drawn):
            sub += "<br>outlier-epoch values above the top are cut off"
    return yaxis, sub


def _outlier_strip_bar(data, channel: int, strip_ax: str) -> go.Bar:
    """Per epoch, the share of runs with an outlier on ``channel`` (bucketed maxima)."""
    frac = data.outlier_mask[:, :, channel].mean(axis=0)
    idx, fmax = bucket_max(frac)
    return go.Bar(
        x=_f32(data.t[idx]),
        y=_f32(fmax),
        name="outlier epochs",
        marker={"color": "#d62728", "line": {"width": 0}},
        legendgroup="outliers",
        hovertemplate="%{y:.0%} of runs<extra>outliers</extra>",
        xaxis=f"x{strip_ax}",
        yaxis=f"y{strip_ax}",
        legendrank=2000,
    )


def _panel_title(label: str, color: str, x0: float, y1: float, note: str = "") -> dict:
    """A small multiple's title: the filter's label in its colour (and ``note`` after it), above
    the panel's left corner.
    """
    return {
        "text": f"<b>{label}</b>" + (f" — {note}" if note else ""),
        "x": x0,
        "xref": "paper",
        "xanchor": "left",
        "y": y1,
        "yref": "paper",
        "yanchor": "bottom",
        "showarrow": False,
        "font": {"size": 13, "color": color},
    }


def _rhat_grid(
    layout: dict,
    res: Results,
    shown: list[str],
    multi: bool,
    shape: tuple[int, int],
    yaxis: dict,
    y_title: str,
    strip_top: float | None,
    sym: str = "R",
) -> None:
    """The panels' axes into ``layout``: rows × cols top to bottom over the strip (``strip_top``:
    its top as a fraction of the plot height, None without the strip), one time axis; ``sym``:
    R or σ.
    """
    rows, cols = shape
    n_panels = len(shown) if multi else 1
    outlier_strip = strip_top is not None
    strip_ax = str(n_panels + 1) if outlier_strip else ""
    colors = filter_colors(list(res.runs))
    # the grid, top to bottom: panel rows, then the strip; fractions of the plot height
    gap = 0.06 if multi else 0.1
    bottom = (strip_top or 0.0) + (gap if outlier_strip else 0.0)
    row_h = (1.0 - bottom - gap * (rows - 1)) / rows
    hgap = 0.04
    col_w = (1.0 - hgap * (cols - 1)) / cols
    last_row = (n_panels - 1) // cols
    for i in range(n_panels):
        r, cidx = divmod(i, cols)
        y1 = 1.0 - r * (row_h + gap)
        x0 = cidx * (col_w + hgap)
        # x labels under the bottom panel of each column (shared x axes, the strip shows its own)
        below = r == last_row or (r == last_row - 1 and cidx > (n_panels - 1) % cols)
        xa: dict = {"domain": [x0, x0 + col_w], "anchor": f"y{_axis_suffix(i)}", "automargin": True}
        # one time axis, titled: the strip's below them all, else the last panel's (bottom row)
        ref = f"x{strip_ax}" if outlier_strip else f"x{_axis_suffix(n_panels - 1)}"
        if ref != f"x{_axis_suffix(i)}":
            xa["matches"] = ref
        xa["showticklabels"] = below and not outlier_strip
        if xa["showticklabels"]:
            xa["title"] = {"text": "time (s)"}
        ya = {**yaxis, "domain": [y1 - row_h, y1], "anchor": f"x{_axis_suffix(i)}"}
        if i:
            ya["matches"] = "y"
        if cidx == 0:
            ya["title"] = {"text": y_title}
        else:
            ya["showticklabels"] = False
        layout[f"xaxis{_axis_suffix(i)}"] = xa
        layout[f"yaxis{_axis_suffix(i)}"] = ya
        if multi:
            fr = res.runs[shown[i]]  # an oracle's estimate is drawn under the truth: say so
            note = f"{sym}̂ = the true {sym}(t)" if is_oracle(fr.key) else ""
            title = _panel_title(fr.label, colors[shown[i]], x0, y1, note)
            layout.setdefault("annotations", []).append(title)


def _strip_axes(layout: dict, strip_ax: str, strip_top: float) -> None:
    """The outlier strip's axes into ``layout``: under the panels, titled, shares of runs 0–100 %."""
    layout[f"xaxis{strip_ax}"] = {
        "domain": [0.0, 1.0],
        "anchor": f"y{strip_ax}",
        "title": {"text": "time (s)"},
        "automargin": True,
    }
    layout[f"yaxis{strip_ax}"] = {
        "title": {"text": "share of runs"},
        "range": [0, 1],
        "dtick": 0.5,
        "tickformat": ".0%",
        "domain": [0.0, strip_top],
        "anchor": f"x{strip_ax}",
        "automargin": True,
    }


def r_vs_rhat(
    res: Results,
    channel: int,
    *,
    log_y: bool = True,
    as_std: bool = False,
    show_used: bool = True,
    band: tuple[float, float] = BAND,
    outlier_strip: bool = False,
    height: int = 420,
) -> go.Figure:
    """True R(t) of the noise schedule beside each filter's R̂ (median and spread over runs).

    Up to ``SINGLE_PANEL_MAX`` filters share one panel (spread bands only while at most
    ``BAND_MAX`` of them estimate R: more bands overlap into one smear); beyond, small multiples:
    one panel per filter, in the table's order, with shared axes and the true R(t) in every panel,
    so no filter hides another. Log y axis by default (``log_y=False``: linear). The true R(t) is
    drawn last, in black on a white halo. The y range is computed from clean entries only — per
    filter, the band's quantiles over the runs whose measurement on this channel and epoch is not
    an outlier — so a contaminated-epoch variance (the oracle's R̂ *is* the variance drawn,
    outliers included) never sets the scale; what lies beyond is cut off and the subtitle says so.
    Filters without an R̂ show the R they used (dashed median) when ``show_used``. With
    ``outlier_strip`` a lower panel shows, per epoch, the share of runs with an outlier on the
    channel.
    """
    data = res.data
    tf = lambda v: np.sqrt(np.maximum(v, 0.0)) if as_std else v  # noqa: E731
    sym = "σ" if as_std else "R"
    shown = [k for k, fr in res.runs.items() if fr.R_hat is not None or show_used]
    multi = len(shown) > SINGLE_PANEL_MAX
    n_est = sum(res.runs[k].R_hat is not None for k in shown)
    cols = 1 if not multi else (2 if len(shown) == 4 else 3)
    rows = 1 if not multi else -(-len(shown) // cols)
    traces, clean, drawn = _rhat_traces(res, shown, channel, tf, sym, band, multi)
    name = data.channel_names[channel] if channel < len(data.channel_names) else str(channel)
    units = _r_units(data, channel, as_std)
    title = f"Channel {name}: true {sym}(t) vs each filter's {sym}̂"
    sub = f"median, {int(band[0] * 100)}–{int(band[1] * 100)} % band over {data.B} runs"
    if not multi and n_est > BAND_MAX:
        sub = f"median over {data.B} runs (bands left out: {n_est} estimates would overlap)"
    if multi:
        sub += "; one panel per filter, the true " + sym + "(t) in black in each"
    yaxis, sub = _rhat_y_axis(clean, drawn, log_y, sub)
    if not multi:
        truth_line(traces, data.t, tf(data.R_schedule[:, channel]), f"true {sym}(t) (schedule)")
    strip_ax = str((len(shown) if multi else 1) + 1) if outlier_strip else ""
    if outlier_strip:  # drawn first (the truth stays the last trace), listed last in the legend
        traces.insert(0, _outlier_strip_bar(data, channel, strip_ax))
    strip_h = 90 if outlier_strip else 0
    plot_h = (rows * PANEL_HEIGHT if multi else height - 120) + strip_h
    layout = _base_layout(title, plot_h + 120, sub)
    if outlier_strip:
        layout["bargap"] = 0
    strip_top = strip_h / plot_h if outlier_strip else None
    y_title = f"{sym} ({units})" if units else sym
    _rhat_grid(layout, res, shown, multi, (rows, cols), yaxis, y_title, strip_top, sym)
    if outlier_strip:
        _strip_axes(layout, strip_ax, strip_top)
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
    return _figure(
        traces,
        "Consistency: average NIS vs its χ² band",
        "time (s)",
        "ANIS (dimensionless)",
        log_y,
        subtitle="ANIS: NIS averaged over the runs at each epoch",
    )


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
        "nlpd": "NLPD (nats)",
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
        "nlpd": "NLPD",
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
    bars = False  # any point with an interval (none below stats.MIN_RUNS runs)
    for key, d in df.groupby("filter", sort=False):
        d = d.sort_values("value")
        y = d["metric_value"].to_numpy(dtype=float)
        err = None
        if {"ci_lo", "ci_hi"} <= set(d.columns):
            lo, hi = d["ci_lo"].to_numpy(dtype=float), d["ci_hi"].to_numpy(dtype=float)
            if np.isfinite(lo).any():
                bars = True
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
        traces,
        f"{y_label} against {x_label}",
        x_label,
        y_label,
        log_y,
        subtitle="bars: 95 % intervals over runs" if bars else f"no interval bars: {TOO_FEW}",
    )
    fig.update_layout(hovermode="closest", xaxis_type="log" if log_x else "linear")
    return clean_log_ticks(fig)


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
        title=title_layout(f"{y_label}: filters × {x_label}"),
        height=140 + 40 * len(piv.index),
        margin=MARGIN,
    )
    fig.update_xaxes(title_text=x_label, type="category", automargin=True)
    fig.update_yaxes(automargin=True)
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
    fig.update_layout(title=title_layout(title), height=160 + 36 * len(piv.index), margin=MARGIN)
    fig.update_xaxes(title_text=x_label, type="category", automargin=True)
    fig.update_yaxes(title_text=y_label, type="category", automargin=True)
    return fig


def _landscape_1d(t0: pd.DataFrame, dim, tuned: float, runs: int, label: str) -> go.Figure:
    """The objective over one parameter: the candidates as a line, the default and the tuned value marked."""
    n = dim.name
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
                x=[dim.default],
                y=[float(d0.objective.iloc[0])],
                mode="markers",
                name="default",
                marker={"size": 13, "symbol": "diamond-open", "color": TRUTH_COLOR},
            )
        )
    hit = t0[np.isclose(t0[f"p.{n}"].to_numpy(dtype=float), tuned)]
    if len(hit):
        traces.append(
            go.Scatter(
                x=[tuned],
                y=[float(hit.objective.iloc[0])],
                mode="markers",
                name="tuned",
                marker={"size": 15, "symbol": "star", "color": "#d62728"},
            )
        )
    fig = _figure(traces, f"{label}: objective over {n}", n, "objective (training seeds)")
    fig.update_xaxes(type="log" if dim.scale == "log" else "linear", range=None)
    return clean_log_ticks(fig)


def _landscape_2d(t0: pd.DataFrame, da, db, tuned: dict, runs: int, label: str) -> go.Figure:
    """The objective over two parameters: candidates coloured by it, default and tuned value marked."""
    a, b = da.name, db.name
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
            x=[da.default],
            y=[db.default],
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
    fig.update_xaxes(type="log" if da.scale == "log" else "linear")
    fig.update_yaxes(type="log" if db.scale == "log" else "linear")
    return clean_log_ticks(fig)


def tune_landscape(
    trials: pd.DataFrame, dims: Sequence, names: Sequence[str], tuned: dict, label: str
) -> go.Figure:
    """A filter's objective over its one or two most influential parameters: every candidate of
    the first successive-halving rung (all on the same training runs), the default and the
    tuned value marked. ``trials`` is :func:`navlab.tune.trials_frame` for this filter.
    """
    by = {d.name: d for d in dims}
    shown = [by[n] for n in names]
    t0 = trials[(trials.rung == 0) & np.isfinite(trials.objective)]
    runs = int(t0.runs.iloc[0]) if len(t0) else 0
    if len(names) == 1:
        return _landscape_1d(t0, shown[0], tuned[names[0]], runs, label)
    return _landscape_2d(t0, shown[0], shown[1], tuned, runs, label)


@functools.lru_cache(maxsize=64)
def _channels(scenario: str, scenario_json: str) -> tuple[tuple[str, ...], tuple[str, ...], int]:
    """(channel names, units, m) of a scenario configuration, from a 3-epoch probe (cached)."""
    from navlab.noise import make_outliers, make_schedule
    from navlab.scenarios import scenario_registry

    cls = scenario_registry()[scenario]
    params = json.loads(scenario_json)
    if cls.simulated and "epochs" in {f["name"] for f in describe(cls.Params)}:
        params = {**params, "epochs": 3}
    data = cls(params).simulate(make_schedule("constant"), make_outliers("none"), [0], 0)
    m = int(data.z.shape[2])
    names = tuple(data.channel_names[:m]) + tuple(str(i) for i in range(len(data.channel_names), m))
    units = tuple(data.channel_units[:m]) + ("",) * max(0, m - len(data.channel_units))
    return names, units, m


MAX_PREVIEW_CHANNELS = 12  # beyond this the preview draws the channels' envelope


def schedule_preview(spec, height: int = 240) -> go.Figure:
    """The chosen noise schedule's true σ(t)/σ_nominal over the run, one line per measurement
    channel (cheap; shown before a run). Channels with the same factor share one line (named
    after all of them); more than ``MAX_PREVIEW_CHANNELS`` distinct lines are drawn as their
    lowest and highest factor.

    It also makes the browser load plotly.js while the user is still configuring.
    """
    from navlab.experiment import plan

    p = plan(spec)
    K = p.scenario.epochs or 100
    try:
        sp = {f.name: getattr(p.scenario.params, f.name) for f in dataclasses.fields(p.scenario.params)}
        names, _units, m = _channels(spec.scenario, json.dumps(sp, sort_keys=True, default=list))
    except Exception:  # the preview must never stop the page: one curve, as before
        names, m = ("all channels",), 1
    f = p.schedule.std(np.ones(m), K)  # (K+1, m)
    k = np.arange(K + 1, dtype=float)
    lines: dict[bytes, list[int]] = {}
    for ch in range(m):
        lines.setdefault(np.round(f[:, ch], 9).tobytes(), []).append(ch)
    traces: list = []
    dashes = ("solid", "dash", "dot", "dashdot", "longdash", "longdashdot")
    if len(lines) > MAX_PREVIEW_CHANNELS:
        add_line(traces, k, f.min(axis=1), "lowest channel", TRUTH_COLOR, "lo", width=2)
        add_line(traces, k, f.max(axis=1), "highest channel", TRUTH_COLOR, "hi", dash="dash", width=2)
    else:
        for i, chans in enumerate(lines.values()):
            label = ", ".join(names[c] for c in chans[:6]) + (" …" if len(chans) > 6 else "")
            add_line(
                traces,
                k,
                f[:, chans[0]],
                f"channel {label}" if len(chans) == 1 else f"channels {label}",
                TRUTH_COLOR if i == 0 else ("#6e7781", "#d62728", "#1f77b4", "#2ca02c")[i % 4],
                f"ch{i}",
                dash=dashes[i % len(dashes)],
                width=2,
            )
    fig = _figure(
        traces,
        f"Noise schedule '{spec.noise_schedule}': true σ(t) relative to the σ the filters assume",
        "epoch",
        "σ / σ nominal",
        height=height,
        subtitle=f"{m} measurement channel" + ("s" if m != 1 else ""),
    )
    fig.update_layout(hovermode="closest")
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


# y-axis titles (with units) of the per-step statistics the filters report
STAT_AXIS = {
    "nis": "NIS (dimensionless)",
    "gamma": "χ² test statistic γ (dimensionless)",
    "fading": "fading factor (dimensionless)",
    "rejected": "share of runs rejecting",
    "replaced": "share of runs replacing",
    "nn_trained": "share of runs with a trained network",
    "skf_flag": "share of runs (parallel SKF flag)",
    "improved_rae": "share of runs (improved RAE)",
    "run_len": "consecutive replacements (epochs)",
    "vb_iters": "VB iterations (count)",
    "vb_delta": "last VB change (relative)",
    "huber_passes": "Huber passes (count)",
    "alpha": "VB shape α (dimensionless)",
    "lambda": "λ (dimensionless)",
    "d_k": "Sage–Husa weight d_k (dimensionless)",
    "nu_tilde": "normalised innovation ν̃ (σ)",
    "P_scale": "tr P (state units², mixed)",
}


def internals_vs_time(res: Results, stat: str, channel: int = 0, log_y: bool = False) -> go.Figure:
    """Per filter, the median over runs of statistic ``stat`` per epoch (for 0/1 indicators such as
    ``rejected`` or ``replaced``: the share of runs), with ``<stat>_threshold`` dashed if reported.
    """
    data = res.data
    m = data.z.shape[2]
    colors = filter_colors(list(res.runs))
    traces: list = []
    dashed = False
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
            dashed = True
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
        f"{stat} per epoch",
        "time (s)",
        STAT_AXIS.get(stat, f"{stat} (as the filter reports it)"),
        log_y,
        height=340,
        subtitle="median over runs (0/1 indicators: share of runs)"
        + ("<br>dashed: the filter's threshold" if dashed else ""),
    )

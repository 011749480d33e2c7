"""The Reproduce page's building blocks: a registered reproduction judged over many seeds, cached
by its configuration, and its verdicts, readings and curves as tables and figures.

Pure helpers (no streamlit calls): :func:`claims_figure`, :func:`curve_figure`,
:func:`style_verdicts`, :func:`readings_table`. :func:`cached_run` is the cached runner the page
calls.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable

import numpy as np
import pandas as pd
import plotly.graph_objects as go

from navlab import stats as S
from navlab.reproduce import REPRODUCTIONS, Outcome
from navlab.reproduce.engine import TOLERANCE
from navlab.reproduce.report import verdict_table
from navlab.ui.colors import PALETTE, TRUTH_COLOR, filter_colors

CONFIG = {"displaylogo": False}
VERDICT_COLORS = {"reproduced": "#d9f2d9", "inconclusive": "#fff1c2", "contradicted": "#f8d0d0"}
MAX_CURVE_POINTS = 2000
APP_SEEDS = 5  # the app's default number of seeds (the CLI's is 20): a first look in seconds


def style_verdicts(o: Outcome):
    """The verdict table (one row per claim) with the verdict cell coloured."""
    t = verdict_table(o)
    return t.style.map(lambda v: f"background-color: {VERDICT_COLORS.get(v, '')}", subset=["verdict"])


def readings_table(o: Outcome) -> pd.DataFrame:
    """The detailed readings with three significant figures and the paper's names."""
    r = o.readings.copy()
    for c in ("value", "ci_lo", "ci_hi", "seed_mean", "range_lo", "range_hi", "paper"):
        r[c] = [S.sig3(v) for v in r[c]]
    return r.drop(columns=["filter"]).rename(columns={"label": "filter", "value": "pooled"})


def claims_figure(o: Outcome) -> go.Figure:
    """Each number, bound and margin claim: navlab's mean over seeds relative to the paper's value
    (%), with its 95 % interval (thick) and the per-seed range (thin); the ±20 % band shaded.
    """
    v = o.verdicts
    v = v[v["kind"].isin(["number", "bound", "margin"]) & np.isfinite(v["mean"].astype(float))]
    v = v.iloc[::-1]
    paper = v["paper"].astype(float).to_numpy()
    rel = lambda col: 100 * (v[col].astype(float).to_numpy() - paper) / np.abs(paper)  # noqa: E731
    y = v["text"].to_numpy()
    colors = [{"reproduced": "#2ca02c", "contradicted": "#d62728"}.get(x, "#f0a500") for x in v["verdict"]]
    fig = go.Figure()
    fig.add_vrect(x0=-100 * TOLERANCE, x1=100 * TOLERANCE, fillcolor="rgba(44,160,44,0.08)", line_width=0)
    fig.add_vline(x=0, line={"color": TRUTH_COLOR, "width": 1})
    m = rel("mean")
    fig.add_trace(
        go.Scatter(
            x=m,
            y=y,
            mode="markers",
            marker={"color": colors, "size": 10},
            name="mean over seeds",
            error_x={
                "type": "data",
                "symmetric": False,
                "array": rel("range_hi") - m,
                "arrayminus": m - rel("range_lo"),
                "thickness": 1,
                "width": 0,
                "color": "#999999",
            },
            hovertemplate="%{y}<br>%{x:+.1f} % from the paper<extra></extra>",
        )
    )
    fig.add_trace(
        go.Scatter(
            x=m,
            y=y,
            mode="markers",
            marker={"color": colors, "size": 1},
            showlegend=False,
            error_x={
                "type": "data",
                "symmetric": False,
                "array": rel("ci_hi") - m,
                "arrayminus": m - rel("ci_lo"),
                "thickness": 4,
                "width": 0,
            },
            hoverinfo="skip",
        )
    )
    fig.update_layout(
        title={
            "text": "navlab relative to the paper (%): mean over seeds, 95 % interval (thick), per-seed "
            "range (thin); shaded ±20 %",
            "x": 0,
            "font": {"size": 14},
        },
        xaxis_title="(navlab − paper) / |paper|  (%)",
        height=max(240, 34 * len(v) + 120),
        margin={"l": 10, "r": 20, "t": 50, "b": 45},
        showlegend=False,
    )
    return fig


def curve_figure(o: Outcome, name: str) -> go.Figure:
    """One curve table (per-epoch RMSE of every filter), in the filters' colours and names."""
    df = o.curves[name]
    rep = o.reproduction
    colors = filter_colors()
    fig = go.Figure()
    t = df["t_s"].to_numpy(dtype=float)
    step = max(1, int(np.ceil(len(t) / MAX_CURVE_POINTS)))
    unit = ""
    for i, col in enumerate(c for c in df.columns if c != "t_s"):
        key, _, rest = col.partition("_rmse_")
        unit = rest.rsplit("_", 1)[-1].replace("p", "/") if "_" in rest else ""
        fig.add_trace(
            go.Scatter(
                x=t[::step].astype(np.float32),
                y=df[col].to_numpy(dtype=float)[::step].astype(np.float32),
                mode="lines",
                name=rep.name(key),
                line={"color": colors.get(key, PALETTE[i % len(PALETTE)])},
            )
        )
    fig.update_layout(
        title={
            "text": f"{name.removesuffix('.csv')}: per-epoch RMSE over the judged runs of all seeds",
            "x": 0,
            "font": {"size": 14},
        },
        xaxis_title="time (s)",
        yaxis_title=f"RMSE ({unit})" if unit else "RMSE",
        height=380,
        legend={"orientation": "h", "yanchor": "top", "y": -0.18, "x": 0},
        margin={"l": 60, "r": 20, "t": 50, "b": 90},
    )
    return fig


# A small process-wide LRU cache instead of st.cache_data: the progress callback draws on a bar
# created outside the function, which st.cache_data cannot replay on a cache hit.
_CACHE: OrderedDict[tuple[str, int, int, int], Outcome] = OrderedDict()
_CACHE_LOCK = threading.Lock()
CACHE_ENTRIES = 16


def is_cached(key: str, runs: int, seeds: int, seed: int) -> bool:
    with _CACHE_LOCK:
        return (key, runs, seeds, seed) in _CACHE


def cached_run(
    key: str, runs: int, seeds: int, seed: int, on_progress: Callable[[int, int], None] | None = None
) -> Outcome:
    """The reproduction's :class:`Outcome`, cached by (reproduction, runs, seeds, seed)."""
    ck = (key, runs, seeds, seed)
    with _CACHE_LOCK:
        if ck in _CACHE:
            _CACHE.move_to_end(ck)
            return _CACHE[ck]
    value = REPRODUCTIONS[key].evaluate(runs=runs, seeds=seeds, seed=seed, on_progress=on_progress)
    with _CACHE_LOCK:
        _CACHE[ck] = value
        _CACHE.move_to_end(ck)
        while len(_CACHE) > CACHE_ENTRIES:
            _CACHE.popitem(last=False)
    return value

"""One Monte Carlo run, filter by filter: the single-run view of Compare.

The averages of Compare hide how a filter reacts; a class needs ONE run: the truth, the
measurements with their outliers marked, each chosen filter's estimate with its ±2σ bounds, its
weights and flags and its R̂ along time. :func:`single_run_figure` draws that (pure); the figure
carries its own play button and time slider (Plotly frames that lift a veil off the future, so
playing costs the server nothing). :func:`most_different_run` picks the run where the filters'
errors differ most; :func:`render` is the Streamlit panel.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from navlab.metrics import sq_error
from navlab.ui.colors import TRUTH_COLOR, filter_colors, rgba
from navlab.ui.figures import judged, readable

if TYPE_CHECKING:
    from navlab.experiment import Results

F32 = np.float32
MAX_FRAMES = 60  # play-button steps (each frame is a few shapes: cheap)
MAX_POINTS = 3000  # epochs drawn per line (a run of 10⁵ epochs was a figure of megabytes)
OUTLIER_COLOR = "#d62728"


def per_run_rmse(res: Results, group: str) -> dict[str, np.ndarray]:
    """Per filter: each run's RMSE of ``group`` over the analysis window (NaN where the run is
    not judged for that filter, e.g. it diverged).
    """
    d = res.data
    W = np.asarray(d.window, dtype=bool)
    out = {}
    for key, fr in res.runs.items():
        sq = sq_error(fr.x, d.x_true, d.groups[group])[:, W]
        with np.errstate(all="ignore"):
            r = np.sqrt(np.nanmean(sq, axis=1))
        r[~judged(res, key)] = np.nan
        out[key] = r
    return out


def most_different_run(res: Results, group: str, filters: list[str] | None = None) -> int:
    """The run (index into the batch) where the chosen filters' RMSEs differ most (largest
    best-to-worst gap among the filters judged on it); 0 if no run has two judged filters.
    """
    rm = per_run_rmse(res, group)
    keys = [k for k in (filters or list(res.runs)) if k in rm]
    if len(keys) < 2:
        return 0
    a = np.stack([rm[k] for k in keys])  # (filters, runs)
    ok = np.isfinite(a).sum(axis=0) >= 2
    if not ok.any():
        return 0
    gap = np.full(a.shape[1], -np.inf)  # runs judged for fewer than two filters never win
    gap[ok] = np.nanmax(a[:, ok], axis=0) - np.nanmin(a[:, ok], axis=0)
    return int(np.argmax(gap))


def measured_channel(res: Results, state: int) -> int | None:
    """The measurement channel that measures state ``state`` directly (H row = unit vector), if
    the model is linear with such a row; else None.
    """
    H = getattr(res.data.model, "H_", None)
    if H is None:
        return None
    H = np.asarray(H, dtype=float)
    if H.ndim != 2:
        return None
    for ch in range(H.shape[0]):
        row = H[ch]
        if np.count_nonzero(row) == 1 and row[state] == 1.0:
            return ch
    return None


def shown_epochs(n: int, max_points: int = MAX_POINTS) -> np.ndarray:
    """The epochs a line of an ``n``-epoch run is drawn at: all of them up to ``max_points``, else
    about ``max_points`` evenly spaced ones (first and last included). Marker traces (outliers,
    flagged epochs) keep every epoch they mark.
    """
    if n <= max_points:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(int))


def _a(v: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(v, dtype=F32)


def _estimate_traces(fr, key: str, c: str, run: int, state: int, t: np.ndarray, ref: np.ndarray) -> list:
    """Panel 1 for one filter: its estimate of ``state`` minus ``ref`` with a ±2σ (√P) band."""
    ix = shown_epochs(t.size)
    x = (fr.x[run, :, state] - ref)[ix]
    s2 = (2.0 * np.sqrt(np.maximum(fr.P_diag[run, :, state], 0.0)))[ix]
    edge = {"mode": "lines", "line": {"width": 0, "color": c}, "showlegend": False, "legendgroup": key}
    return [
        go.Scatter(x=_a(t[ix]), y=_a(x + s2), hoverinfo="skip", **edge),
        go.Scatter(
            x=_a(t[ix]), y=_a(x - s2), fill="tonexty", fillcolor=rgba(c, 0.15), hoverinfo="skip", **edge
        ),
        go.Scatter(
            x=_a(t[ix]),
            y=_a(x),
            mode="lines",
            name=_run_label(fr, run),
            line={"color": c, "width": 2},
            legendgroup=key,
        ),
    ]


def _run_label(fr, run: int) -> str:
    """The filter's label, saying so when it diverged in this run."""
    return fr.label + (" (diverged in this run)" if fr.diverged[run] else "")


def _weight_traces(fr, key: str, c: str, run: int, channel: int, t: np.ndarray) -> list:
    """Panel 2 for one filter: its weight on ``channel`` from the first update on, × where flagged."""
    ix1 = shown_epochs(t.size)
    ix1 = ix1[ix1 > 0]
    w = fr.weights[run, :, channel]
    out = [
        go.Scatter(
            x=_a(t[ix1]),
            y=_a(w[ix1]),
            mode="lines",
            name=_run_label(fr, run),
            line={"color": c, "width": 1.5, "shape": "hv"},
            legendgroup=key,
            showlegend=False,
        )
    ]
    flagged = fr.flags[run, :, channel] > 0
    if flagged[1:].any():
        k = np.flatnonzero(flagged)
        k = k[k > 0]
        out.append(
            go.Scatter(
                x=_a(t[k]),
                y=_a(w[k]),
                mode="markers",
                name=f"{fr.label}: flagged",
                marker={"color": c, "symbol": "x", "size": 8},
                legendgroup=key,
                showlegend=False,
            )
        )
    return out


def _r_trace(fr, key: str, c: str, run: int, channel: int, t: np.ndarray) -> go.Scatter:
    """Panel 3 for one filter: its R̂ on ``channel`` (dashed: the R it used, without an R̂)."""
    ix1 = shown_epochs(t.size)
    ix1 = ix1[ix1 > 0]
    est = fr.R_hat is not None
    return go.Scatter(
        x=_a(t[ix1]),
        y=_a((fr.R_hat if est else fr.R_used)[run, ix1, channel]),
        mode="lines",
        name=f"{fr.label} {'R̂' if est else 'R used'}",
        line={"color": c, "width": 2 if est else 1.2, "dash": None if est else "dash"},
        legendgroup=key,
        showlegend=False,
    )


def _measurement_traces(d, run: int, mch: int, t: np.ndarray, ref: np.ndarray) -> list:
    """Panel 1: the measurements of channel ``mch`` minus ``ref`` (clean ones decimated; outliers: red ×)."""
    drawn = np.zeros(t.size, bool)
    drawn[shown_epochs(t.size)] = True
    z = d.z[run, :, mch] - ref
    bad = d.outlier_mask[run, :, mch] & np.isfinite(z)
    clean = ~d.outlier_mask[run, :, mch] & np.isfinite(z) & drawn
    out = []
    for sel, name, marker, always in (
        (clean, "measurement", {"color": "#6e7781", "symbol": "circle-open", "size": 6}, True),
        (bad, "outlier (measurement)", {"color": OUTLIER_COLOR, "symbol": "x", "size": 10}, False),
    ):
        if always or sel.any():
            out.append(go.Scatter(x=_a(t[sel]), y=_a(z[sel]), mode="markers", name=name, marker=marker))
    return out


def _truth_traces(
    d, run: int, state: int, channel: int, t: np.ndarray, ref: np.ndarray, relative: bool
) -> list:
    """The truth of ``state`` minus ``ref`` (panel 1) and the true R(t) of ``channel`` (panel 3)."""
    ix = shown_epochs(t.size)
    truth = d.x_true[run, :, state]
    line = {"color": TRUTH_COLOR, "width": 2.5}
    return [
        (
            go.Scatter(
                x=_a(t[ix]),
                y=_a((truth - ref)[ix]),
                mode="lines",
                name="truth" + (" (the zero line)" if relative else ""),
                line=line,
            ),
            1,
        ),
        (
            go.Scatter(
                x=_a(t[ix]),
                y=_a(d.R_schedule[ix, channel]),
                mode="lines",
                name="true R(t)",
                line=line,
                showlegend=False,
            ),
            3,
        ),
    ]


def _outlier_tick_traces(d, run: int, channel: int, t: np.ndarray, in_legend: bool) -> list:
    """Red ticks at the outlier epochs of ``channel`` on the time axes of panels 2 and 3."""
    out = d.outlier_mask[run, :, channel]
    if not out.any():
        return []
    k = np.flatnonzero(out)
    return [
        (
            go.Scatter(
                x=_a(t[k]),
                y=np.zeros(k.size, F32) if row == 2 else _a(d.R_schedule[k, channel]),
                mode="markers",
                name="outlier epoch",
                marker={"color": OUTLIER_COLOR, "symbol": "triangle-up", "size": 9},
                legendgroup="outlier",
                showlegend=row == 2 and in_legend,
            ),
            row,
        )
        for row in (2, 3)
    ]


def _names(d, state: int, channel: int) -> tuple[str, str, str]:
    """The state's name, the channel's name and the channel's unit ("" if not given)."""
    sname = d.state_names[state] if state < len(d.state_names) else str(state)
    cname = d.channel_names[channel] if channel < len(d.channel_names) else str(channel)
    cunit = d.channel_units[channel] if channel < len(d.channel_units) else ""
    return sname, cname, cunit


def _state_unit(d, state: int) -> str:
    """The unit of state ``state`` as plotted (its metric group's, when that group shows it
    unscaled; "" when no group names it).
    """
    return next((g.unit for g in d.groups.values() if state in g.idx and g.scale == 1.0 and g.unit), "")


def _three_panels(d, state: int, channel: int, mch: int | None, relative: bool) -> go.Figure:
    """The empty figure: estimate (1), weight (2) and R (3) over a shared time axis, with titles."""
    sname, cname, _ = _names(d, state, channel)
    return make_subplots(
        rows=3,
        cols=1,
        shared_xaxes=True,
        vertical_spacing=0.07,
        row_heights=(0.5, 0.22, 0.28),
        subplot_titles=(
            f"state {sname}{' minus the truth' if relative else ''}: each filter's estimate ± 2σ"
            + (f", measurements of channel {d.channel_names[mch]}" if mch is not None else ""),
            f"weight on channel {cname} (1 = untouched; ×: flagged)",
            f"R on channel {cname}: each filter's R̂ (dashed: the R it used) and the true R(t)",
        ),
    )


def _label_axes(fig: go.Figure, d, state: int, channel: int, log_r: bool, relative: bool) -> None:
    """Axis titles of the three panels (R on a log axis with ``log_r``)."""
    sname, _, cunit = _names(d, state, channel)
    unit = f" ({cunit})" if cunit else ""
    su = _state_unit(d, state)
    sunit = f" ({su})" if su else ""
    fig.update_yaxes(title_text=(f"{sname} − truth" if relative else sname) + sunit, row=1, col=1)
    fig.update_yaxes(title_text="weight", range=[-0.08, 1.12], row=2, col=1)
    fig.update_yaxes(
        title_text=f"R{unit[:-1]}²)" if cunit else "R", type="log" if log_r else "linear", row=3, col=1
    )
    fig.update_xaxes(title_text="time (s)", row=3, col=1)


def single_run_figure(
    res: Results,
    run: int,
    filters: list[str],
    state: int,
    channel: int,
    *,
    log_r: bool = True,
    frames: bool = True,
    relative: bool = True,
) -> go.Figure:
    """One run (batch index ``run``) of the chosen ``filters`` in three panels over time.


    1 the truth of state ``state`` (black), each filter's estimate with ±2σ (√P) bounds, and the
      measurements of the channel that measures this state (outliers: red ×);
    2 each filter's weight on channel ``channel`` (1 = untouched; × where the filter flagged it);
    3 each filter's R̂ on ``channel`` (R used, dashed, for filters without R̂) against the true R(t).

    Outlier epochs of the channel are marked by red ticks on the time axis of every panel. With
    ``frames`` a play button and a time slider reveal the run epoch by epoch. ``relative``: panel 1
    shows everything minus the truth (the truth is the zero line), so an estimate's error and its
    bounds are readable whatever the size of the state (a position of 10⁵ m). Lines are drawn at
    :func:`shown_epochs` (at most ``MAX_POINTS``); every outlier and flagged epoch keeps its mark.
    """
    d = res.data
    t = np.asarray(d.t, dtype=float)
    colors = filter_colors(list(res.runs))
    mch = measured_channel(res, state)
    truth = d.x_true[run, :, state]
    ref = truth if relative else np.zeros_like(truth)
    fig = _three_panels(d, state, channel, mch, relative)
    traces: list[tuple[Any, int]] = []
    for key in filters:
        fr, c = res.runs[key], colors[key]
        traces += [(tr, 1) for tr in _estimate_traces(fr, key, c, run, state, t, ref)]
        traces += [(tr, 2) for tr in _weight_traces(fr, key, c, run, channel, t)]
        traces.append((_r_trace(fr, key, c, run, channel, t), 3))
    if mch is not None:
        traces += [(tr, 1) for tr in _measurement_traces(d, run, mch, t, ref)]
    traces += _truth_traces(d, run, state, channel, t, ref, relative)
    traces += _outlier_tick_traces(d, run, channel, t, in_legend=mch is None)
    for tr, row in traces:
        fig.add_trace(tr, row=row, col=1)
    _label_axes(fig, d, state, channel, log_r, relative)
    r_idx = int(d.runs[run]) if run < len(d.runs) else run
    fig.update_layout(
        height=820,
        hovermode="x unified",
        title={
            "text": f"Monte Carlo run {r_idx}, seed {res.spec.seed}: {len(filters)} filters on the same data"
        },
    )
    readable(fig)
    if frames and t.size > 2:
        add_player(fig, t)
    return fig


def _veil_and_cursor(tk: float, t_end: float, pad: float) -> list[dict]:
    """Layout shapes at time ``tk``: a white veil over the later epochs and an orange cursor line."""
    return [
        {
            "type": "rect",
            "xref": "x",
            "yref": "paper",
            "x0": tk + pad,
            "x1": t_end + pad,
            "y0": 0,
            "y1": 1,
            "fillcolor": "rgba(255,255,255,0.82)",
            "line": {"width": 0},
            "layer": "above",
        },
        {
            "type": "line",
            "xref": "x",
            "yref": "paper",
            "x0": tk,
            "x1": tk,
            "y0": 0,
            "y1": 1,
            "line": {"color": "#f0a500", "width": 2},
        },
    ]


def _play_buttons(names: list[str]) -> dict:
    """The ▶ play / ❚❚ pause buttons that animate the frames ``names``."""
    return {
        "type": "buttons",
        "direction": "left",
        "x": 0.0,
        "xanchor": "left",
        "y": 1.07,
        "yanchor": "bottom",
        "pad": {"t": 0, "r": 4},
        "showactive": False,
        "buttons": [
            {
                "label": "▶ play",
                "method": "animate",
                "args": [
                    names,
                    {
                        "frame": {"duration": 120, "redraw": True},
                        "fromcurrent": False,
                        "mode": "immediate",
                    },
                ],
            },
            {
                "label": "❚❚ pause",
                "method": "animate",
                "args": [[None], {"frame": {"duration": 0, "redraw": False}, "mode": "immediate"}],
            },
        ],
    }


def _time_slider(names: list[str]) -> dict:
    """A slider with one step a frame, at the last one."""
    return {
        "active": len(names) - 1,
        "x": 0.16,
        "len": 0.84,
        "y": 1.07,
        "yanchor": "bottom",
        "pad": {"t": 0, "b": 0},
        "currentvalue": {"prefix": "epoch ", "font": {"size": 12}},
        "steps": [
            {
                "label": name,
                "method": "animate",
                "args": [
                    [name],
                    {"frame": {"duration": 0, "redraw": True}, "mode": "immediate"},
                ],
            }
            for name in names
        ],
    }


def add_player(fig: go.Figure, t: np.ndarray) -> None:
    """A play button and a time slider: frames that move a cursor and lift a white veil off the
    epochs up to it (layout shapes only, so a frame is a few bytes and the data is sent once).
    """
    K = t.size - 1
    steps = np.unique(np.linspace(1, K, min(MAX_FRAMES, K)).round().astype(int))
    t_end = float(t[-1])
    pad = 0.5 * float(np.median(np.diff(t))) if t.size > 1 else 0.5
    names = [str(int(k)) for k in steps]
    fig.frames = [
        go.Frame(name=str(int(k)), layout={"shapes": _veil_and_cursor(float(t[int(k)]), t_end, pad)})
        for k in steps
    ]
    fig.update_layout(
        shapes=_veil_and_cursor(float(t[int(steps[-1])]), t_end, pad),
        updatemenus=[_play_buttons(names)],
        sliders=[_time_slider(names)],
    )
    # the title at the top of the figure, the controls between it and the first panel
    fig.update_layout(
        margin_t=190,
        title={"y": 0.995, "yref": "container", "yanchor": "top", "automargin": False},
    )


# --------------------------------------------------------------------------- the panel


def render(res: Results, page: str, group: str) -> None:
    """Draw the single-run panel (Streamlit): run chooser, filters, state, channel, figure."""
    import streamlit as st

    from navlab.ui.views import channel_label, chart

    d = res.data
    keys = list(res.runs)
    st.markdown("##### One run, filter by filter")
    c1, c2, c3, c4 = st.columns([2, 3, 2, 2])
    how = c1.radio(
        "Run",
        ["where the filters differ most", "run number"],
        key=f"{page}_one_how",
        help="the run whose best-to-worst RMSE gap (headline error) is largest, or a run you pick",
    )
    chosen = c2.multiselect(
        "Filters",
        keys,
        default=keys[: min(4, len(keys))],
        format_func=lambda k: res.runs[k].label,
        key=f"{page}_one_flt",
    )
    if not chosen:
        st.info("Choose at least one filter for the single-run view.")
        return
    if how == "run number":
        run = int(
            c1.number_input(
                "Monte Carlo run (0 … B−1)",
                0,
                d.B - 1,
                0,
                key=f"{page}_one_run",
                help="index into this experiment's runs",
            )
        )
    else:
        run = most_different_run(res, group, chosen)
    mapped = [s for s in range(len(d.state_names)) if measured_channel(res, s) is not None]
    state = c3.selectbox(
        "State",
        list(range(len(d.state_names))),
        index=mapped[0] if mapped else 0,
        format_func=lambda s: d.state_names[s],
        key=f"{page}_one_state",
    )
    mch = measured_channel(res, state)
    m = d.z.shape[2]
    channel = c4.selectbox(
        "Channel (weights, R̂)",
        list(range(m)),
        index=mch if mch is not None else 0,
        format_func=lambda ch: channel_label(res, ch),
        key=f"{page}_one_ch",
    )
    rm = per_run_rmse(res, group)
    g = d.groups[group]
    # the batch index only where it differs from the run's number (a resumed or filtered batch)
    where = f" (batch index {run})" if int(d.runs[run]) != run else ""
    st.caption(
        f"Run {int(d.runs[run])}{where} · RMSE {g.label} in this run: "
        + ", ".join(
            f"{res.runs[k].label} {rm[k][run]:.3g} {g.unit}" for k in chosen if np.isfinite(rm[k][run])
        )
        + " · ▶ play / the slider above the chart reveal the run epoch by epoch"
    )
    chart(
        st,
        single_run_figure(res, run, chosen, state, channel),
        "one Monte Carlo run: truth, measurements, estimates with 2-sigma bounds, weights, R-hat",
        key=f"{page}_one_fig",
        name=f"run-{int(d.runs[run])}",
    )

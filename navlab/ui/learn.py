"""The Learn page's building blocks: step-through figures (pure) and Streamlit renderers.

The maths lives in :mod:`navlab.learn` (no streamlit); here are the Plotly figures of a
:class:`navlab.learn.StepThrough` and the small Streamlit pieces the page script composes.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import plotly.graph_objects as go
import streamlit as st
from plotly.subplots import make_subplots

from navlab.errors import NavlabError
from navlab.filters import registry
from navlab.learn import StepThrough, TinySpec, applicability, filter_info, step_through
from navlab.ui.colors import TRUTH_COLOR, filter_color, rgba
from navlab.ui.figures import readable

F32 = np.float32
CHANNEL_DASH = ("solid", "dot", "dash", "dashdot")
CONFIG = {"displaylogo": False}


# ------------------------------------------------------------------------------- pure figures
def _a(s: pd.Series) -> np.ndarray:
    return np.ascontiguousarray(s.to_numpy(dtype=float), dtype=F32)


def add_measurements(fig: go.Figure, g: pd.DataFrame, suffix: str, size: int) -> None:
    """One channel's measurements (open circles) and its outliers (red ×) into row 1 of ``fig``."""
    z = {"color": "#555555", "symbol": "circle-open", "size": size}
    trace = go.Scatter(x=_a(g["epoch"]), y=_a(g["z"]), name=f"measurement z{suffix}", marker=z)
    fig.add_trace(trace.update(mode="markers", legendgroup="z"), row=1, col=1)
    out = g[g["outlier"]]
    if len(out):
        mark = {"color": "#d62728", "symbol": "x", "size": size + 4}
        trace = go.Scatter(x=_a(out["epoch"]), y=_a(out["z"]), name=f"outlier{suffix}", marker=mark)
        fig.add_trace(trace.update(mode="markers", legendgroup="outlier"), row=1, col=1)


def _four_panels() -> go.Figure:
    """The empty figure: z and ẑ⁻ (1), NIS (2), R (3) and weights (4) over shared epochs."""
    return make_subplots(
        rows=4,
        cols=1,
        shared_xaxes=True,
        vertical_spacing=0.05,
        subplot_titles=(
            "measurement z, prediction ẑ⁻ and truth",
            "NIS vs the χ² threshold (◇: with nominal R₀)",
            "R used in the gain, R̂ and true R",
            "weights (1 = untouched)",
        ),
        row_heights=(0.32, 0.24, 0.24, 0.2),
    )


def _add_z_panel(fig: go.Figure, g: pd.DataFrame, ch, dash: str, color: str) -> None:
    """Panel 1 for one channel: its truth, the filter's prediction ẑ⁻ and the measurements."""
    x = _a(g["epoch"])
    truth_line = {"color": TRUTH_COLOR, "dash": dash, "width": 1}
    fig.add_trace(
        go.Scatter(
            x=x, y=_a(g["truth"]), name=f"truth {ch}", mode="lines", line=truth_line, legendgroup="truth"
        ),
        row=1,
        col=1,
    )
    fig.add_trace(
        go.Scatter(
            x=x,
            y=_a(g["z_pred"]),
            name=f"prediction ẑ⁻ {ch}",
            mode="lines+markers",
            line={"color": color, "dash": dash},
            legendgroup="pred",
        ),
        row=1,
        col=1,
    )
    add_measurements(fig, g, f" {ch}", size=8)


def _add_r_panel(fig: go.Figure, g: pd.DataFrame, ch, dash: str, color: str) -> None:
    """Panel 3 for one channel: the R used in the gain and, if the filter estimates it, R̂."""
    x = _a(g["epoch"])
    fig.add_trace(
        go.Scatter(
            x=x,
            y=_a(g["R_used"]),
            name=f"R used {ch}",
            mode="lines+markers",
            line={"color": color, "dash": dash},
            legendgroup="Rused",
        ),
        row=3,
        col=1,
    )
    if np.isfinite(g["R_hat"].to_numpy(dtype=float)).any():
        fig.add_trace(
            go.Scatter(
                x=x,
                y=_a(g["R_hat"]),
                name=f"R̂ {ch}",
                mode="lines+markers",
                line={"color": rgba(color, 0.55), "dash": dash, "width": 3},
                marker={"symbol": "diamond"},
                legendgroup="Rhat",
            ),
            row=3,
            col=1,
        )


def _true_r_trace(g: pd.DataFrame, ch, dash: str) -> go.Scatter:
    """One channel's true R (black, thick enough to be unmistakable)."""
    return go.Scatter(
        x=_a(g["epoch"]),
        y=_a(g["R_true"]),
        name=f"true R {ch}",
        mode="lines",
        line={"color": TRUTH_COLOR, "dash": dash, "width": 2.5},
        legendgroup="Rtrue",
    )


def _weight_trace(g: pd.DataFrame, ch, dash: str, color: str) -> go.Scatter:
    """Panel 4 for one channel: its weight, the flag as hover text."""
    return go.Scatter(
        x=_a(g["epoch"]),
        y=_a(g["weight"]),
        name=f"weight {ch}",
        mode="lines+markers",
        line={"color": color, "dash": dash},
        text=g["flag_name"].astype(str).to_numpy(),
        hovertemplate="epoch %{x}: w = %{y:.3g} (%{text})<extra></extra>",
        legendgroup="w",
    )


def _nis_traces(ep: pd.DataFrame, color: str) -> list:
    """Panel 2: NIS per epoch (red where it exceeds the threshold), the NIS with R₀, the χ² threshold."""
    exceed = ep["nis_exceeds"].to_numpy(dtype=bool)
    x = _a(ep["epoch"])
    return [
        go.Bar(
            x=x, y=_a(ep["nis"]), name="NIS", marker={"color": np.where(exceed, "#d62728", color).tolist()}
        ),
        go.Scatter(
            x=x,
            y=_a(ep["nis_nominal"]),
            name="NIS with nominal R₀",
            mode="markers",
            marker={"color": TRUTH_COLOR, "symbol": "diamond-open", "size": 10},
        ),
        go.Scatter(
            x=x,
            y=_a(ep["nis_threshold"]),
            name="χ² threshold",
            mode="lines",
            line={"color": TRUTH_COLOR, "dash": "dash", "shape": "hvh"},
        ),
    ]


def _finish_overview(fig: go.Figure, step: int, epochs: int) -> None:
    """The step's cursor on every panel, the axes (two log panels) and the layout."""
    for r in (1, 2, 3, 4):
        fig.add_vline(x=step, line={"color": "#f0a500", "width": 2}, opacity=0.5, row=r, col=1)
    fig.update_yaxes(title_text="z (m)", row=1, col=1)
    fig.update_yaxes(type="log", title_text="NIS (dimensionless)", row=2, col=1)
    fig.update_yaxes(type="log", title_text="R (m²)", row=3, col=1)
    fig.update_yaxes(range=[-0.05, 1.1], title_text="weight", row=4, col=1)
    fig.update_xaxes(title_text="epoch k", dtick=1 if epochs <= 20 else 2, row=4, col=1)
    fig.update_layout(height=860, bargap=0.4)
    # legend below, clean 1-2-5 / decade ticks on the two log panels (no main title: the
    # subplot titles sit where it would)
    readable(fig, title_above=False)
    fig.update_layout(margin_t=40)  # room for the first subplot title


def overview_figure(res: StepThrough, step: int) -> go.Figure:
    """Four stacked panels over the epochs, the current ``step`` highlighted.

    1 measurement z, the filter's prediction ẑ⁻ and the truth per channel (outliers marked);
    2 NIS per epoch against the χ²_{1−α}(m) threshold;
    3 R_used and R̂ against the true R per channel (log scale);
    4 per-channel weights (1 = untouched) with the flag of each channel as hover text.
    """
    color = filter_color(res.key)
    fig = _four_panels()
    ep = res.epoch_table()
    true_R: list[go.Scatter] = []  # drawn after every channel's R used and R̂: on top
    for i, (ch, g) in enumerate(res.steps.groupby("channel", sort=False)):
        dash = CHANNEL_DASH[i % len(CHANNEL_DASH)]
        _add_z_panel(fig, g, ch, dash, color)
        _add_r_panel(fig, g, ch, dash, color)
        true_R.append(_true_r_trace(g, ch, dash))
        fig.add_trace(_weight_trace(g, ch, dash, color), row=4, col=1)
    for tr in true_R:
        fig.add_trace(tr, row=3, col=1)
    if len(ep):
        for tr in _nis_traces(ep, color):
            fig.add_trace(tr, row=2, col=1)
    _finish_overview(fig, step, res.epochs)
    return fig


def step_channels(res: StepThrough, step: int) -> pd.DataFrame:
    """The per-channel table of one epoch, with readable column names (R̂ change: since k−1)."""
    rows = res.steps[res.steps["epoch"] == step].copy()
    if rows.empty:
        return rows
    rows["√S"] = np.sqrt(rows["S"].to_numpy(dtype=float))
    prev = res.steps[res.steps["epoch"] == step - 1].set_index("channel")["R_hat"]
    rows["R̂ change"] = rows["R_hat"].to_numpy(dtype=float) - (
        prev.reindex(rows["channel"]).to_numpy(dtype=float) if len(prev) else np.nan
    )
    cols = {
        "channel": "channel",
        "z": "z",
        "z_pred": "ẑ⁻ (predicted)",
        "innov": "innovation ν",
        "√S": "√S",
        "innov_norm": "ν/√S",
        "weight": "weight",
        "flag_name": "flag",
        "R_true": "true R",
        "R_used": "R used",
        "R_hat": "R̂",
        "R̂ change": "R̂ change",
        "outlier": "outlier added",
    }
    stat_cols = [c for c in rows.columns if c.startswith("stat:")]
    out = rows[list(cols) + stat_cols].rename(columns=cols)
    return out.rename(columns={c: c[5:] for c in stat_cols}).reset_index(drop=True)


def step_states(res: StepThrough, step: int) -> pd.DataFrame:
    """Prior, posterior and truth of each state at one epoch."""
    s = res.states[res.states["epoch"] == step].copy()
    s["σ prior"] = np.sqrt(s["P_prior"].to_numpy(dtype=float))
    s["σ posterior"] = np.sqrt(s["P_post"].to_numpy(dtype=float))
    keep = ["state", "truth", "prior", "posterior", "σ prior", "σ posterior", "error"]
    return s[keep].reset_index(drop=True)


# --------------------------------------------------------------------------- cached compute
@st.cache_data(max_entries=256, show_spinner=False)
def cached_step_through(key: str, spec: TinySpec) -> StepThrough:
    return step_through(key, spec)


@st.cache_data(max_entries=32, show_spinner=False)
def cached_applicability(spec: TinySpec) -> pd.DataFrame:
    rows = []
    for key, r in applicability(spec).items():
        cls = registry()[key]
        rows.append(
            {
                "filter": key,
                "label": cls.label,
                "family": cls.family,
                "runs on the tiny example": "yes" if r.applicable else "no",
                "why not": r.reason,
            }
        )
    return pd.DataFrame(rows)


# ------------------------------------------------------------------------------- renderers
FAMILY_ORDER = ("baseline", "oracle", "robust", "adaptive", "robust-adaptive", "nonlinear")


def filter_keys() -> list[str]:
    """Registered filter keys, grouped by family (baseline first), then by key."""
    reg = registry()
    rank = {f: i for i, f in enumerate(FAMILY_ORDER)}
    return sorted(reg, key=lambda k: (rank.get(reg[k].family, 99), k))


def render_filter_card(key: str) -> None:
    """Idea, paper, equations and parameters of one filter."""
    cls = registry()[key]
    info = filter_info(cls)
    st.header(info["label"])
    meta = f"**family** {info['family']} · **paper** {info['paper']}"
    if info["spec_section"]:
        meta += f" · **spec** ALGORITHMS.md {info['spec_section']}"
    meta += f" · **key** `{key}`"
    st.markdown(meta)
    if info["reconstruction"]:
        st.warning(
            "Reconstruction: the original paper could not be retrieved; navlab implements the "
            "reading documented in its spec section.",
            icon=":material/construction:",
        )
    st.markdown(info["idea"])
    st.subheader("Key equations")
    if info["equations"]:
        if info["equations_of"] not in (None, key):
            st.caption(f"The equations of `{info['equations_of']}`, which this filter varies.")
        for line in info["equations"]:
            st.latex(line)
    else:
        st.info(f"No equations written up for `{key}` yet. {info['summary']}")
    if info["params"]:
        with st.expander("Parameters and defaults"):
            p = pd.DataFrame(info["params"])[["name", "default", "lo", "hi", "help"]]
            p["default"] = p["default"].astype(str)
            for col in ("lo", "hi"):  # no bound: — (never a literal None)
                p[col] = [f"{v:g}" if isinstance(v, (int, float)) else "—" for v in p[col]]
            st.dataframe(p, hide_index=True, width="stretch")


def readable_table(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with every float written to 4 significant figures and a missing value as —."""
    out = df.copy()
    for col in out.columns:
        if pd.api.types.is_float_dtype(out[col]):
            out[col] = [f"{v:.4g}" if np.isfinite(v) else "—" for v in out[col]]
        elif out[col].dtype == object:
            out[col] = ["—" if v is None else v for v in out[col]]
    return out


def render_step(res: StepThrough, step: int) -> None:
    """What happened at one epoch: NIS against the threshold, the channels, the states."""
    ep = res.epoch_table().set_index("epoch")
    row = ep.loc[step]
    c1, c2, c3, c4, c5 = st.columns(5)
    c1.metric(
        "NIS γ (filter's S)",
        f"{row['nis']:.3g}",
        delta=f"{row['nis'] - row['nis_threshold']:+.3g} vs threshold",
        delta_color="inverse",
        help="νᵀS⁻¹ν with the S the filter used (a robust filter's S is already inflated)",
    )
    c2.metric(
        "NIS with nominal R₀",
        f"{row['nis_nominal']:.3g}",
        delta=f"{row['nis_nominal'] - row['nis_threshold']:+.3g} vs threshold",
        delta_color="inverse",
        help="νᵀ(HP⁻Hᵀ + R₀)⁻¹ν: what a plain KF would test",
    )
    c3.metric(
        "χ² threshold", f"{row['nis_threshold']:.3g}", help=f"χ²_(1−α)(m) with α = {res.data.spec.alpha:g}"
    )
    c4.metric("outlier at this epoch", "yes" if row["outlier"] else "no")
    flags = res.steps.loc[res.steps["epoch"] == step, "flag_name"].unique().tolist()
    c5.metric("flags", ", ".join(flags))
    if row["nis_exceeds"] or row["nis_nominal_exceeds"]:
        which = row["nis"] if row["nis_exceeds"] else row["nis_nominal"]
        st.warning(
            f"Epoch {step}: the NIS {which:.3g} exceeds the χ² threshold "
            f"{row['nis_threshold']:.3g} — the innovation is implausible under the model.",
            icon=":material/priority_high:",
        )
    st.markdown(
        "**Per channel** (innovation, its normalised size, the weight/flag the filter "
        "gave it, the R it used, its R̂ and the filter's own stats)"
    )
    st.dataframe(readable_table(step_channels(res, step)), hide_index=True, width="stretch")
    extra = res.extra_stats.get(step, {})
    if extra:
        with st.expander("Other stats at this epoch (e.g. per-iteration traces)"):
            for name, v in extra.items():
                st.write(f"`{name}`", np.asarray(v))
    st.markdown("**States**: prior x⁻ (after predict), posterior x⁺ (after update), truth")
    st.dataframe(readable_table(step_states(res, step)), hide_index=True, width="stretch")


def step_buttons(n_steps: int, key: str = "step") -> None:
    """◀ / ▶ / reset buttons moving the bound step slider (changed through session_state)."""

    def move(d: int) -> None:
        st.session_state[key] = int(min(n_steps, max(1, st.session_state.get(key, 1) + d)))

    b1, b2, b3, _ = st.columns([1, 1, 1, 5])
    b1.button("◀ previous", on_click=move, args=(-1,), key=f"{key}_prev", width="stretch")
    b2.button("next ▶", on_click=move, args=(1,), key=f"{key}_next", width="stretch")
    b3.button("⟲ first", on_click=move, args=(-n_steps,), key=f"{key}_first", width="stretch")


def safe_step_through(key: str, spec: TinySpec) -> StepThrough | None:
    try:
        return cached_step_through(key, spec)
    except NavlabError as exc:
        st.error(str(exc))
        return None


# ------------------------------------------------------------------------------ side by side
def side_by_side_figure(results: list[StepThrough], step: int) -> go.Figure:
    """Two or three filters on the same tiny example, stacked panels over the epochs, the current
    ``step`` marked: 1 the measurements of the first channel (the outlier red ×), the truth and
    each filter's posterior estimate of the measured state; 2 each filter's weight on that
    channel; 3 the R each used in its gain (log) against the true R; 4 each filter's position
    error |x⁺ − x|.
    """
    fig = make_subplots(
        rows=4,
        cols=1,
        shared_xaxes=True,
        vertical_spacing=0.05,
        row_heights=(0.34, 0.2, 0.23, 0.23),
        subplot_titles=(
            "measurement z, truth and each filter's estimate x⁺ (first channel)",
            "weight on the first channel (1 = untouched)",
            "R used in the gain (first channel) and the true R",
            "position error |x⁺ − x| (all measured axes)",
        ),
    )
    first = results[0]
    ch0 = first.data.channel_names[0]
    st0 = first.steps[first.steps["channel"] == ch0]
    x = _a(st0["epoch"])
    names = first.data.channel_names
    nmeas = len(names)
    for res in results:
        color = filter_color(res.key)
        g = res.steps[res.steps["channel"] == ch0]
        post = res.states[(res.states["state"] == res.data.state_names[0]) & (res.states["epoch"] > 0)]
        err = res.states[res.states["epoch"] > 0].copy()
        err = err[err["state"].isin(res.data.state_names[:nmeas])]
        e = err.assign(sq=err["error"].to_numpy(dtype=float) ** 2).groupby("epoch")["sq"].sum() ** 0.5
        weight_hover = {
            "text": g["flag_name"].astype(str).to_numpy(),
            "hovertemplate": "epoch %{x}: w = %{y:.3g} (%{text})<extra></extra>",
        }
        rows = [  # (x, y, extra trace settings) for the estimate, weight, R used, error panels
            (post["epoch"], post["posterior"], {"line": {"color": color, "width": 2.5}}),
            (g["epoch"], g["weight"], {**weight_hover, "showlegend": False}),
            (g["epoch"], g["R_used"], {"showlegend": False}),
            (pd.Series(e.index, dtype=float), e, {"showlegend": False}),
        ]
        for row, (xs, ys, extra) in enumerate(rows, 1):
            trace = {"name": res.label, "mode": "lines+markers", "line": {"color": color}}
            trace.update(legendgroup=res.key, **extra)
            fig.add_trace(go.Scatter(x=_a(xs), y=_a(ys), **trace), row=row, col=1)
    add_measurements(fig, st0, "", size=9)
    fig.add_trace(
        go.Scatter(
            x=x, y=_a(st0["truth"]), name="truth", mode="lines", line={"color": TRUTH_COLOR, "width": 2}
        ),
        row=1,
        col=1,
    )
    fig.add_trace(
        go.Scatter(
            x=x,
            y=_a(st0["R_true"]),
            name="true R",
            mode="lines",
            line={"color": TRUTH_COLOR, "width": 2.5},
            showlegend=False,
        ),
        row=3,
        col=1,
    )
    for r in (1, 2, 3, 4):
        fig.add_vline(x=step, line={"color": "#f0a500", "width": 2}, opacity=0.5, row=r, col=1)
    fig.update_yaxes(title_text=f"{ch0} (m)", row=1, col=1)
    fig.update_yaxes(range=[-0.05, 1.1], title_text="weight", row=2, col=1)
    fig.update_yaxes(type="log", title_text="R (m²)", row=3, col=1)
    fig.update_yaxes(title_text="error (m)", row=4, col=1)
    fig.update_xaxes(title_text="epoch k", dtick=1 if first.epochs <= 20 else 2, row=4, col=1)
    fig.update_layout(height=860, hovermode="x unified")
    readable(fig, title_above=False)
    fig.update_layout(margin_t=40)
    return fig


def side_by_side_table(results: list[StepThrough], step: int) -> pd.DataFrame:
    """One row per filter at epoch ``step``: innovation, NIS against the threshold, weight and
    flag of each channel, the R it used, its error after the update.
    """
    rows = []
    for res in results:
        s = res.steps[res.steps["epoch"] == step]
        states = res.states[res.states["epoch"] == step]
        nmeas = len(res.data.channel_names)
        err = float(np.sqrt((states["error"].to_numpy(dtype=float)[:nmeas] ** 2).sum()))
        rows.append(
            {
                "filter": res.label,
                "innovation ν": ", ".join(f"{v:.3g}" for v in s["innov"]),
                "NIS": f"{s['nis'].iloc[0]:.3g}",
                "χ² threshold": f"{s['nis_threshold'].iloc[0]:.3g}",
                "weight": ", ".join(f"{v:.3g}" for v in s["weight"]),
                "flag": ", ".join(s["flag_name"].astype(str)),
                "R used": ", ".join(f"{v:.3g}" for v in s["R_used"]),
                "error after the update (m)": f"{err:.3g}",
            }
        )
    return pd.DataFrame(rows)


# ------------------------------------------------------------------------------ play button
PLAY_EVERY_S = 0.8


def play_button(n_steps: int, key: str = "step", container=None) -> None:
    """▶ play / ❚❚ pause for the step slider ``key`` (a full rerun starts or stops the timer of
    :func:`stepper`); at the last step, play starts again from the first.
    """
    c = container if container is not None else st
    flag = f"{key}_playing"

    def toggle() -> None:
        on = not st.session_state.get(flag, False)
        st.session_state[flag] = on
        if on and st.session_state.get(key, 1) >= n_steps:
            st.session_state[key] = 1

    playing = st.session_state.get(flag, False)
    c.button(
        "❚❚ pause" if playing else "▶ play",
        on_click=toggle,
        key=f"{key}_play",
        width="stretch",
        help=f"step through the epochs, one every {PLAY_EVERY_S:g} s",
    )


def stepper(n_steps: int, draw, key: str = "step") -> None:
    """The bound step slider and ``draw(step)`` in a fragment that, while playing
    (:func:`play_button`), advances the step every :data:`PLAY_EVERY_S` seconds (only this
    fragment reruns) and stops at the last step.
    """
    flag = f"{key}_playing"
    playing = bool(st.session_state.get(flag, False))

    def body() -> None:
        ss = st.session_state
        if ss.get(flag, False):
            if ss.get(key, 1) >= n_steps:
                ss[flag] = False
                st.rerun()  # the whole page: the fragment is drawn again without a timer
            ss[key] = int(min(n_steps, ss.get(key, 1) + 1))
        if ss.get(key, 1) > n_steps:
            ss[key] = n_steps
        step = st.slider("Step (epoch k)", 1, n_steps, key=key, bind="query-params")
        draw(int(step))

    st.fragment(body, run_every=PLAY_EVERY_S if playing else None)()


# ------------------------------------------------------------------------------ page sections
def _navigation(n_steps: int) -> None:
    b = st.columns([1, 1, 1, 1, 4])
    play_button(n_steps, container=b[0])

    def move(d: int) -> None:
        st.session_state["step"] = int(min(n_steps, max(1, st.session_state.get("step", 1) + d)))
        st.session_state["step_playing"] = False

    b[1].button("◀ previous", on_click=move, args=(-1,), key="step_prev", width="stretch")
    b[2].button("next ▶", on_click=move, args=(1,), key="step_next", width="stretch")
    b[3].button("⟲ first", on_click=move, args=(-n_steps,), key="step_first", width="stretch")


def render_one(key: str, spec: TinySpec) -> None:
    """The step-through of one filter: caveat, navigation and play, the step's tables, the chart."""
    from navlab.learn import caveat
    from navlab.ui.views import chart

    res = safe_step_through(key, spec)
    if res is None:
        return
    if not res.applicable:
        st.warning(f"**{res.label}** cannot be stepped through here: {res.reason}", icon=":material/block:")
        return
    note = caveat(key)
    if note:
        st.info(note, icon=":material/info:")
    _navigation(res.epochs)

    def draw(step: int) -> None:
        render_step(res, step)
        chart(
            st,
            overview_figure(res, step),
            "Step-through overview: measurements, NIS against the χ² threshold, R and weights",
            name=f"learn-{key}-step-{step}",
        )
        st.download_button(
            "Download the step table (CSV)",
            res.steps.to_csv(index=False).encode(),
            file_name=f"navlab-learn-{key}.csv",
            mime="text/csv",
            on_click="ignore",
        )

    stepper(res.epochs, draw)


def render_side_by_side(keys: list[str], spec: TinySpec) -> None:
    """Two or three filters on the same tiny example, one step slider and one play button."""
    from navlab.ui.views import chart

    if len(keys) < 2:
        st.info("Choose two or three filters to compare them on the same example.")
        return
    results = [r for r in (safe_step_through(k, spec) for k in keys) if r is not None]
    bad = [r for r in results if not r.applicable]
    for r in bad:
        st.warning(f"**{r.label}** cannot be stepped through here: {r.reason}", icon=":material/block:")
    results = [r for r in results if r.applicable]
    if len(results) < 2:
        return
    labels = " · ".join(f"**{r.label}**: {registry()[r.key].summary}" for r in results)
    st.markdown(labels)
    _navigation(results[0].epochs)

    def draw(step: int) -> None:
        st.markdown(f"**Epoch {step}**, every filter after its update")
        st.dataframe(readable_table(side_by_side_table(results, step)), hide_index=True, width="stretch")
        chart(
            st,
            side_by_side_figure(results, step),
            "Filters side by side: estimates, weights, R used and errors on the same example",
            name="learn-side-by-side-" + "-".join(r.key for r in results),
        )

    stepper(results[0].epochs, draw)


def compare_link(keys: list[str], spec: TinySpec) -> None:
    """A link to Compare running these filters on the 2-D tracking scenario with outliers, its
    single-run view below the averages.
    """
    from navlab.ui.frame import PRESENT, presenting

    reg = registry()
    flt = [k for k in keys if k in reg and reg[k].family != "nonlinear"] or ["kf"]
    if "kf" not in flt:
        flt = ["kf", *flt]
    # the Learn example only, not the session's carried experiment (a sins_gps run before would
    # open sins_gps with its filter parameters under a label that says 2-D tracking)
    q = {"flt": flt, "runs": "50", "go": "1"}
    if presenting():
        q[PRESENT] = "1"
    st.page_link(
        "pages/1_Compare.py",
        label="These filters on one Monte Carlo run of the 2-D tracking scenario (Compare, single-run view)",
        icon=":material/play_circle:",
        query_params=q,
    )

"""The Reproduce page's building blocks: a registered reproduction judged seed block by seed block,
its finished blocks kept in the server's results store, and its verdicts, evidence, readings and
curves as tables and figures.

Pure helpers (no streamlit calls): :func:`claims_figure`, :func:`evidence_figure`,
:func:`curve_figure`, :func:`style_verdicts`, :func:`readings_table`, :func:`seeds_note`,
:func:`progress_note`. :func:`run_live` computes with progress and Stop, :func:`stored_outcome`
shows what the store holds, :func:`show_verdicts` draws an outcome.
"""

from __future__ import annotations

import contextlib
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd
import plotly.graph_objects as go
import streamlit as st

from navlab import stats as S
from navlab.reproduce import DEFAULT_SEEDS, REPRODUCTIONS, Outcome
from navlab.reproduce.engine import TOLERANCE, Margin, iter_evaluate, workers
from navlab.reproduce.report import VERDICT_RULES, claims_table, counts, verdict_table
from navlab.ui import sweep as U
from navlab.ui.colors import PALETTE, TRUTH_COLOR, filter_colors
from navlab.ui.figures import readable, title_layout
from navlab.ui.share import literal
from navlab.ui.views import chart

VERDICT_COLORS = {
    "reproduced": "#d9f2d9",
    "inconclusive": "#fff1c2",
    "contradicted": "#f8d0d0",
    "setup-dependent": "#dbe4f8",
    "not testable": "#e6e6e6",
}
DOT_COLORS = {
    "reproduced": "#2ca02c",
    "contradicted": "#d62728",
    "inconclusive": "#f0a500",
    "setup-dependent": "#1f5fbf",
    "not testable": "#7f7f7f",
}
MAX_CURVE_POINTS = 2000
CELL_NAMES = {"#": "no."}  # st.table writes its cells as Markdown: "#" alone is an empty heading
# The page opens on the paper that answers fastest, at a seed count that answers in seconds
# (measured on this 2-core machine while shared, seeds judged in this process: irakf's first seed
# ≈ 1–2 s, its 5 seeds ≈ 3–5 s; vbekf's first seed ≈ 3.5 s; hakf and nnmfukf take tens of seconds
# per seed block). The CLI judges at 20 seeds.
DEFAULT_KEY = "irakf"
APP_SEEDS = 5

Config = tuple[str, int, int, int]  # (reproduction, runs per seed, seeds, base seed)


def default_key(keys: list[str]) -> str:
    return DEFAULT_KEY if DEFAULT_KEY in keys else keys[0]


def seeds_note(key: str, seeds: int) -> str:
    """What the seed count means, with the CLI line of the full judgement."""
    cli = f"`python -m navlab reproduce {key} --seeds {DEFAULT_SEEDS}`"
    if seeds >= DEFAULT_SEEDS:
        return f"{seeds} seeds, as the CLI judges ({cli}). Verdicts appear as blocks of seeds finish."
    return (
        f"{seeds} seeds: a first look that answers in seconds (verdicts appear as blocks of seeds "
        f"finish, the first after one seed). The full judgement is {DEFAULT_SEEDS} seeds: {cli}; "
        "verdicts can change with more seeds."
    )


def progress_note(o: Outcome) -> str:
    """Whether the verdicts are final, and on how many seeds they rest."""
    seeds = f"{o.seeds} seed{'s' if o.seeds != 1 else ''}"
    if o.complete:
        return f"Judged on {seeds} × {o.runs} runs (base seed {o.seed})."
    return (
        f"Provisional: judged on {seeds} of {o.seeds_asked} × {o.runs} runs (base seed {o.seed}); "
        "with fewer seeds a number has a wider interval (none with one seed), so more verdicts "
        "are inconclusive."
    )


def _cells(t: pd.DataFrame) -> pd.DataFrame:
    """A table for ``st.table``, which writes every cell as Markdown: Markdown's characters
    escaped (a paper cell "> 10.0 m" was a block quote), "#" renamed (alone, an empty heading).
    """
    return t.rename(columns=CELL_NAMES).map(lambda v: literal(v) if isinstance(v, str) else v)


def style_verdicts(o: Outcome):
    """The verdict table (one row per claim) with the verdict cell coloured."""
    t = _cells(verdict_table(o))
    return t.style.map(lambda v: f"background-color: {VERDICT_COLORS.get(v, '')}", subset=["verdict"])


def readings_table(o: Outcome) -> pd.DataFrame:
    """The detailed readings with three significant figures and the paper's names."""
    r = o.readings.copy()
    for c in ("value", "ci_lo", "ci_hi", "seed_mean", "range_lo", "range_hi", "paper"):
        r[c] = [S.sig3(v) for v in r[c]]
    return r.drop(columns=["filter"]).rename(columns={"label": "filter", "value": "pooled"})


def _dots(
    fig: go.Figure, x: np.ndarray, lo: np.ndarray, hi: np.ndarray, y: list[str], colors: list[str], hover: str
) -> None:
    """One dot per row with its 95 % interval as a thick bar."""
    fig.add_trace(
        go.Scatter(
            x=x,
            y=y,
            mode="markers",
            marker={"color": colors, "size": 10},
            error_x={
                "type": "data",
                "symmetric": False,
                "array": np.where(np.isfinite(hi), hi - x, 0.0),
                "arrayminus": np.where(np.isfinite(lo), x - lo, 0.0),
                "thickness": 4,
                "width": 0,
            },
            hovertemplate=hover,
            showlegend=False,
        )
    )


def claims_figure(o: Outcome) -> go.Figure | None:
    """Each number, bound and margin claim: navlab's mean over seeds relative to the paper's value
    (%), with its 95 % interval (thick) and the per-seed range (thin); the ±20 % band shaded.
    None when the paper states no such number.
    """
    v = o.verdicts
    v = v[v["kind"].isin(["number", "bound", "margin"]) & np.isfinite(v["mean"].astype(float))]
    if v.empty:
        return None
    v = v.iloc[::-1]
    paper = v["paper"].astype(float).to_numpy()
    rel = lambda col: 100 * (v[col].astype(float).to_numpy() - paper) / np.abs(paper)  # noqa: E731
    y = [f"{i + 1}. {t}" for i, t in zip(v.index, v["text"], strict=True)]
    colors = [DOT_COLORS.get(x, DOT_COLORS["inconclusive"]) for x in v["verdict"]]
    fig = go.Figure()
    fig.add_vrect(x0=-100 * TOLERANCE, x1=100 * TOLERANCE, fillcolor="rgba(44,160,44,0.08)", line_width=0)
    fig.add_vline(x=0, line={"color": TRUTH_COLOR, "width": 1})
    m = rel("mean")
    fig.add_trace(  # the per-seed range, thin and grey, under the interval
        go.Scatter(
            x=m,
            y=y,
            mode="markers",
            marker={"size": 1, "color": "#999999"},
            error_x={
                "type": "data",
                "symmetric": False,
                "array": np.nan_to_num(rel("range_hi") - m),
                "arrayminus": np.nan_to_num(m - rel("range_lo")),
                "thickness": 1,
                "width": 0,
                "color": "#999999",
            },
            hoverinfo="skip",
            showlegend=False,
        )
    )
    _dots(fig, m, rel("ci_lo"), rel("ci_hi"), y, colors, "%{y}<br>%{x:+.1f} % from the paper<extra></extra>")
    fig.update_layout(xaxis_title="(navlab − paper) / |paper|  (%)", height=max(260, 34 * len(v) + 160))
    readable(fig)
    fig.update_layout(
        title=title_layout(
            "navlab relative to the paper's numbers (%)",
            "mean over seeds; 95 % interval (thick), per-seed range (thin); shaded: ±20 % (reproduced)",
        ),
        yaxis={"automargin": True},
    )
    return fig


def evidence_figure(o: Outcome) -> go.Figure | None:
    """The evidence of every qualitative claim (a ranking, "close"): the paired relative difference
    (A − B)/B of the claimed filter A against each competitor B (a "close" claim: each filter
    against the best, its ±band shaded on its rows), with its 95 % interval, coloured by the
    claim's verdict. None when the paper makes no such claim.
    """
    e = o.evidence
    if e.empty:
        return None
    num = {c: i + 1 for i, c in enumerate(o.verdicts["claim"])}
    verdict = dict(zip(o.verdicts["claim"], o.verdicts["verdict"], strict=True))
    e = e.iloc[::-1]
    y = [f"{num[c]}. {a} vs {b}" for c, a, b in zip(e["claim"], e["a"], e["b"], strict=True)]
    flip = np.where(e["lower"].astype(bool), 1.0, -1.0)  # negative = A better, on every row
    pct = lambda col: 100 * flip * e[col].astype(float).to_numpy()  # noqa: E731
    lo, hi = pct("rel_lo"), pct("rel_hi")
    lo, hi = np.fmin(lo, hi), np.fmax(lo, hi)
    fig = go.Figure()
    for i, (kind, within) in enumerate(zip(e["kind"], e["within"].astype(float), strict=True)):
        if kind == "close" and np.isfinite(within):
            fig.add_shape(
                type="rect",
                x0=-100 * within,
                x1=100 * within,
                y0=i - 0.45,
                y1=i + 0.45,
                fillcolor="rgba(44,160,44,0.12)",
                line_width=0,
                layer="below",
            )
    fig.add_vline(x=0, line={"color": TRUTH_COLOR, "width": 1})
    colors = [DOT_COLORS.get(verdict.get(c, ""), DOT_COLORS["inconclusive"]) for c in e["claim"]]
    _dots(fig, pct("rel"), lo, hi, y, colors, "%{y}<br>%{x:+.1f} %<extra></extra>")
    fig.update_layout(
        xaxis_title="paired (A − B) / B  (%): below 0, A has the lower error",
        height=max(260, 30 * len(e) + 160),
    )
    readable(fig)
    fig.update_layout(
        title=title_layout(
            "The paper's rankings: the paired differences they rest on",
            "A = the filter the claim favours, B = each competitor (claim number first); 95 % interval "
            "over all runs pooled<br>a ranking holds where the whole interval is below 0; shaded: "
            "the ±band of a 'close' claim",
        ),
        yaxis={"automargin": True, "type": "category"},
    )
    return fig


_CURVE_WORDS = {"pos": "position", "vel": "velocity", "att": "attitude"}


def curve_label(o: Outcome, name: str) -> str:
    """A curve table's name in words: ``irakf_isolated_rmse_x_pos.csv`` → "isolated: RMSE of x
    position" (the file keeps its name; a tab and a chart title read as words).
    """
    stem = name.removeprefix(f"{o.reproduction.key}_").removesuffix(".csv")
    exp, sep, quantity = stem.rpartition("_rmse_")
    if not sep:
        return stem
    what = " ".join(_CURVE_WORDS.get(w, w) for w in quantity.split("_"))
    return f"{exp}: RMSE of {what}" if exp else f"RMSE of {what}"


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
        xaxis_title="time (s)",
        yaxis_title=f"RMSE ({unit})" if unit else "RMSE (unit not stated in the curve table)",
        height=420,
    )
    readable(fig)  # legend below the plot, axes pushing the margins
    fig.update_layout(
        title=title_layout(curve_label(o, name), "per-epoch RMSE over the judged runs of all seeds")
    )
    return fig


def margin_note(rep: Any) -> str | None:
    """How a margin claim's numbers read ("IRAKF 27.43 % more accurate than RRAE" is listed as
    −27.43 %, the paper's (a − b)/b), or None when the paper states no such margin.
    """
    if not any(isinstance(c, Margin) and not c.as_ratio for c in rep.claims):
        return None
    return (
        'Margins ("A x % more accurate than B"): the paper and navlab columns give (A − B) / B, so '
        "negative means A has the lower error."
    )


def show_verdicts(container: Any, o: Outcome) -> None:
    """The counts, the verdict table and the claims' charts of ``o`` (drawn into ``container``,
    e.g. an ``st.empty()`` that each provisional outcome replaces).
    """
    with container.container():
        cols = st.columns(1 + len(VERDICT_RULES))
        cols[0].metric("claims", len(o.verdicts))
        for c, (v, n) in zip(cols[1:], counts(o).items(), strict=True):
            c.metric(v, n, help=VERDICT_RULES[v])
        (st.caption if o.complete else st.warning)(progress_note(o))
        # a static table: its long claims wrap (no sideways scrolling for the verdict) and it
        # needs no data-grid code in the browser (on a busy machine the grid's first load took
        # up to 7 s after the verdicts were sent)
        st.table(style_verdicts(o), hide_index=True, alt=f"verdicts of {o.reproduction.key}")
        if note := margin_note(o.reproduction):
            st.caption(note)
        for fig, alt, name in (
            (claims_figure(o), "navlab's value relative to the paper's for every number claim", "claims"),
            (evidence_figure(o), "the paired differences behind every ranking claim", "rankings"),
        ):
            if fig is not None:
                chart(st, fig, alt, name=f"{o.reproduction.key}-{name}")


def show_claims(container: Any, rep: Any) -> None:
    """The paper's claims, not judged yet, under a note to press Run (in ``container``)."""
    with container.container():
        st.info("Press **Run** to judge the paper's claims; the first verdicts come after one seed.")
        table = _cells(claims_table(rep))
        st.table(table, hide_index=True, alt=f"the claims of {rep.key}")
        st.caption(
            "‡: a setting navlab chose where the paper is silent or with the judged scenario in view. "
            "Not testable: the paper gives too little to test, or the claim needs a reconstruction "
            "that fails; the reasons come with the verdicts."
            + (f" {note}" if (note := margin_note(rep)) else "")
        )


# --------------------------------------------------------------------------- running


# Complete outcomes in memory (the store keeps the blocks; judging them again costs seconds):
# a process-wide LRU shared by the sessions. Outcomes are shared, never mutated.
_CACHE: OrderedDict[Config, Outcome] = OrderedDict()
_CACHE_LOCK = threading.Lock()
CACHE_ENTRIES = 16


def _remember(config: Config, o: Outcome) -> None:
    with _CACHE_LOCK:
        _CACHE[config] = o
        _CACHE.move_to_end(config)
        while len(_CACHE) > CACHE_ENTRIES:
            _CACHE.popitem(last=False)


def stored_outcome(config: Config) -> Outcome | None:
    """The outcome of ``config`` without computing anything: from memory, else judged on the
    seeds whose blocks the results store holds (provisional if not all), else None.
    """
    with _CACHE_LOCK:
        if config in _CACHE:
            _CACHE.move_to_end(config)
            return _CACHE[config]
    key, runs, seeds, seed = config
    gen = iter_evaluate(REPRODUCTIONS[key], runs, seeds, seed, store=U.app_store(), should_stop=U.stored_only)
    with contextlib.closing(gen):
        last = next(gen, None)  # the stored seeds' outcome is the first one; nothing is computed
    if last is not None and last.complete:
        _remember(config, last)
    return last


def where_text(config: Config) -> str:
    key, runs, seeds, seed = config
    n = workers(REPRODUCTIONS[key], runs, seeds, seed)
    return "in the server process" if n == 1 else f"in {n} worker processes"


def run_live(
    page: str, config: Config, stop_container: Any, render: Callable[[Outcome], None]
) -> Outcome | None:
    """Judge ``config`` with a progress bar and a Stop button (in ``stop_container``), calling
    ``render`` with every provisional outcome as its seed blocks finish. Returns the last outcome
    (None after an error, shown, or a stop before the first seed).

    Every finished block is kept in the results store: Stop (a rerun), a closed browser (the
    session's script is stopped) or an error end the work at once — worker processes included —
    and the next Run resumes from the store.
    """
    key, runs, seeds, seed = config
    with _CACHE_LOCK:
        done = _CACHE.get(config)
    if done is not None:  # judged already: nothing to compute
        U.cancel(page)
        render(done)
        return done

    def work(store: Any, on_progress: Any, tick: Any) -> Outcome | None:
        last = None
        gen = iter_evaluate(
            REPRODUCTIONS[key], runs, seeds, seed, store=store, on_progress=on_progress, tick=tick
        )
        with contextlib.closing(gen):
            for last in gen:
                render(last)
        return last

    out = U.run_job(page, stop_container, work, what="runs", where=where_text(config))
    if out is not None and out.complete:
        _remember(config, out)
    return out

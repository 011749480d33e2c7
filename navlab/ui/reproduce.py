"""The Reproduce page's building blocks: run a registered paper reproduction, cached by its
configuration, and show the paper's numbers beside navlab's (tables, bars, curves).

Pure helpers (no streamlit calls): :func:`numeric_table`, :func:`differences`,
:func:`bar_figure`, :func:`paper_groups`, :func:`curve_figure`, :func:`style_table`,
:func:`paper_runs`. :func:`cached_run` is the cached runner the page calls.
"""

from __future__ import annotations

import inspect
import sys
import tempfile
import threading
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import plotly.graph_objects as go

from navlab.reproduce import COLUMNS, REPRODUCTIONS, Reproduction
from navlab.ui.colors import PALETTE, TRUTH_COLOR, filter_colors
from navlab.ui.figures import readable

PAPER_COLOR = "#9aa0a6"  # the paper's bars: neutral grey beside the filter's own colour
CONFIG = {"displaylogo": False}
X_COLUMNS = ("epoch", "k", "t_s", "t", "time", "time_s")
CLOSE, FAR = 0.10, 0.25  # |rel_diff| ≤ 10 %: close; > 25 %: far (colouring only)
MAX_CURVE_POINTS = 2000


# ------------------------------------------------------------------------------------ pure
def paper_runs(rep: Reproduction) -> int | None:
    """The paper's Monte Carlo size if the reproduction's module states it (``DEFAULT_RUNS``)."""
    for obj in (rep, sys.modules.get(getattr(rep.run, "__module__", ""), None)):
        for name in ("paper_runs", "DEFAULT_RUNS"):
            v = getattr(obj, name, None)
            if isinstance(v, int) and not isinstance(v, bool) and v > 0:
                return v
    return None


def accepts(fn: Callable[..., Any], name: str) -> bool:
    """Whether ``fn`` takes a keyword argument ``name`` (or **kwargs)."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False
    return name in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def numeric_table(df: pd.DataFrame) -> pd.DataFrame:
    """The reproduction table with ``value``, ``paper`` and ``rel_diff`` as floats (None → NaN)."""
    out = df.copy()
    for c in COLUMNS:
        if c not in out.columns:
            out[c] = np.nan if c in ("value", "paper", "rel_diff") else ""
    for c in ("value", "paper", "rel_diff"):
        out[c] = pd.to_numeric(out[c], errors="coerce").astype(float)
    for c in ("experiment", "filter", "metric", "unit", "note"):
        out[c] = out[c].fillna("").astype(str)
    extra = [c for c in out.columns if c not in COLUMNS]
    return out[COLUMNS + extra].reset_index(drop=True)


def verdict(rel: float) -> str:
    if not np.isfinite(rel):
        return "no paper number"
    a = abs(rel)
    return "close" if a <= CLOSE else ("differs" if a <= FAR else "far")


def differences(df: pd.DataFrame, tol: float = CLOSE) -> pd.DataFrame:
    """Rows with a paper number: paper, ours, the relative difference, a verdict and why.

    Sorted so the largest disagreements come first.
    """
    t = numeric_table(df)
    t = t[np.isfinite(t["paper"])].copy()
    t["verdict"] = [verdict(r) for r in t["rel_diff"]]
    t["abs_rel"] = t["rel_diff"].abs()
    t = t.sort_values("abs_rel", ascending=False, na_position="last")
    return t.drop(columns="abs_rel").reset_index(drop=True)


def style_table(df: pd.DataFrame):
    """A pandas Styler: rel_diff coloured green (≤ 10 %), amber (≤ 25 %), red (beyond)."""
    t = numeric_table(df)

    def colour(v: float) -> str:
        if not np.isfinite(v):
            return "color: #888"
        a = abs(v)
        if a <= CLOSE:
            return "background-color: #d9f2d9"
        if a <= FAR:
            return "background-color: #fff1c2"
        return "background-color: #f8d0d0"

    return (
        t.style.format({"value": "{:.4g}", "paper": "{:.4g}", "rel_diff": "{:+.1%}"}, na_rep="—")
        .map(colour, subset=["rel_diff"])
        .map(lambda v: "font-weight: 600", subset=["value", "paper"])
    )


def paper_groups(df: pd.DataFrame) -> list[tuple[str, str]]:
    """(experiment, metric) pairs having at least one paper number, in table order."""
    t = numeric_table(df)
    t = t[np.isfinite(t["paper"])]
    return list(dict.fromkeys(zip(t["experiment"], t["metric"], strict=True)))


NAME_TABLES = ("PAPER_NAMES", "NAMES")  # {registry key: paper's name} in a reproduction module


def paper_name_keys() -> dict[str, str]:
    """Paper name → registry key, from the name tables of the registered reproductions' modules
    (e.g. ``navlab.reproduce.hakf.PAPER_NAMES``: ``"HKF"`` → ``huber-kf``). The first
    reproduction (by key) naming a paper name wins.
    """
    out: dict[str, str] = {}
    for rk in sorted(REPRODUCTIONS):
        mod = sys.modules.get(getattr(REPRODUCTIONS[rk].run, "__module__", ""), None)
        for attr in NAME_TABLES:
            table = getattr(mod, attr, None)
            if isinstance(table, dict):
                for key, name in table.items():
                    if isinstance(key, str) and isinstance(name, str):
                        out.setdefault(name, key)
    return out


def filter_key(name: str, keys: list[str] | None = None, names: dict[str, str] | None = None) -> str | None:
    """The registry key a reproduction's ``filter`` entry (or curve column) stands for, or None.

    A registry key itself; a paper's name of one (:func:`paper_name_keys`); a key followed by a
    variant (``vb-ekf (τ_P=3)``, ``vb-ekf_tauP3_rmse_pos_m``): the longest key it starts with.
    """
    keys = sorted(filter_colors(), key=len, reverse=True) if keys is None else keys
    names = paper_name_keys() if names is None else names
    if name in names:
        return names[name]
    return _key_of(name, keys) or _key_of(name.split(" ")[0], keys)


def reproduction_colors(names: list[str]) -> list[str]:
    """The colour of each reproduction ``filter`` entry: its registry key's colour on every page
    (Compare's colour), a palette colour for what is not a filter (e.g. a ratio row).
    """
    colours = filter_colors()
    keys = sorted(colours, key=len, reverse=True)
    table = paper_name_keys()
    out = []
    for i, n in enumerate(names):
        k = filter_key(n, keys, table)
        out.append(colours[k] if k else PALETTE[i % len(PALETTE)])
    return out


def bar_figure(df: pd.DataFrame, experiment: str, metric: str) -> go.Figure:
    """Grouped bars per filter: the paper's number (grey) and navlab's (the filter's colour).

    Bars are coloured by registry key (``filter``; a paper's name is mapped to its key) and
    labelled with ``label`` where the table has one.
    """
    t = numeric_table(df)
    t = t[(t["experiment"] == experiment) & (t["metric"] == metric)]
    ours_c = reproduction_colors(t["filter"].tolist())
    labels = t["label"] if "label" in t.columns else t["filter"]
    filters = [
        str(lab) if isinstance(lab, str) and lab else str(f)
        for lab, f in zip(labels, t["filter"], strict=True)
    ]
    unit = next((u for u in t["unit"] if u), "")
    fig = go.Figure()
    fig.add_trace(
        go.Bar(
            x=filters,
            y=t["paper"].to_numpy(dtype=np.float32),
            name="paper",
            marker={"color": PAPER_COLOR, "pattern": {"shape": "/"}},
            hovertemplate="%{x}<br>paper: %{y:.4g}<extra></extra>",
        )
    )
    fig.add_trace(
        go.Bar(
            x=filters,
            y=t["value"].to_numpy(dtype=np.float32),
            name="navlab",
            marker={"color": ours_c},
            customdata=np.stack([t["rel_diff"].to_numpy(dtype=float)], axis=-1),
            hovertemplate="%{x}<br>navlab: %{y:.4g}<br>rel. diff %{customdata[0]:+.1%}<extra></extra>",
        )
    )
    fig.update_layout(
        barmode="group",
        title=f"{experiment} · {metric}",
        height=360,
        yaxis_title=f"{metric} ({unit})" if unit else f"{metric} (no unit)",
        xaxis_title="filter",
    )
    return readable(fig)


def reldiff_figure(df: pd.DataFrame) -> go.Figure:
    """One horizontal bar per row with a paper number: (navlab − paper)/paper, coloured by verdict."""
    d = differences(df)
    d = d[np.isfinite(d["rel_diff"])].iloc[::-1]
    labels = (d["experiment"] + " · " + d["filter"] + " · " + d["metric"]).to_numpy()
    cmap = {"close": "#2ca02c", "differs": "#f0a500", "far": "#d62728"}
    fig = go.Figure(
        go.Bar(
            x=(100 * d["rel_diff"]).to_numpy(dtype=np.float32),
            y=labels,
            orientation="h",
            marker={"color": [cmap.get(v, "#888888") for v in d["verdict"]]},
            customdata=np.stack([d["paper"].to_numpy(dtype=float), d["value"].to_numpy(dtype=float)], axis=-1)
            if len(d)
            else None,
            hovertemplate="%{y}<br>paper %{customdata[0]:.4g} · navlab %{customdata[1]:.4g}"
            "<br>%{x:+.1f} %<extra></extra>",
        )
    )
    for x in (-100 * FAR, -100 * CLOSE, 100 * CLOSE, 100 * FAR):
        fig.add_vline(x=x, line={"color": "#bbbbbb", "dash": "dot", "width": 1})
    fig.update_layout(
        title="navlab vs paper: relative difference (%)",
        xaxis_title="(navlab − paper)/paper (%)",
        height=max(260, 26 * len(d) + 110),
        showlegend=False,
    )
    return readable(fig)


def _x_column(df: pd.DataFrame) -> str | None:
    for c in X_COLUMNS:
        if c in df.columns:
            return c
    return None


def is_long(df: pd.DataFrame) -> bool:
    """A tidy curves table: one row per (filter, epoch) with a ``filter`` column."""
    return "filter" in df.columns


def curve_measures(df: pd.DataFrame) -> list[str]:
    """The numeric columns one can plot against the time/epoch column."""
    x_col = _x_column(df)
    return [c for c in df.columns if c != x_col and pd.api.types.is_numeric_dtype(df[c])]


def _key_of(name: str, keys: list[str]) -> str | None:
    return next((k for k in keys if name == k or name.startswith((k + "_", k + " "))), None)


def wide_groups(df: pd.DataFrame) -> dict[str, list[str]]:
    """Columns of a wide curves table grouped by quantity: ``<filter key>_<quantity>``.

    A variant's column (``vb-ekf_tauP3_rmse_pos_m``) joins the group whose quantity its own ends
    with (``rmse_pos_m``). Returns {} when grouping would not help (one group, or one column per
    group): then every column goes in one chart.
    """
    if is_long(df):
        return {}
    keys = sorted(filter_colors(), key=len, reverse=True)
    cols = curve_measures(df)
    suffix = {}
    for c in cols:
        k = _key_of(c, keys)
        suffix[c] = c[len(k) + 1 :] if k and len(c) > len(k) else c
    bases = sorted(set(suffix.values()), key=len)
    groups: dict[str, list[str]] = {}
    for c in cols:
        q = suffix[c]
        base = next((b for b in bases if b != q and q.endswith("_" + b)), q)
        groups.setdefault(base, []).append(c)
    if len(groups) <= 1 or len(groups) == len(cols):
        return {}
    return groups


UNIT_SUFFIX = {"m": "m", "mps": "m/s", "arcmin": "arcmin", "deg": "deg", "rad": "rad", "s": "s", "m2": "m²"}
X_TITLES = {"epoch": "epoch", "k": "epoch k", "t_s": "time (s)", "t": "time (s)", "time_s": "time (s)"}
WORDS = {"rmse": "RMSE", "sigma": "σ", "att": "attitude", "pos": "position", "vel": "velocity"}


def split_unit(quantity: str) -> tuple[str, str]:
    """``"rmse_vel_mps"`` → (``"rmse_vel"``, ``"m/s"``); no unit suffix → (quantity, "")."""
    base, _, suffix = quantity.rpartition("_")
    return (base, UNIT_SUFFIX[suffix]) if base and suffix in UNIT_SUFFIX else (quantity, "")


def quantity_label(quantity: str, with_unit: bool = True) -> str:
    """A curve column's quantity in words.

    ``"rmse_att_arcmin"`` → ``"RMSE attitude (arcmin)"``; ``"sigma_hat_x_m"`` → ``"σ̂ x (m)"``.
    """
    base, unit = split_unit(quantity)
    text = " ".join(base.split("_")).replace("sigma hat", "σ̂")
    text = " ".join(WORDS.get(w, w) for w in text.split(" "))
    return f"{text} ({unit})" if with_unit and unit else text


def _is_truth(name: str) -> bool:
    return "true" in name.replace(" ", "_").split("_")


def curve_figure(
    df: pd.DataFrame, title: str, measure: str | None = None, columns: list[str] | None = None
) -> go.Figure:
    """Curves of a reproduction's CSV against its time/epoch column (decimated, float32).

    Wide table: every numeric column (or those in ``columns``; ``measure`` then names the group)
    is a line. Tidy table (a ``filter`` column): one line per filter of ``measure`` (default: the
    first numeric column). A line of a registered filter (its key or paper name leading the
    column) takes that filter's colour on every page and its label; a "true …" column is the
    reference, drawn last in black. The y axis is titled with the quantity and its unit (from the
    column's unit suffix, e.g. ``_m``, ``_mps``, ``_arcmin``).
    """
    from navlab.filters import registry

    reg = registry()
    x_col = _x_column(df)
    colours = filter_colors()
    keys = sorted(colours, key=len, reverse=True)
    names = paper_name_keys()
    series: list[tuple[str, np.ndarray, np.ndarray]] = []
    if is_long(df):
        measure = measure or (curve_measures(df) or [None])[0]
        if measure is not None:
            for f, g in df.groupby("filter", sort=False):
                x = g[x_col].to_numpy(dtype=float) if x_col else np.arange(len(g), dtype=float)
                series.append((str(f), x, g[measure].to_numpy(dtype=float)))
    else:
        x = df[x_col].to_numpy(dtype=float) if x_col else np.arange(len(df), dtype=float)
        series = [(c, x, df[c].to_numpy(dtype=float)) for c in (columns or curve_measures(df))]
    # what each column measures once its filter key is taken off
    parts = []
    for name, _, _ in series:
        k = filter_key(name, keys, names)
        rest = name[len(k) + 1 :] if k and name.startswith(k) and len(name) > len(k) else ""
        parts.append((k, rest))
    rests = {r for _, r in parts if r}
    if is_long(df):
        common = measure or ""
    elif measure:
        common = measure
    else:
        common = next(iter(rests)) if len(rests) == 1 else ""
    traces, refs = [], []
    for i, ((name, x, y), (k, rest)) in enumerate(zip(series, parts, strict=True)):
        if k in reg:
            label = reg[k].label
            if is_long(df) or not rest:
                shown = label
            elif common and rest.endswith(common):
                variant = rest[: -len(common)].strip("_")
                shown = f"{label} {variant}" if variant else label
            else:
                shown = f"{label} {quantity_label(rest)}"
        else:
            shown = quantity_label(name)
        truth = _is_truth(name)
        colour = TRUTH_COLOR if truth else (colours[k] if k else PALETTE[i % len(PALETTE)])
        dash = "dot" if any(s in name for s in ("tau", "paper")) else "solid"
        step = max(1, int(np.ceil(len(y) / MAX_CURVE_POINTS)))
        trace = go.Scattergl if len(y) // step > 1000 else go.Scatter
        tr = trace(
            x=x[::step].astype(np.float32),
            y=y[::step].astype(np.float32),
            name=shown,
            mode="lines",
            line={"color": colour, "dash": dash, "width": 2.5 if truth else 1.8},
        )
        (refs if truth else traces).append(tr)
    units = {split_unit(r)[1] for r in rests} | {split_unit(n)[1] for n, _, _ in series if _is_truth(n)}
    units.discard("")
    if common:
        y_title = quantity_label(common)
        if not split_unit(common)[1]:
            y_title += " (unit not stated in the CSV)"
    else:
        y_title = f"value ({units.pop()})" if len(units) == 1 else "value (see legend)"
    fig = go.Figure(data=traces + refs)  # references last: on top
    fig.update_layout(
        title=title if measure is None else f"{title} · {quantity_label(measure, with_unit=False)}",
        height=420,
        xaxis_title=X_TITLES.get(x_col or "", x_col or "row"),
        yaxis_title=y_title,
    )
    return readable(fig)


# --------------------------------------------------------------------------------- running
def run_reproduction(
    key: str,
    runs: int | None,
    seed: int,
    on_progress: Callable[[int, int], None] | None = None,
) -> tuple[pd.DataFrame, dict[str, pd.DataFrame]]:
    """Run reproduction ``key`` into a temporary outdir: (tidy table, {csv name: curves})."""
    rep = REPRODUCTIONS[key]
    kwargs: dict[str, Any] = {"runs": runs, "seed": seed}
    if on_progress is not None and accepts(rep.run, "on_progress"):
        kwargs["on_progress"] = on_progress
    with tempfile.TemporaryDirectory(prefix=f"navlab-{key}-") as tmp:
        table = rep.run(outdir=Path(tmp), **kwargs)
        curves = {}
        for p in sorted(Path(tmp).rglob("*.csv")):
            try:
                curves[str(p.relative_to(tmp))] = pd.read_csv(p)
            except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError):
                continue
    return numeric_table(table), curves


# A small process-wide LRU cache instead of st.cache_data: the progress callback draws on a bar
# created outside the function, which st.cache_data cannot replay on a cache hit
# (CacheReplayClosureError). Entries are returned as copies, so callers cannot alter them.
_CACHE: OrderedDict[tuple[str, int | None, int], tuple[pd.DataFrame, dict[str, pd.DataFrame]]]
_CACHE = OrderedDict()
_CACHE_LOCK = threading.Lock()
CACHE_ENTRIES = 32


def _copy(v: tuple[pd.DataFrame, dict[str, pd.DataFrame]]):
    return v[0].copy(), {k: d.copy() for k, d in v[1].items()}


def is_cached(key: str, runs: int | None, seed: int) -> bool:
    with _CACHE_LOCK:
        return (key, runs, seed) in _CACHE


def cached_run(
    key: str, runs: int | None, seed: int, on_progress: Callable[[int, int], None] | None = None
) -> tuple[pd.DataFrame, dict[str, pd.DataFrame]]:
    """:func:`run_reproduction` cached by (reproduction, runs, seed) (LRU, process-wide)."""
    ck = (key, runs, seed)
    with _CACHE_LOCK:
        if ck in _CACHE:
            _CACHE.move_to_end(ck)
            return _copy(_CACHE[ck])
    value = run_reproduction(key, runs, seed, on_progress)
    with _CACHE_LOCK:
        _CACHE[ck] = value
        _CACHE.move_to_end(ck)
        while len(_CACHE) > CACHE_ENTRIES:
            _CACHE.popitem(last=False)
    return _copy(value)

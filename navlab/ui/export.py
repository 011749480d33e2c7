"""Publication export of navlab's charts: any Plotly figure as SVG or PNG in a clean print style.

Pure (no streamlit). The figure is redrawn with matplotlib from the Plotly figure object the page
shows (the same traces, colours, log axes and subplot layout), in a print style: 6.5 in wide
(a journal's text width), 9 pt sans-serif type, no hover or UI chrome, the legend below the
axes, text kept as text in the SVG (editable in a vector editor), PNG at 300 dpi.

Why matplotlib and not Plotly's own static export: Plotly's ``to_image`` needs kaleido, which
drives a Chrome/Chromium browser per export; the machine has /usr/bin/chromium but the container
image has none (it would add ≈ 400 MB and a browser process per export on a 2-core server). A
client-side export (Plotly.js in the browser) gives one format per chart only through the mode
bar and cannot restyle for print. matplotlib renders both formats in-process in ≈ 0.1–0.3 s,
deterministically, everywhere navlab runs (app, container, notebook, script): measured here
0.5–2 s for both formats of one chart (the first export of a process also loads the fonts).

Traces understood: scatter / scattergl (lines, markers, ``fill="tonexty"`` bands), bar, heatmap;
layout: titles and subtitles, subplot domains (``make_subplots``), log axes and explicit ticks,
axis ranges, subplot titles (annotations), vertical lines and x bands (shapes; not a player's
animated ones), error bars of type "data". Anything else is skipped.
"""

from __future__ import annotations

import io
import re
import threading
from typing import Any

import numpy as np
import plotly.graph_objects as go

WIDTH_IN = 6.5  # a journal's text width
DPI = 300
STYLE = {
    "font.family": "DejaVu Sans",
    "font.size": 9,
    "axes.titlesize": 9,
    "axes.labelsize": 9,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "legend.fontsize": 8,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.color": "#e6e6e6",
    "grid.linewidth": 0.6,
    "svg.fonttype": "none",  # text stays text in the SVG
    "figure.dpi": 100,
}
_LOCK = threading.Lock()  # rc_context is process-global: one export at a time
_DASH = {"solid": "-", "dash": "--", "dot": ":", "dashdot": "-.", "longdash": "--", "longdashdot": "-."}
_MARK = {
    "circle": "o",
    "circle-open": "o",
    "x": "x",
    "diamond": "D",
    "diamond-open": "D",
    "square": "s",
    "square-open": "s",
    "triangle-up": "^",
    "cross": "P",
}


def plain(text: Any) -> str:
    """Plotly's title HTML as plain text (``<br>`` → new line, tags dropped)."""
    if not text:
        return ""
    s = re.sub(r"<br\s*/?>", "\n", str(text))
    return re.sub(r"<[^>]+>", "", s).strip()


def _color(c: Any, default: str = "#333333") -> Any:
    """A Plotly colour string as a matplotlib colour (``rgba(r,g,b,a)`` included)."""
    if c is None or isinstance(c, (list, tuple, np.ndarray)):
        return default
    s = str(c).strip()
    m = re.fullmatch(r"rgba?\(([^)]*)\)", s)
    if m:
        v = [float(x) for x in m.group(1).split(",")]
        rgb = [x / 255.0 for x in v[:3]]
        return (*rgb, v[3] if len(v) > 3 else 1.0)
    return s


def _arr(v: Any) -> np.ndarray:
    if v is None:
        return np.zeros(0)
    a = np.asarray(v)
    if a.dtype.kind in "US" or a.dtype == object:
        try:
            return a.astype(float)
        except (TypeError, ValueError):
            return a
    return a.astype(float)


def _axis_name(ref: str | None, letter: str) -> str:
    """'x2' → 'xaxis2', None/'x' → 'xaxis'."""
    ref = ref or letter
    return f"{letter}axis{ref[1:]}"


def _domains(layout: go.Layout, pairs: list[tuple[str, str]]) -> dict[tuple[str, str], tuple]:
    out = {}
    for xr, yr in pairs:
        xa, ya = layout[_axis_name(xr, "x")], layout[_axis_name(yr, "y")]
        xd = tuple(xa.domain) if xa.domain else (0.0, 1.0)
        yd = tuple(ya.domain) if ya.domain else (0.0, 1.0)
        out[(xr, yr)] = (xd, yd)
    return out


def _apply_axis(ax: Any, layout: go.Layout, name: str, which: str) -> None:
    a = layout[name]
    log = a.type == "log"
    if log:
        (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    if a.range is not None and all(v is not None for v in a.range):
        lo, hi = (float(v) for v in a.range)
        if log:
            lo, hi = 10.0**lo, 10.0**hi
        (ax.set_xlim if which == "x" else ax.set_ylim)(lo, hi)
    if a.tickvals is not None:
        vals = list(a.tickvals)
        (ax.set_xticks if which == "x" else ax.set_yticks)(vals)
        if a.ticktext is not None:
            (ax.set_xticklabels if which == "x" else ax.set_yticklabels)(list(a.ticktext))
    title = plain(a.title.text) if a.title is not None else ""
    if title:
        (ax.set_xlabel if which == "x" else ax.set_ylabel)(title)


def _draw_scatter(ax: Any, tr: Any, prev: dict[Any, np.ndarray]) -> None:
    x, y = _arr(tr.x), _arr(tr.y)
    if not x.size or x.shape != y.shape:
        return
    mode = tr.mode or "lines"
    line = tr.line
    color = _color(line.color if line is not None else None)
    label = plain(tr.name) if tr.showlegend is not False and tr.name else "_nolegend_"
    key = id(ax)
    if tr.fill == "tonexty" and key in prev:
        px, py = prev[key]
        if px.shape == x.shape:
            ax.fill_between(x, py, y, color=_color(tr.fillcolor, "#cccccc"), linewidth=0, label=label)
            prev[key] = (x, y)
            return
    prev[key] = (x, y)
    width = float(line.width) if line is not None and line.width is not None else 2.0
    if "lines" in mode and width > 0:
        ax.plot(
            x,
            y,
            color=color,
            linewidth=width * 0.55,
            linestyle=_DASH.get(line.dash or "solid", "-") if line is not None else "-",
            label=label,
            drawstyle="steps-mid" if line is not None and line.shape in ("hv", "vh", "hvh") else "default",
        )
        label = "_nolegend_"
    if "markers" in mode:
        mk = tr.marker
        sym = str(mk.symbol) if mk is not None and mk.symbol is not None else "circle"
        mcol = _color(mk.color if mk is not None else None, color if isinstance(color, str) else "#333333")
        size = float(mk.size) if mk is not None and mk.size is not None else 6.0
        ax.plot(
            x,
            y,
            linestyle="none",
            marker=_MARK.get(sym, "o"),
            markersize=size * 0.55,
            markerfacecolor="none" if sym.endswith("-open") else mcol,
            markeredgecolor=mcol,
            label=label,
        )
    _draw_errors(ax, tr, x, y, color)


def _error(e: Any, n: int) -> np.ndarray | None:
    """A Plotly ``error_x`` / ``error_y`` of type "data" as matplotlib's (2, n) minus/plus array
    (None for another type, invisible bars or a length that does not match the points).
    """
    if e is None or e.type != "data" or e.visible is False or e.array is None:
        return None
    plus = _arr(e.array)
    minus = plus if e.symmetric is not False or e.arrayminus is None else _arr(e.arrayminus)
    if plus.shape != (n,) or minus.shape != (n,) or plus.dtype.kind != "f" or minus.dtype.kind != "f":
        return None
    return np.vstack([np.nan_to_num(minus), np.nan_to_num(plus)])


def _draw_errors(ax: Any, tr: Any, x: np.ndarray, y: np.ndarray, color: Any) -> None:
    """The trace's error bars of type "data" (Sweep's 95 % intervals, the claims' ranges)."""
    for e, which in ((tr.error_y, "y"), (tr.error_x, "x")):
        err = _error(e, x.size)
        if err is None:
            continue
        thick = float(e.thickness) if e.thickness is not None else 2.0
        ax.errorbar(
            x,
            y,
            **{f"{which}err": err},
            fmt="none",
            ecolor=_color(e.color, color if isinstance(color, str) else "#333333"),
            elinewidth=thick * 0.55,
            capsize=float(e.width) * 0.5 if e.width is not None else 1.5,
            label="_nolegend_",
        )


def _draw_bar(ax: Any, tr: Any) -> None:
    x, y = _arr(tr.x), _arr(tr.y)
    if not x.size or x.dtype.kind not in "fi":
        return
    w = float(np.min(np.diff(np.unique(x)))) * 0.8 if np.unique(x).size > 1 else 0.8
    mk = tr.marker
    c = mk.color if mk is not None else None
    colors = [_color(v) for v in c] if isinstance(c, (list, tuple, np.ndarray)) else _color(c, "#1f77b4")
    label = plain(tr.name) if tr.showlegend is not False and tr.name else "_nolegend_"
    ax.bar(x, y, width=w, color=colors, linewidth=0, label=label)


def _draw_heatmap(fig: Any, ax: Any, tr: Any) -> None:
    z = np.asarray(tr.z, dtype=float)
    if z.ndim != 2:
        return
    x = _arr(tr.x) if tr.x is not None else np.arange(z.shape[1], dtype=float)
    y = _arr(tr.y) if tr.y is not None else np.arange(z.shape[0], dtype=float)
    cat_x, cat_y = x.dtype.kind not in "fi", y.dtype.kind not in "fi"
    xs = np.arange(z.shape[1]) if cat_x else x
    ys = np.arange(z.shape[0]) if cat_y else y
    mesh = ax.pcolormesh(xs, ys, np.ma.masked_invalid(z), shading="nearest", cmap="viridis")
    if cat_x:
        ax.set_xticks(xs, [str(v) for v in x])
    if cat_y:
        ax.set_yticks(ys, [str(v) for v in y])
    cb = fig.colorbar(mesh, ax=ax, fraction=0.05, pad=0.02)
    title = tr.colorbar.title.text if tr.colorbar is not None and tr.colorbar.title is not None else ""
    if title:
        cb.set_label(plain(title))
    ax.grid(False)


def _axis_pairs(fig: go.Figure) -> list[tuple[str, str]]:
    """The (x, y) axis pairs the traces are drawn on, in the order of the traces (at least one)."""
    pairs: list[tuple[str, str]] = []
    for tr in fig.data:
        p = (getattr(tr, "xaxis", None) or "x", getattr(tr, "yaxis", None) or "y")
        if p not in pairs:
            pairs.append(p)
    return pairs or [("x", "y")]


def _subplots(layout, pairs: list[tuple[str, str]], dom: dict, width_in: float):
    """A matplotlib Figure with one subplot per axis pair on the grid of the Plotly domains (an
    x axis that matches or is anchored shares the first subplot's): (figure, {pair: axes}).
    """
    from matplotlib.figure import Figure
    from matplotlib.gridspec import GridSpec

    rows = sorted({d[1] for d in dom.values()}, key=lambda d: -d[1])  # top first
    cols = sorted({d[0] for d in dom.values()})
    height_px = float(layout.height or 420)
    height_in = max(2.2, min(9.0, width_in * height_px / 1000 * (1.15 if len(rows) > 1 else 1.0)))
    mfig = Figure(figsize=(width_in, height_in), layout="constrained")
    gs = GridSpec(
        len(rows),
        len(cols),
        figure=mfig,
        height_ratios=[max(0.05, r[1] - r[0]) for r in rows],
        width_ratios=[max(0.05, c[1] - c[0]) for c in cols],
    )
    axes: dict[tuple[str, str], Any] = {}
    by_x: dict[str, Any] = {}
    for p in pairs:
        xd, yd = dom[p]
        anchor = layout[_axis_name(p[0], "x")].matches or layout[_axis_name(p[0], "x")].anchor
        share = by_x.get(p[0]) if anchor else None
        ax = mfig.add_subplot(gs[rows.index(yd), cols.index(xd)], sharex=share)
        by_x.setdefault(p[0], ax)
        axes[p] = ax
    return mfig, axes


def _draw_traces(mfig, fig: go.Figure, axes: dict) -> None:
    """Every visible scatter, bar and heatmap trace on its subplot."""
    prev: dict[Any, Any] = {}
    for tr in fig.data:
        if tr.visible is False:
            continue
        ax = axes[(getattr(tr, "xaxis", None) or "x", getattr(tr, "yaxis", None) or "y")]
        kind = tr.type
        if kind in ("scatter", "scattergl"):
            _draw_scatter(ax, tr, prev)
        elif kind == "bar":
            _draw_bar(ax, tr)
        elif kind == "heatmap":
            _draw_heatmap(mfig, ax, tr)


def _style_axes(layout, axes: dict, dom: dict) -> None:
    """The Plotly axes' titles, ranges and scales; per x axis only the lowest subplot on the page
    carries its title and tick labels.
    """
    lowest = {}
    for xr, yr in axes:
        if xr not in lowest or dom[(xr, yr)][1][0] < dom[lowest[xr]][1][0]:
            lowest[xr] = (xr, yr)
    for (xr, yr), ax in axes.items():
        _apply_axis(ax, layout, _axis_name(xr, "x"), "x")
        _apply_axis(ax, layout, _axis_name(yr, "y"), "y")
        if lowest[xr] != (xr, yr):
            ax.set_xlabel("")
            ax.tick_params(labelbottom=False)


def _draw_shapes(fig: go.Figure, axes: dict) -> None:
    """Vertical lines and x bands across the plot; a player's shapes (the frames move them: its
    cursor and veil) are not part of a still figure.
    """
    layout = fig.layout
    for sh in () if fig.frames else layout.shapes or ():
        xr = (sh.xref or "x").split(" ")[0]
        across = (sh.yref or "y").split(" ")[-1] in ("paper", "domain")
        targets = [ax for (axr, _), ax in axes.items() if axr == xr]
        if sh.type == "line" and sh.x0 is not None and sh.x0 == sh.x1:
            for ax in targets:
                ax.axvline(float(sh.x0), color=_color(sh.line.color, "#f0a500"), linewidth=1, alpha=0.6)
        elif sh.type == "rect" and across and sh.x0 is not None and sh.x1 is not None:
            c = _color(sh.fillcolor, "#cccccc")
            alpha = float(sh.opacity) if sh.opacity is not None else None
            for ax in targets:
                ax.axvspan(float(sh.x0), float(sh.x1), color=c, alpha=alpha, linewidth=0, zorder=0)


def _titles(mfig, layout, axes: dict, dom: dict) -> None:
    """Subplot titles (annotations at the top of a domain) on their axes; the main title above."""
    for an in layout.annotations or ():
        if an.xref == "paper" and an.yref == "paper" and an.text:
            best = min(
                axes.items(),
                key=lambda kv: (
                    abs(dom[kv[0]][1][1] - float(an.y or 0)) + abs(sum(dom[kv[0]][0]) / 2 - float(an.x or 0))
                ),
            )
            best[1].set_title(plain(an.text), loc="left", fontsize=8.5)
    title = plain(layout.title.text) if layout.title is not None else ""
    if title:
        head, *sub = title.split("\n")
        mfig.suptitle(head + ("\n" + "\n".join(sub) if sub else ""), x=0.01, ha="left", fontsize=10)


def _legend(mfig, layout, axes: dict) -> None:
    """One legend below the figure for every subplot's labelled artists (each label once)."""
    handles, labels = [], []
    for ax in axes.values():
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab and not lab.startswith("_") and lab not in labels:
                handles.append(h)
                labels.append(lab)
    if handles and layout.showlegend is not False:
        mfig.legend(handles, labels, loc="outside lower center", ncols=min(3, len(labels)), frameon=False)


def publication(fig: go.Figure, width_in: float = WIDTH_IN) -> Any:
    """The matplotlib Figure of Plotly ``fig`` in the print style (call under :data:`_LOCK`)."""
    layout = fig.layout
    pairs = _axis_pairs(fig)
    dom = _domains(layout, pairs)
    mfig, axes = _subplots(layout, pairs, dom, width_in)
    _draw_traces(mfig, fig, axes)
    _style_axes(layout, axes, dom)
    _draw_shapes(fig, axes)
    _titles(mfig, layout, axes, dom)
    _legend(mfig, layout, axes)
    return mfig


def render(fig: go.Figure, fmt: str, width_in: float = WIDTH_IN) -> bytes:
    """``fig`` as publication ``fmt`` ("svg" or "png") bytes."""
    import matplotlib

    if fmt not in ("svg", "png"):
        raise ValueError(f"format must be svg or png, got {fmt!r}")
    with _LOCK, matplotlib.rc_context(STYLE):
        mfig = publication(fig, width_in)
        buf = io.BytesIO()
        mfig.savefig(buf, format=fmt, dpi=DPI, metadata={"Date": None} if fmt == "svg" else None)
    return buf.getvalue()


def to_svg(fig: go.Figure) -> bytes:
    """Publication SVG of ``fig``."""
    return render(fig, "svg")


def to_png(fig: go.Figure) -> bytes:
    """Publication PNG (300 dpi) of ``fig``."""
    return render(fig, "png")


def save(fig: go.Figure, path: str) -> None:
    """Write ``fig`` to ``path`` as SVG or PNG (by the file's extension)."""
    fmt = str(path).rsplit(".", 1)[-1].lower()
    with open(path, "wb") as f:
        f.write(render(fig, fmt))

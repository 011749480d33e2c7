"""Result views shared by pages: live-updating chart/table panels and view-only controls.

A view is created (placeholders laid out) before a run starts and its :meth:`render` is called
with the accumulated results after every chunk, so curves and tables fill in while the Monte Carlo
runs. View controls (which error group, which channel, log scale) are ordinary widgets created on
the first render; changing one reruns the page, which finds the finished results in the store and
only redraws (no recomputation).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import streamlit as st

from navlab import tables
from navlab.diagnostics import FLAG_KINDS, explain
from navlab.metrics import summary
from navlab.pcrb import floor_text
from navlab.scenarios import scenario_registry
from navlab.ui import figures as F

if TYPE_CHECKING:
    from navlab.experiment import Results

PLOTLY_CONFIG = {"displaylogo": False, "toImageButtonOptions": {"format": "png", "scale": 2}}
PRESENT_HEIGHT = 700  # px: one chart fills a projector screen below its title


PRESENT_FONT = 20  # px: the smallest type of a chart on a projector (axis labels, legend, subtitles)


def present_style(fig: Any) -> Any:
    """A copy of ``fig`` sized and lettered for a projector (presentation mode): every text at
    least ``PRESENT_FONT`` px — titles, subtitles, axis labels, legends, panel titles.
    """
    import re

    import plotly.graph_objects as go

    from navlab.ui.figures import SUBTITLE_FONT

    out = go.Figure(fig)
    out.update_layout(
        height=max(PRESENT_HEIGHT, int(fig.layout.height or 0)),
        font={"size": PRESENT_FONT},
        legend={"font": {"size": PRESENT_FONT}},
    )
    if out.layout.title.text:
        small = f"font-size:{SUBTITLE_FONT['size']}px"
        text = re.sub(re.escape(small), f"font-size:{PRESENT_FONT}px", out.layout.title.text)
        out.update_layout(title={"text": text, "font": {"size": PRESENT_FONT + 6}})
    out.update_annotations(font_size=PRESENT_FONT)
    return out


def _slug(text: str) -> str:
    import re

    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:60] or "figure"


def chart(container: Any, fig: Any, alt: str, *, key: str | None = None, name: str | None = None) -> None:
    """``st.plotly_chart`` with navlab's defaults, and the chart's publication downloads (SVG and
    PNG, :mod:`navlab.ui.export`, made only when clicked) below it; in presentation mode the
    chart is sized for a screen and the downloads are left out.
    """
    from navlab.ui.frame import next_chart_id, presenting

    present = presenting()
    dl_key = key or next_chart_id()
    with container.container():
        st.plotly_chart(
            present_style(fig) if present else fig,
            width="stretch",
            config=PLOTLY_CONFIG,
            theme=None,
            alt=alt,
            key=key,
        )
        if not present:
            figure_downloads(fig, name or _slug(alt), dl_key)


def figure_downloads(fig: Any, name: str, key: str) -> None:
    """Two small download buttons (publication SVG and PNG of ``fig``), rendered on click only."""
    from navlab.ui import export

    base = f"navlab-{_slug(name)}"
    row = st.container(horizontal=True, gap="medium")  # sized to their labels: no "P…" in a narrow column
    for fmt, mime in (("svg", "image/svg+xml"), ("png", "image/png")):
        row.download_button(
            f"{fmt.upper()}",
            (lambda f=fmt: export.render(fig, f)),
            file_name=f"{base}.{fmt}",
            mime=mime,
            key=f"{key}_{fmt}",
            on_click="ignore",
            icon=":material/download:",
            help=f"this chart as {fmt.upper()} in a print style (6.5 in wide, legend below, no UI)",
            type="tertiary",
        )


def divergence_warnings(res: Results, container: Any = None) -> None:
    """One warning naming the filters that lost runs to divergence (rule in the table notes)."""
    c = container if container is not None else st
    jd = summary(res).judgement
    notes = []
    for key, fr in res.runs.items():
        lost = jd.lost(key)
        if not lost:
            continue
        first = int(np.min(fr.diverged_at[fr.diverged_at >= 0]))
        what = "left out for every filter" if jd.reliable[key] else "more than 5 %: ranks below"
        notes.append(f"**{fr.label}**: {lost}/{jd.n_runs} runs (first at epoch {first}; {what})")
    if notes:
        c.warning(
            f"Diverged runs — the curves and numbers use the {int(jd.common.sum())} runs every "
            "reliable filter kept: " + "; ".join(notes)
        )


def headline_groups(res: Results) -> list[str]:
    """The scenario's headline error groups that exist in the data (else all groups)."""
    try:
        want = scenario_registry()[res.spec.scenario].headline
    except KeyError:
        want = ()
    got = [g for g in want if g in res.data.groups]
    return got or list(res.data.groups)


def channel_label(res: Results, ch: int) -> str:
    d = res.data
    name = d.channel_names[ch] if ch < len(d.channel_names) else str(ch)
    unit = d.channel_units[ch] if ch < len(d.channel_units) else ""
    return f"{ch}: {name}" + (f" ({unit})" if unit else "")


def show_stored(view: Any, spec: Any) -> Results | None:
    """Without a Run: draw this configuration's cached or interrupted results into ``view`` (a
    CompareView or NoiseView), or invite a Run under a preview of the noise schedule.
    """
    from navlab.ui.runner import cached_results, partial_results

    res = cached_results(spec) or partial_results(view.page, spec)
    if res is None:
        view.status.info("Press **Run** to simulate this configuration.")
        chart(view.preview, F.schedule_preview(spec), "noise schedule preview")
        return None
    view.render(res)
    if not res.complete:
        st.info(f"Stopped after {res.done_runs} of {spec.runs} runs: press Run to continue.")
    return res


class CompareView:
    """Error vs time, RMSE table, true R(t) vs R̂, NIS vs χ² — laid out once, redrawn per chunk."""

    def __init__(self, page: str) -> None:
        self.page = page
        self.controls = st.container()
        self.status = st.empty()
        self.preview = st.empty()
        self.err = st.empty()
        st.markdown("##### Summary over the analysis window")
        self.table = st.empty()
        self.notes = st.empty()
        # one below the other, full width: the R̂ chart has a panel per filter beyond three
        self.rhat = st.empty()
        self.nis = st.empty()
        self._made = False
        self.group = self.channel = self.ref = None
        self.log_err = False
        self.log_r = True
        self.as_std = False
        self.live = False  # set by the page while run_live streams chunks

    def _controls(self, res: Results) -> None:
        if self._made:
            return
        self._made = True
        # widths: "σ not R" and its help icon uncut at 1440 px
        c1, c2, c3, c4, c5, c6 = self.controls.columns([2, 1, 2, 1.3, 1, 2])
        keys = list(res.runs)
        self.ref = c6.selectbox(
            "Compare to",
            keys,
            index=keys.index("kf") if "kf" in keys else 0,
            format_func=lambda k: res.runs[k].label if k in res.runs else k,
            key=f"{self.page}_v_ref",
            help="reference filter of the paired test: each other filter is better, worse or "
            "indistinguishable from it over the same runs (Holm-corrected, 95 %)",
        )
        groups = list(res.data.groups)
        first = headline_groups(res)[0]
        self.group = c1.selectbox(
            "Error of",
            groups,
            index=groups.index(first),
            format_func=lambda g: f"{res.data.groups[g].label} ({res.data.groups[g].unit})",
            key=f"{self.page}_v_group",
        )
        self.log_err = c2.toggle("log error", key=f"{self.page}_v_logerr")
        m = res.data.z.shape[2]
        self.channel = c3.selectbox(
            "R̂ channel",
            list(range(m)),
            format_func=lambda ch: channel_label(res, ch),
            key=f"{self.page}_v_ch",
        )
        self.as_std = c4.toggle(
            "σ not R", key=f"{self.page}_v_std", help="show standard deviations instead of variances"
        )
        self.log_r = c5.toggle(
            "log R", value=True, key=f"{self.page}_v_logr", help="off: a linear axis for R̂ and the true R(t)"
        )

    def render(self, res: Results) -> None:
        self._controls(res)
        state = "complete" if res.complete else "partial"
        self.status.caption(
            f"{res.done_runs}/{res.spec.runs} runs ({state}) · {res.elapsed_s:.2f} s compute · "
            f"scenario `{res.spec.scenario}`, {res.data.K} epochs"
        )
        group = self.group if self.group in res.data.groups else headline_groups(res)[0]
        chart(
            self.err,
            F.error_vs_time(res, group, log_y=self.log_err, floor=res.complete),
            "RMSE over time per filter with spread bands",
        )
        show_table(self.table, self.notes, res, self.ref)
        if not res.complete and self.live:
            # while chunks stream, only the error curves and the table update: fewer browser
            # redraws, so the first chart appears sooner
            self.rhat.caption("R̂ against the true R(t): drawn when the run completes")
            self.nis.caption("NIS against its χ² band: drawn when the run completes")
            return
        ch = self.channel if self.channel is not None and self.channel < res.data.z.shape[2] else 0
        rhat_chart(self.rhat, res, ch, F.r_vs_rhat(res, ch, log_y=self.log_r, as_std=self.as_std))
        chart(self.nis, F.nis_vs_chi2(res), "average NIS against its chi-square band")


def rhat_chart(slot: Any, res: Results, channel: int, fig: Any, key: str | None = None) -> None:
    """The R̂ chart in ``slot`` with the sentence that says what to look at under it
    (:func:`navlab.diagnostics.rhat_sentence`, computed from this run).
    """
    from navlab.diagnostics import rhat_sentence

    with slot.container():
        chart(st, fig, "true R(t) against each filter's R-hat", key=key, name="rhat")
        if res.complete:
            what = rhat_sentence(res, channel)
            st.markdown(f"**What to look at.** {what}" if what else no_rhat())


def show_table(table: Any, notes: Any, res: Results, ref: str | None = None) -> None:
    """The headline table with intervals and the paired verdicts against ``ref``, and its notes."""
    ref = ref if ref in res.runs else None
    t = tables.headline(
        res,
        compare_to=ref if len(res.runs) > 1 else None,
        explanations=False,
        best=res.complete,
        floor=False,  # shown as its own paragraph below
    )
    # a static table: it wraps its cells to the page's width, so the verdict column is never
    # scrolled out of sight (a data grid sized its columns to their text and scrolled sideways)
    table.table(highlight_best(t))
    with notes.container():
        if res.complete and len(res.runs) > 1:
            st.caption(
                "**Bold on green**: among the non-oracle filters (on the outlier-flag columns: "
                "those that flag outliers), the one better than every other on that column "
                "(paired test over the same runs, Holm-corrected, 95 %)"
                + ("" if t.best else " — no column has one at this run count")
                + "; no highlight where the best point estimate is not backed by the test."
            )
        if res.complete:
            floor = floor_text(res, headline_groups(res)[0])
            if floor:
                st.markdown(floor)
        divergence_warnings(res)
        for e in explain(res, kinds=FLAG_KINDS):  # divergence: above
            st.info(e.markdown(), icon=":material/lightbulb:")
        st.caption("  \n".join(t.notes))
        with st.expander("What each column means"):
            st.caption("  \n".join(f"**{c}**: {h}" for c, h in t.help.items() if h))


def no_rhat() -> str:
    """What to do when no chosen filter estimates R."""
    from navlab.filters import registry

    est = [f"`{k}`" for k, c in registry().items() if c.estimates_R and c.family != "oracle"]
    return f"None of the chosen filters estimates R: add one that does ({', '.join(est)}) to see R̂."


BEST_STYLE = "font-weight: bold; background-color: #dcf2e1"


def highlight_best(t: Any) -> Any:
    """The table's cells with each column's tested best filter highlighted (a pandas Styler)."""
    cells = t.cells

    def col_style(col: Any) -> list[str]:
        who = t.best.get(col.name)
        return [BEST_STYLE if who is not None and row == who else "" for row in col.index]

    return cells.style.apply(col_style, axis=0) if t.best else cells


def outlier_summary(res: Results, ch: int) -> str:
    """One line on the outlier epochs of channel ``ch`` (for captions)."""
    frac = res.data.outlier_mask[:, :, ch].mean(axis=0)
    if not frac.any():
        return f"no outliers on this channel (outlier model `{res.spec.outliers}`)"
    ep = F.outlier_epochs(res, ch)
    share = float(res.data.outlier_mask[:, 1:, ch].mean())
    s = f"{100 * share:.1f} % of measurements contaminated"
    if ep.size:
        shown = ", ".join(map(str, ep[:12].tolist())) + (" …" if ep.size > 12 else "")
        s += f"; epochs contaminated in most runs: {shown}"
    return s


def rhat_error_table(res: Results) -> Any:
    """Per filter and channel: |σ̂/σ − 1| (%) against the σ the noise was drawn with, on clean
    epochs of the analysis window — each run's mean, then their mean over the judged runs with a
    95 % t interval over the runs (filters with R̂ only; — for a channel with no clean entry).
    """
    import pandas as pd

    from navlab.stats import mean_ci

    d = res.data
    W = np.asarray(d.window, dtype=bool)
    jd = summary(res).judgement
    rows = []
    for key, fr in res.runs.items():
        if fr.R_hat is None:
            continue
        ok = jd.judged[key]
        row = {"filter": fr.label}
        clean = ~d.outlier_mask[ok][:, W] & np.isfinite(d.z[ok][:, W])
        with np.errstate(all="ignore"):
            err = np.abs(np.sqrt(fr.R_hat[ok][:, W] / d.R_true[ok][:, W]) - 1.0)
        for ch in range(d.z.shape[2]):
            use = clean[..., ch] & np.isfinite(err[..., ch])
            n = use.sum(axis=1)
            per_run = np.add.reduce(np.where(use, err[..., ch], 0.0), axis=1)[n > 0] / n[n > 0]
            e = mean_ci(100 * per_run)
            row[channel_label(res, ch)] = tables.cell(e.value, e.lo, e.hi) or "—"
        rows.append(row)
    return pd.DataFrame(rows).set_index("filter") if rows else pd.DataFrame()


class NoiseView:
    """R̂ inspection: per channel, true R(t) vs each filter's R̂ (median + band), outlier epochs
    marked on the time axis, and the R̂ error metric — laid out once, redrawn per chunk.
    """

    def __init__(self, page: str) -> None:
        self.page = page
        self.controls = st.container()
        self.status = st.empty()
        self.preview = st.empty()
        self.fig = st.empty()
        self.outliers = st.empty()
        st.markdown(
            "##### R̂ error on clean epochs: mean |σ̂/σ − 1| against the σ the noise was drawn with (%)"
        )
        self.table = st.empty()
        self.notes = st.empty()
        st.markdown(
            "##### Filter internals: fading factors, test statistics against their "
            "thresholds, VB iterations, replaced measurements"
        )
        self.internals_ctrl = st.container()
        self.internals = st.empty()
        self._made = False
        self.channel = 0
        self.stat = None
        self._drawn = 0
        self.as_std = False
        self.log_r = True
        self.show_used = True

    def _controls(self, res: Results) -> None:
        if self._made:
            return
        self._made = True
        c1, c2, c3, c4 = self.controls.columns([3, 1, 1, 2])
        m = res.data.z.shape[2]
        self.channel = c1.selectbox(
            "Channel", list(range(m)), format_func=lambda ch: channel_label(res, ch), key=f"{self.page}_v_ch"
        )
        self.as_std = c2.toggle(
            "σ not R", key=f"{self.page}_v_std", help="show standard deviations instead of variances"
        )
        self.log_r = c3.toggle(
            "log scale",
            value=True,
            key=f"{self.page}_v_log",
            help="off: a linear axis for R̂ and the true R(t)",
        )
        self.show_used = c4.toggle("R used by non-adaptive filters", value=True, key=f"{self.page}_v_used")
        stats = F.internal_stats(res)
        if stats:
            self.stat = self.internals_ctrl.selectbox("Statistic", stats, key=f"{self.page}_v_stat")

    def _chart(self, container: Any, fig: Any, name: str) -> None:
        # a streamed run renders once per chunk in the same script run, and the figures of two
        # chunks can be identical (no filter estimates R): the key keeps the element ids unique
        chart(container, fig, name, key=f"{self.page}_{name}_{self._drawn}", name=name)

    def render(self, res: Results) -> None:
        self._controls(res)
        self._drawn += 1
        state = "complete" if res.complete else "partial"
        self.status.caption(f"{res.done_runs}/{res.spec.runs} runs ({state}) · {res.elapsed_s:.2f} s compute")
        ch = self.channel if self.channel is not None and self.channel < res.data.z.shape[2] else 0
        # the outlier strip only where there are outliers to mark (else an empty panel)
        strip = bool(res.data.outlier_mask[:, :, ch].any())
        fig = F.r_vs_rhat(
            res, ch, log_y=self.log_r, as_std=self.as_std, show_used=self.show_used, outlier_strip=strip
        )
        rhat_chart(self.fig, res, ch, fig, key=f"{self.page}_rhat_{self._drawn}")
        self.outliers.caption("Outliers on this channel: " + outlier_summary(res, ch))
        tab = rhat_error_table(res)
        if tab.empty:
            self.table.info(no_rhat())
        else:
            with self.table.container():
                st.table(tab)
                st.caption(
                    "Each run's mean over the clean epochs of the analysis window, then the mean "
                    "over the judged runs with its 95 % t interval over the runs; outlier epochs "
                    "are left out (their own number is in the Compare table's tidy download, "
                    "rhat_err_contaminated_pct). —: no clean measurement on the channel."
                )
        with self.notes.container():
            divergence_warnings(res)
            for e in explain(res, kinds=FLAG_KINDS):  # divergence: above
                st.info(e.markdown(), icon=":material/lightbulb:")
        if self.stat is None:
            self.internals.caption("None of the chosen filters reports per-step statistics.")
        elif res.complete:  # drawn once the run is complete (fewer browser redraws)
            self._chart(self.internals, F.internals_vs_time(res, self.stat, ch), "internals")


def noise_preset() -> dict[str, Any]:
    """The Noise page's suggestion: a step in σ plus isolated outliers, the KF, the oracle and
    (up to 4) filters that estimate R, 50 runs.
    """
    from navlab.filters import registry

    reg = registry()
    est = [k for k, c in reg.items() if c.estimates_R and k != "oracle-kf"][:4]
    filters = [k for k in ("kf", "oracle-kf", *est) if k in reg]
    return {"flt": filters, "runs": 50, "noise": "step", "out": "isolated"}


def _apply_preset(values: dict[str, Any]) -> None:
    for k, v in values.items():
        st.session_state[k] = v


def noise_preset_button(spec: Any, container: Any) -> None:
    """A button that sets the experiment to :func:`noise_preset` (every page keeps the same
    defaults, so the Noise page's suggestion is a button, not a different default).
    """
    pre = noise_preset()
    same = (
        spec.noise_schedule == pre["noise"]
        and spec.outliers == pre["out"]
        and list(spec.filters) == pre["flt"]
        and spec.runs == pre["runs"]
    )
    container.button(
        "Try: σ step + isolated outliers",
        key="noise_preset",
        on_click=_apply_preset,
        args=(pre,),
        disabled=same,
        help="a step in the true σ and isolated outliers, with the KF, the oracle and filters that "
        "estimate R (" + ", ".join(pre["flt"]) + "), 50 runs",
    )


def run_downloads(res: Results, view: CompareView, group: str, page: str) -> None:
    """A finished run's downloads on one line: the metric table and the RMSE per epoch (CSV), the
    headline table for a paper (LaTeX booktabs, Markdown: navlab.tables.run_table, as ``navlab run
    --format``), and a notebook and a script that re-run the experiment and redraw the figures.
    """
    from navlab.notebook import default_figures, notebook, script
    from navlab.ui.share import csv_download, text_download

    spec = res.spec
    figs = default_figures(group, view.channel or 0)
    row = st.container(horizontal=True)  # each button as wide as its label: none is cut
    csv_download(
        lambda: tables.summary_rows(res, compare_to=view.ref),
        "Metrics (CSV)",
        "navlab-metrics.csv",
        f"dl_metrics_{page}",
        container=row,
    )
    csv_download(
        lambda: F.rmse_curves(res),
        "RMSE per epoch (CSV)",
        "navlab-rmse-per-epoch.csv",
        f"dl_curves_{page}",
        container=row,
    )
    for fmt, label, name, mime in (
        ("latex", "Table (LaTeX)", "navlab-table.tex", "application/x-tex"),
        ("markdown", "Table (Markdown)", "navlab-table.md", "text/markdown"),
    ):
        text_download(
            lambda fmt=fmt: tables.run_table(res, fmt, compare_to=view.ref),
            label,
            name,
            f"dl_{fmt}_{page}",
            mime,
            "the headline table for a paper: each value with its 95 % interval, the best in bold only "
            "where the paired test backs it, a caption naming the runs, seeds and interval method"
            + (" (LaTeX: needs \\usepackage{booktabs})" if fmt == "latex" else ""),
            container=row,
        )
    for make, label, name, key, mime, what in (
        (
            notebook,
            "Notebook (.ipynb)",
            "navlab-run.ipynb",
            "nb",
            "application/x-ipynb+json",
            "a Jupyter notebook that re-runs this experiment with navlab and redraws these figures",
        ),
        (
            script,
            "Script (.py)",
            "navlab-run.py",
            "py",
            "text/x-python",
            "a Python script that re-runs this experiment and writes the figures as SVG and PNG",
        ),
    ):
        text_download(
            lambda make=make: make(spec, figs), label, name, f"dl_{key}_{page}", mime, what, container=row
        )

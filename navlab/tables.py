"""Display tables: the headline metrics of an experiment as text cells with their intervals, the
paired verdicts against a reference filter, and the footnotes that say how the numbers were made.

Pure (no streamlit): the CLI prints :func:`headline` as text, the app shows the same table.
Cells hold three significant figures, "value [lo, hi]" where an interval exists; a cell that does
not apply is empty and its reason is in a footnote — never ``NaN`` or ``None``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from navlab import metrics as M
from navlab import stats as S
from navlab.filters import is_oracle
from navlab.scenarios.base import scenario_registry

if TYPE_CHECKING:
    from navlab.experiment import Results

NAMES = {
    "anees": "ANEES",
    "anis": "ANIS",
    "nlpd": "NLPD (nats)",
    "rhat_err_pct": "R̂ error, clean epochs (%)",
    "rhat_err_contaminated_pct": "R̂ error, outlier epochs (%)",
    "detected_pct": "outliers flagged (%)",
    "false_alarm_pct": "false alarms (%)",
    "band_pct": "R̂ at its band (%)",
    "numfix_pct": "numerical fixes (%)",
    "diverged": "diverged runs",
    "us_per_run_step": "µs per run·step",
    "h_err_median": "median horizontal error (m)",
    "h_err_p90": "90 % horizontal error (m)",
}
HELP = {
    "anees": "average NEES over runs and window epochs; a consistent filter reads the state "
    "dimension, inside the χ² band",
    "anis": "average NIS; a consistent filter reads the measurement dimension",
    "nlpd": "negative log predictive density of each measurement under the filter's own model "
    "before it is used, per measurement (lower is better; needs no truth: a score for choosing "
    "hyper-parameters on a real recording; only filters that state their predictive density)",
    "rhat_err_pct": "mean |σ̂/σ − 1| of the filter's R̂ against the σ the noise was drawn with, "
    "on clean epochs",
    "detected_pct": "share of contaminated measurements the filter flagged as outliers (codes 1–5)",
    "false_alarm_pct": "share of clean measurements flagged as outliers (codes 1–5)",
    "band_pct": "share of measurements where the filter's R̂ was held at a bound of its band "
    "[r_min, r_max] × R0 (code 6): there R̂ is the bound, not an estimate",
    "numfix_pct": "share of measurements where the filter needed a numerical repair (code 9)",
    "diverged": "runs lost to divergence (rule in the footnote)",
    "h_err_median": "median of the horizontal position error over all epochs and runs",
    "h_err_p90": "90th percentile of the horizontal position error over all epochs and runs",
}
COLUMN_HELP = {
    NAMES["diverged"]: HELP["diverged"],
    "µs per run·step": "filter wall time per run and epoch, batched over the runs, timed over "
    "epochs 2 … K: the first epoch's one-off start-up (loading or compiling a kernel, imports) is "
    "left out, so the first filter of a run is not charged for it",
}


def metric_help(metric: str, data) -> str:
    """The tooltip of a metric's column: what it is, over what, and its interval."""
    if metric in HELP:
        return HELP[metric] + "; [lo, hi]: its 95 % interval over runs"
    for prefix, word in (("mean_rmse_", "mean over runs of each run's RMSE"), ("rmse_", "RMSE")):
        if metric.startswith(prefix) and metric[len(prefix) :] in data.groups:
            g = data.groups[metric[len(prefix) :]]
            return (
                f"{word} of the {g.label} error ({g.unit}), pooled over the analysis window's epochs "
                "and the judged runs; [lo, hi]: its 95 % interval over runs"
            )
    return ""


def metric_name(metric: str, data) -> str:
    """Readable column name with unit for a metric key of :func:`navlab.metrics.summarize`."""
    groups = data.groups
    for prefix, word in (("mean_rmse_", "mean RMSE"), ("rmse_", "RMSE")):
        if metric.startswith(prefix) and metric[len(prefix) :] in groups:
            g = groups[metric[len(prefix) :]]
            return f"{word} {g.label} ({g.unit})"
    return NAMES.get(metric, metric.replace("_", " "))


def cell(value: float, lo: float = np.nan, hi: float = np.nan) -> str:
    """'1.23 [1.10, 1.37]', '1.23' without an interval, '' for no value."""
    v = S.sig3(value)
    if not v:
        return ""
    if np.isfinite(lo) and np.isfinite(hi) and not lo == hi == value:
        return f"{v} [{S.sig3(lo)}, {S.sig3(hi)}]"
    return v


def verdict_cell(row: pd.Series, ref_label: str, short: bool = False) -> str:
    """'better than KF (Δ −0.41 m [−0.52, −0.30], Holm p < 0.002)' etc. for one ``_diff`` row
    (``short``: the reference is in the column's name: 'better (Δ −0.41 m [−0.52, −0.30], …)');
    a p at the bootstrap's floor is written as the bound it is ("p < …").
    """
    unit = f" {row['unit']}" if row["unit"] and row["unit"] != "%" else (" %" if row["unit"] else "")
    d = f"Δ {S.sig3(row['value'])}{unit}"
    if np.isfinite(row["ci_lo"]):
        d += f" [{S.sig3(row['ci_lo'])}, {S.sig3(row['ci_hi'])}]"
    p = row.get("p_holm", np.nan)
    if p is not None and np.isfinite(p):
        d += f", Holm {S.format_p(p, row.get('p_holm_bound') == '<')}"
    n_common, cv = row.get("common_runs", np.nan), row.get("common_value", np.nan)
    if n_common is not None and np.isfinite(n_common) and n_common != row["runs_used"] and np.isfinite(cv):
        # beside the verdict (lost runs scored as losses): Δ over the runs both kept
        d += f"; on the {int(n_common)} runs both kept Δ {S.sig3(cv)}{unit}"
        if np.isfinite(row.get("common_ci_lo", np.nan)):
            d += f" [{S.sig3(row['common_ci_lo'])}, {S.sig3(row['common_ci_hi'])}]"
    v = row["verdict"]
    words = {
        "better": f"better than {ref_label}",
        "worse": f"worse than {ref_label}",
        "indistinguishable": f"indistinguishable from {ref_label} at this run count",
    }
    if v in words:
        return f"{v if short else words[v]} ({d})"
    return f"{d}" if row["ci_method"] else f"{d}; no test"


def text_table(df: pd.DataFrame, index: bool = True) -> str:
    """A plain-text table with left-aligned text and right-aligned numbers-first cells."""
    t = df.reset_index() if index and df.index.name else df
    cols = [str(c) for c in t.columns]
    cells = [[("" if v is None else str(v)) for v in row] for row in t.itertuples(index=False)]
    widths = [max([len(c)] + [len(r[i]) for r in cells]) for i, c in enumerate(cols)]

    def numeric(v: str) -> bool:
        head = v.split(" ")[0].replace("-", "", 1).replace(".", "", 1)
        return bool(head) and head.isdigit()

    right = [
        all(numeric(r[i]) or not r[i] for r in cells) and any(r[i] for r in cells) for i in range(len(cols))
    ]
    fmt = lambda vals: "  ".join(  # noqa: E731
        (v.rjust(w) if r else v.ljust(w)) for v, w, r in zip(vals, widths, right, strict=True)
    ).rstrip()
    return "\n".join([fmt(cols)] + [fmt(r) for r in cells])


@dataclass
class Table:
    """A display table (text cells, one row per filter) and its footnotes."""

    cells: pd.DataFrame
    notes: list[str] = field(default_factory=list)
    help: dict[str, str] = field(default_factory=dict)  # column -> tooltip
    best: dict[str, str] = field(default_factory=dict)  # column -> the row label better than all

    def text(self) -> str:
        body = text_table(self.cells) if len(self.cells) else "(no filters)"
        return body + "\n" + "\n".join(f"  {n}" for n in self.notes) + "\n"


def _zero_variance(res: Results, key: str) -> str:
    """Why a filter's NEES is undefined where its P is singular: the states it holds at variance 0
    (e.g. a bias modelled with σ = 0); "" when none is.
    """
    Pd = getattr(res.runs.get(key), "P_diag", None)  # a summary run keeps no per-epoch arrays
    if Pd is None:
        return ""
    Pd = Pd[:, 1:]
    zero = np.flatnonzero((Pd == 0).any(axis=tuple(range(Pd.ndim - 1))))
    if not zero.size:
        return ""
    names = ", ".join(res.data.state_names[i] for i in zero)
    return f": its P holds {names} at variance 0 (singular), where the NEES is undefined"


def _headline_groups(res: Results, groups: list[str]) -> list[str]:
    """The scenario's headline error groups among ``groups`` (all of ``groups`` if it names none)."""
    try:
        head = scenario_registry()[res.spec.scenario].headline
    except KeyError:
        head = ()
    return [g for g in head if g in groups] or list(groups)


def _present(res: Results, wanted: list[str], scenario_metrics: bool) -> list[str]:
    """The metrics of ``wanted`` some filter of the experiment has (or, with ``scenario_metrics``,
    the scenario reports).
    """
    present = {m for k in res.runs for m in M.summary(res).metrics_of(k)}
    if scenario_metrics:
        present |= set(res.data.extras.get("metrics", {}))
    return [m for m in wanted if m in present]


def headline_metrics(res: Results) -> list[str]:
    """The columns of the headline table (those that exist in this experiment)."""
    data = res.data
    cols = [f"rmse_{g}" for g in _headline_groups(res, list(data.groups))] if data.has_truth else []
    return _present(res, cols + list(data.extras.get("metrics", {})) + list(M.QUALITY_METRICS), True)


# --------------------------------------------------------------------------- display choices
# which metrics a comparison reports and which filters may be called "best": choices of the
# display (they read the scenario's headline groups and the filter registry), not of the metrics


def comparison_metrics(res: Results) -> list[str]:
    """The metrics a comparison reports: the headline error groups' RMSEs, scenario metrics,
    consistency, R̂ error and detection rates (those that exist in this experiment).
    """
    data = res.data
    head = _headline_groups(res, list(data.groups) if data.has_truth else [])
    wanted = [f"rmse_{g}" for g in head] + [f"mean_rmse_{g}" for g in head]
    return _present(res, wanted + list(data.extras.get("metrics", {})) + list(M.QUALITY_METRICS), False)


FLAG_METRICS = ("detected_pct", "false_alarm_pct")  # rates of the filters' outlier decisions


def best_candidates(res: Results, metric: str) -> list[str]:
    """The filters "best" on ``metric`` is chosen among: never the oracle (it is told which
    measurements are outliers and the true R: the accuracy floor, not a contender), and for the
    outlier-flag rates (:data:`FLAG_METRICS`) only the filters that flagged a measurement as an
    outlier (codes 1–5) in the analysis window (one that never flags "wins" false alarms by
    doing nothing).
    """
    sm = M.summary(res)
    keys = [k for k in res.runs if not is_oracle(k)]
    if metric in FLAG_METRICS:
        flagged = lambda k: float(np.sum(sm.stats[k].sums["detected"] + sm.stats[k].sums["false_alarm"]))  # noqa: E731
        keys = [k for k in keys if flagged(k) > 0]
    return keys


def best_filter(res: Results, metric: str) -> tuple[str | None, pd.DataFrame]:
    """The filter better than every other candidate (:func:`best_candidates`: the non-oracle
    filters; for the flag rates those that flag outliers) on ``metric`` after Holm's correction,
    or None.

    The candidate is the reliable filter with the best point estimate; it is "best" only if the
    paired test (:func:`navlab.metrics.compare`, Holm across the other candidates) says it is
    better than each other candidate. Returns (key or None, the comparison rows against the candidate).
    """
    sm = M.summary(res)
    d = M.direction(metric) or 1
    among = best_candidates(res, metric)
    values = {
        k: sm.metrics_of(k)[metric][0].point()
        for k in among
        if sm.judgement.reliable[k] and metric in sm.metrics_of(k)
    }
    values = {k: v for k, v in values.items() if np.isfinite(v)}
    if len(among) < 2 or not values:
        return None, pd.DataFrame(columns=M.COLUMNS + M.DIFF_COLUMNS)
    cand = min(values, key=lambda k: d * values[k])
    rows = M.compare(res, cand, [metric], among)
    ok = len(rows) == len(among) - 1 and (rows["verdict"] == "worse").all()
    return (cand if ok else None), rows


def summary_rows(res: Results, compare_to: str | None = None) -> pd.DataFrame:
    """The tidy table of :func:`navlab.metrics.summarize` (every metric of every filter), the
    posterior Cramér–Rao bound's ``pcrb_*`` rows and each filter's ``gap_*`` to it
    (:func:`navlab.pcrb.rows`, simulated scenarios), with the paired ``_diff`` rows against
    ``compare_to`` on the :func:`comparison_metrics` appended.
    """
    from navlab.pcrb import rows as pcrb_rows

    df = pd.concat([M.summarize(res), pcrb_rows(res)], ignore_index=True)
    if compare_to is None:
        return df
    return pd.concat([df, M.compare(res, compare_to, comparison_metrics(res))], ignore_index=True)


# --------------------------------------------------------------------------- the headline table


def headline(
    res: Results,
    compare_to: str | None = None,
    metrics: list[str] | None = None,
    explanations: bool = True,
    best: bool = False,
    floor: bool = True,
) -> Table:
    """The headline table: one row per filter, each metric with its 95 % interval, diverged runs,
    the run time, and — with ``compare_to`` — the paired verdict on the first headline metric.
    ``explanations``: the known failure mechanisms as footnotes (the app shows them as boxes with
    a link to the Learn page instead).

    ``best``: find, per metric that has a direction (errors, detection rates), the filter that
    the paired test says is better than EVERY other candidate (:func:`best_filter`,
    Holm-corrected; the candidates are the non-oracle filters, and on the outlier-flag rates only
    those that flag outliers): ``Table.best`` maps the column to that row; a column where no
    filter is better than all others (a point-estimate winner the test does not back) has no
    entry.

    ``floor``: a footnote with the posterior Cramér–Rao bound of the first error column and each
    filter's gap to it (:func:`navlab.pcrb.floor_text`; simulated scenarios).
    """
    sm = M.summary(res)
    data = res.data
    metrics = metrics or headline_metrics(res)
    df = sm.rows(metrics)
    cells = _headline_cells(res, metrics, df)
    helps = {metric_name(m, data): metric_help(m, data) for m in metrics} | COLUMN_HELP
    notes = []
    if compare_to is not None and compare_to in res.runs and metrics:
        col, help_, notes = _verdict_column(res, cells, compare_to, metrics[0])
        helps[col] = help_
    notes += footnotes(res, sm, explanations, df)
    have = set(zip(df["filter"], df["metric"], strict=True))
    if any(m.startswith("rhat_err") and (k, m) not in have for k in res.runs for m in metrics):
        notes.append("R̂ error: — for filters that do not estimate R")
    if floor and metrics and metrics[0].startswith("rmse_"):  # the PCRB of the first error column
        from navlab.pcrb import floor_text

        line = floor_text(res, metrics[0][len("rmse_") :], markdown=False)
        notes += [line] if line else []
    winners = _winners(res, metrics) if best and len(res.runs) > 1 else {}
    return Table(cells, notes, {c: h for c, h in helps.items() if h and c in cells.columns}, winners)


def _headline_cells(res: Results, metrics: list[str], df: pd.DataFrame) -> pd.DataFrame:
    """One row per filter: each metric as "value [lo, hi]" ("—" where the filter has none), its
    diverged runs and its run time.
    """
    data = res.data
    by = {(r["filter"], r["metric"]): r for r in df.to_dict("records")}
    rows = []
    for key, fr in res.runs.items():
        row = {"filter": fr.label}
        for m in metrics:
            r = by.get((key, m))
            row[metric_name(m, data)] = "—" if r is None else cell(r["value"], r["ci_lo"], r["ci_hi"])
        lost = by[(key, "diverged")]
        row["diverged runs"] = f"{int(lost['value'])} of {data.B}" if lost["value"] else "0"
        row["µs per run·step"] = S.sig3(by[(key, "us_per_run_step")]["value"])
        rows.append(row)
    return pd.DataFrame(rows).set_index("filter")


def _verdict_column(
    res: Results, cells: pd.DataFrame, compare_to: str, first: str
) -> tuple[str, str, list[str]]:
    """Inserts the paired verdict of every filter against ``compare_to`` on the metric ``first``
    beside that metric's column; returns the column's name, its help and its notes.
    """
    data = res.data
    ref_label = res.runs[compare_to].label
    col = f"vs {ref_label}"
    c = M.compare(res, compare_to, [first])
    verdicts = {r["filter"]: verdict_cell(r, ref_label, short=True) for r in c.to_dict("records")}
    # beside the metric it judges, so the verdict is on screen with it
    cells.insert(1, col, ["reference" if k == compare_to else verdicts.get(k, "") for k in res.runs])
    others = len(res.runs) - 1  # one comparison: Holm's correction is the p-value itself
    holm = "p < 0.05" if others == 1 else f"Holm-corrected p < 0.05 across the {others} other filters"
    notes = [
        f"{col}: {metric_name(first, data)} paired over the same runs, Δ = filter − {ref_label} "
        f"with its 95 % interval; better/worse when {holm}, else indistinguishable at this run "
        "count; p < …: below the bootstrap's resolution (no resample on the other side of 0)",
        f"Lost runs: {M.LOSS_RULE}.",
    ]
    help_ = (
        f"{metric_name(first, data)}: paired difference from the reference over the same "
        "runs, with its 95 % interval and the Holm-corrected verdict"
    )
    return col, help_, notes


def _winners(res: Results, metrics: list[str]) -> dict[str, str]:
    """Column -> the filter the paired test says is better than every other candidate
    (:func:`best_filter`), for the metrics with a direction; no entry where there is none.
    """
    winners = {}
    for m in metrics:
        key = best_filter(res, m)[0] if M.direction(m) != 0 else None
        if key is not None:
            winners[metric_name(m, res.data)] = res.runs[key].label
    return winners


def interval_note(runs: int) -> str:
    """How the [lo, hi] of a metric over ``runs`` judged runs was made (docs/STATISTICS.md)."""
    if runs < S.MIN_RUNS:
        return f"Intervals: {S.TOO_FEW}."
    how = (
        "delta method (normal) over runs"
        if runs >= S.DELTA_FROM
        else f"BCa bootstrap over runs (B = {S.N_BOOT}, seeded; the same resamples for every filter)"
    )
    return f"[lo, hi]: 95 % interval, {how}."


def footnotes(
    res: Results, sm: M.Summary | None = None, explanations: bool = True, rows: pd.DataFrame | None = None
) -> list[str]:
    """How the numbers were made: window, intervals, divergence, skipped entries, fixes."""
    sm = sm or M.summary(res)
    jd = sm.judgement
    n_common = int(jd.common.sum())
    sizes = {int(jd.judged[k].sum()) for k in res.runs} - {0}  # a filter with no run has no row
    out = [f"Analysis window: {sm.window}.", interval_note(min(sizes) if sizes else 0)]
    lost = {k: jd.lost(k) for k in res.runs if jd.lost(k)}
    if lost:
        out.append(
            f"Judged on {n_common} of {jd.n_runs} runs (the runs every reliable filter kept): "
            + "; ".join(
                f"{res.runs[k].label} lost {v}" + ("" if jd.reliable[k] else " (> 5 %: ranks below)")
                for k, v in lost.items()
            )
            + "."
        )
    out.append("Divergence: " + sm.rule + ".")
    t = sm.rows([]) if rows is None else rows
    skipped = t[t.metric.str.endswith("_skipped") & (t.value > 0)]
    for r in skipped.itertuples():
        what = r.metric.replace("_skipped", "").upper().replace("RHAT", "R̂ ratio")
        why = _zero_variance(res, r.filter) if what == "NEES" else ""
        out.append(f"{r.label}: {int(r.value)} non-finite {what} entries skipped (counted, not hidden){why}.")
    explained = set()
    if explanations and sm.arrays:  # the known failure mechanisms (need the per-epoch arrays)
        from navlab.diagnostics import FLAG_KINDS, explain

        for e in explain(res, kinds=FLAG_KINDS):
            out.append(f"{e.sentence} (the Learn page shows how: filter {e.filter})")
            explained.add((e.filter, e.kind))
    said = {
        "band_pct": ("band", "R̂ held at its band (flag 6)"),
        "numfix_pct": ("numerical_fix", "numerical fixes (flag 9)"),
    }
    for r in t[t.metric.isin(list(said)) & (t.value > M.FLAG_SHOW_PCT)].itertuples():
        kind, what = said[r.metric]
        if (r.filter, kind) not in explained:
            out.append(f"{r.label}: {what} on {S.sig3(r.value)} % of measurements — not outlier decisions.")
    return out


# --------------------------------------------------------------------------- paper formats
# A Table as Markdown or as a LaTeX booktabs table: the same cells (value [lo, hi]), the best
# in bold only where Table.best says the paired test backs it, the notes below, a caption that
# names the runs, the seeds and the interval method.

FORMATS = ("markdown", "latex")
BEST_NOTE = (
    "Bold: better than every other candidate filter on that column (paired test over the same "
    "runs, Holm-corrected p < 0.05; the oracle is not a candidate); a column with no bold has no "
    "such filter."
)


def run_caption(res: Results) -> str:
    """What a run's table is: scenario, runs and seeds, window, the interval method."""
    spec, sm = res.spec, M.summary(res)
    scls = scenario_registry().get(spec.scenario)
    label = scls.label if scls is not None else spec.scenario
    judged = {int(sm.judgement.judged[k].sum()) for k in res.runs} - {0}
    return (
        f"{label} (navlab scenario {spec.scenario}), noise schedule {spec.noise_schedule}, outliers "
        f"{spec.outliers}: {res.data.B} Monte Carlo runs (seed {spec.seed}, runs 0 to {res.data.B - 1}), "
        f"{res.data.K} epochs; analysis window {sm.window}. " + interval_note(min(judged) if judged else 0)
    )


def run_table(res: Results, fmt: str, compare_to: str | None = None) -> str:
    """A run's headline table for a paper (``navlab run --format``, the pages' downloads): the
    best in bold where the paired test backs it, the caption from :func:`run_caption`.
    """
    t = headline(res, compare_to=compare_to, best=True)
    return render(t, fmt, run_caption(res), label=f"tab:navlab-{res.spec.scenario}")


def render(t: Table, fmt: str, caption: str, label: str = "tab:navlab") -> str:
    """``t`` as ``fmt`` (:data:`FORMATS`) with ``caption`` (LaTeX: ``label`` too)."""
    if fmt == "markdown":
        return markdown_table(t, caption)
    if fmt == "latex":
        return latex_table(t, caption, label)
    raise ValueError(f"format {fmt!r}: one of {', '.join(FORMATS)}")


def _rows(t: Table) -> tuple[list[str], list[list[str]], list[list[bool]]]:
    """Header, body cells and which cells are bold (Table.best) of a display table."""
    df = t.cells.reset_index() if t.cells.index.name else t.cells
    cols = [str(c) for c in df.columns]
    body = [
        ["" if v is None else str(v).replace("\n", " ") for v in row] for row in df.itertuples(index=False)
    ]
    labels = [str(v) for v in t.cells.index] if t.cells.index.name else [""] * len(body)
    bold = [[t.best.get(c) == lab and bool(lab) for c in cols] for lab in labels]
    return cols, body, bold


def markdown_table(t: Table, caption: str) -> str:
    """A pipe table (GitHub/pandoc Markdown): caption above, notes below, best cells in bold."""
    cols, body, bold = _rows(t)
    esc = lambda v: v.replace("|", "\\|").replace("\n", " ")  # noqa: E731
    lines = [f"Table: {caption}" + (f" {BEST_NOTE}" if t.best else ""), ""]
    lines.append("| " + " | ".join(esc(c) for c in cols) + " |")
    right = _numeric_columns(body, len(cols))
    lines.append("|" + "|".join("---:" if r else "---" for r in right) + "|")
    for row, b in zip(body, bold, strict=True):
        lines.append(
            "| "
            + " | ".join(f"**{esc(v)}**" if bb and v else esc(v) for v, bb in zip(row, b, strict=True))
            + " |"
        )
    if t.notes:
        lines += [""] + [f"- {esc(n)}" for n in t.notes]
    return "\n".join(lines) + "\n"


def _numeric_columns(body: list[list[str]], n: int) -> list[bool]:
    """Columns whose every non-empty cell starts with a number (right-aligned)."""

    def numeric(v: str) -> bool:
        head = v.split(" ")[0].replace("−", "-").replace("-", "", 1).replace(".", "", 1)
        return bool(head) and head.isdigit()

    return [all(numeric(r[i]) or not r[i] for r in body) and any(r[i] for r in body) for i in range(n)]


_TEX_TEXT = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\~{}",
    "^": r"\^{}",
    "<": r"\textless{}",
    ">": r"\textgreater{}",
    "−": "$-$",
    "–": "--",
    "—": "---",
    "…": r"\ldots{}",
    "§": r"\S{}",
    "‡": r"\ddag{}",
    "°": "$^\\circ$",
    "’": "'",
    "“": "``",
    "”": "''",
}
_TEX_MATH = {
    "µ": r"\mu",
    "μ": r"\mu",
    "·": r"\cdot",
    "×": r"\times",
    "÷": r"\div",
    "±": r"\pm",
    "≈": r"\approx",
    "≤": r"\leq",
    "≥": r"\geq",
    "≠": r"\neq",
    "≪": r"\ll",
    "→": r"\to",
    "←": r"\leftarrow",
    "⇒": r"\Rightarrow",
    "∞": r"\infty",
    "√": r"\surd",
    "∈": r"\in",
    "∂": r"\partial",
    "²": "^2",
    "³": "^3",
    "¹": "^1",
    "⁻": "^-",
    "⁺": "^+",
    "ᵀ": "^T",
    "‖": r"\|",
}
_LATIN_TWIN = {
    "ALPHA": "A", "BETA": "B", "EPSILON": "E", "ZETA": "Z", "ETA": "H", "IOTA": "I", "KAPPA": "K",
    "MU": "M", "NU": "N", "RHO": "P", "TAU": "T", "CHI": "X",
}  # fmt: skip
_GREEK_CAPITALS = {"GAMMA", "DELTA", "THETA", "LAMDA", "XI", "PI", "SIGMA", "UPSILON", "PHI", "PSI", "OMEGA"}


def _greek(ch: str) -> str | None:
    r"""A Greek letter as its LaTeX macro (σ → \sigma, Δ → \Delta; capitals LaTeX has no
    macro for, such as Α, as their Latin twin); None for any other character.
    """
    import unicodedata

    name = unicodedata.name(ch, "")
    for case in ("SMALL", "CAPITAL"):
        prefix = f"GREEK {case} LETTER "
        if name.startswith(prefix) and " " not in name[len(prefix) :]:
            word = name[len(prefix) :].replace("LAMDA", "LAMBDA")
            if word == "OMICRON":
                return "o" if case == "SMALL" else "O"
            if case == "SMALL":
                return "\\" + word.lower()
            if name[len(prefix) :] in _GREEK_CAPITALS:
                return "\\" + word.capitalize()
            return _LATIN_TWIN.get(word, "?")
    return None


_TEX_MATH.update({c: f"^{i}" for i, c in enumerate("⁰¹²³⁴⁵⁶⁷⁸⁹")})
_TEX_MATH.update({c: f"_{i}" for i, c in enumerate("₀₁₂₃₄₅₆₇₈₉")})
_ACCENT = {"\u0302": r"\hat", "\u0303": r"\tilde", "\u0304": r"\bar", "\u0307": r"\dot"}


def latex_escape(text: str) -> str:
    r"""Plain text as LaTeX that pdflatex compiles with no package: ASCII only (Greek letters and
    symbols as math, x̂ as $\hat{x}$, accented letters without their accent, anything else
    as '?').
    """
    import unicodedata

    out: list[tuple[bool, str]] = []  # (math?, text): adjacent math joins, σ² → $\sigma^2$
    i = 0
    while i < len(text):
        ch = text[i]
        nxt = text[i + 1] if i + 1 < len(text) else ""
        if nxt in _ACCENT:  # a letter with a combining accent: R̂ → $\hat{R}$
            base = _TEX_MATH.get(ch) or _greek(ch) or (ch if ch.isascii() and ch.isalnum() else "?")
            out.append((True, f"{_ACCENT[nxt]}{{{base}}}"))
            i += 2
            continue
        if ch in _TEX_TEXT:
            t = _TEX_TEXT[ch]
            out.append((True, t[1:-1]) if t.startswith("$") else (False, t))
        elif ch in _TEX_MATH:
            out.append((True, _TEX_MATH[ch]))
        elif (g := _greek(ch)) is not None:
            out.append((g.startswith("\\"), g))
        elif ch.isascii():
            out.append((False, " " if ch == "\n" else ch))
        else:
            plain = "".join(c for c in unicodedata.normalize("NFKD", ch) if c.isascii())
            out.append((False, plain if plain else "?"))
        i += 1
    parts: list[str] = []
    for k, (math, t) in enumerate(out):
        if math and k > 0 and out[k - 1][0]:  # the previous math run goes on
            prev = parts[-1][1:-1]
            sup = re.fullmatch(r"(.*)([\^_])(\{[^{}]*\}|[^{}])", prev, flags=re.S)
            if sup and t[:1] == sup.group(2):  # ⁻¹: one superscript ^{-1}, not ^-^1 (and subscripts)
                prev = f"{sup.group(1)}{t[0]}{{{sup.group(3).strip('{}')}{t[1:]}}}"
                parts[-1] = f"${prev}$"
            else:
                parts[-1] = f"${prev}{t}$"
        else:
            parts.append(f"${t}$" if math else t)
    return "".join(parts)


def latex_table(t: Table, caption: str, label: str = "tab:navlab") -> str:
    r"""A booktabs table (``\usepackage{booktabs}``): caption, label, the best cells in
    \textbf, the notes in small type under the rule. ASCII only: pdflatex compiles it with
    booktabs as its one package.
    """
    cols, body, bold = _rows(t)
    right = _numeric_columns(body, len(cols))
    cap = latex_escape(caption) + (f" {latex_escape(BEST_NOTE)}" if t.best else "")
    lines = [
        "% navlab table: needs \\usepackage{booktabs}",
        "\\begin{table}[htbp]",
        "\\centering",
        "\\small",
        f"\\caption{{{cap}}}",
        f"\\label{{{label}}}",
        "\\begin{tabular}{" + "".join("r" if r else "l" for r in right) + "}",
        "\\toprule",
        " & ".join(latex_escape(c) for c in cols) + " \\\\",
        "\\midrule",
    ]
    for row, b in zip(body, bold, strict=True):
        cells = [latex_escape(v) for v in row]
        cells = [f"\\textbf{{{c}}}" if bb and c else c for c, bb in zip(cells, b, strict=True)]
        if cells and cells[0].startswith("["):  # not \\[length] after the previous row's \\
            cells[0] = "{}" + cells[0]
        lines.append(" & ".join(cells) + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}"]
    if t.notes:
        lines.append("\\par\\medskip\\footnotesize")
        lines += [latex_escape(n) + "\\par" for n in t.notes]
    lines.append("\\end{table}")
    return "\n".join(lines) + "\n"

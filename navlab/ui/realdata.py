"""Helpers of the Real data page: specs, uploads, a per-epoch progress runner, figures, tables.

The figures are plain plotly (``Scattergl`` on local east/north metres, no map tiles: the app
works offline). Everything but :func:`run_with_progress` is a pure function of its arguments.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import plotly.graph_objects as go

from navlab.data.checks import Finding, run_messages
from navlab.data.loaders import RTKX_SOURCE, SMARTLOC_SOURCE, load_generic
from navlab.errors import NavlabError
from navlab.experiment import (
    ExperimentSpec,
    FilterRun,
    ParamGroup,
    Results,
    iter_experiment,
    plan,
    presets,
)
from navlab.filters.base import FLAG_NAMES, registry
from navlab.metrics import summarize
from navlab.noise import OUTLIERS
from navlab.scenarios.base import get_scenario_class
from navlab.ui.colors import TRUTH_COLOR, filter_colors
from navlab.ui.figures import readable, title_layout, truth_line, value_range, y_range_layout
from navlab.ui.uploads import SessionUploads, sweep

RECORDINGS = {
    "drive0708": "Car drive: MEMS IMU + 1 Hz GNSS (rtkx_drive_0708)",
    "smartloc-berlin": "Urban pseudoranges: smartLoc Berlin Potsdamer Platz",
    "upload": "Upload your own drive (generic CSV)",
    "upload-pr": "Upload your own pseudoranges (generic CSV)",
}


def warm_spec() -> ExperimentSpec:
    """A tiny run of the page's default experiment (the drive, its default filters): what the
    page warms in the background at its first view.
    """
    scen = get_scenario_class("drive0708")
    return ExperimentSpec(scenario="drive0708", filters=scen.default_filters, runs=1, epochs=20)


#: The page's uploads and the scenario each one runs.
UPLOADS = {"upload": "own-drive", "upload-pr": "own-pseudoranges"}
_OWN_FILES = (
    "Your own files (generic navlab CSV format). They are kept in a temporary folder of this "
    "session only and deleted when the session ends (at the latest one hour after its last use)."
)
LICENCES = {
    "drive0708": RTKX_SOURCE,
    "smartloc-berlin": SMARTLOC_SOURCE,
    "upload": _OWN_FILES,
    "upload-pr": _OWN_FILES,
}
TABLE_METRICS = (
    ("h_err_median", "median horizontal error (m)"),
    ("h_err_p90", "90 % horizontal error (m)"),
    ("rmse_hpos", "RMSE horizontal (m)"),
    ("rmse_pos", "RMSE 3-D (m)"),
    ("diverged", "diverged runs"),
    ("runtime_s", "runtime (s)"),
)
MAX_POINTS = 4000
#: Most noise/outlier injections (runs) the page offers.
MAX_INJECTIONS = 50


def link_problems(query: Mapping[str, Sequence[str]]) -> list[str]:
    """Why each of this page's link values (``rd_*``) is not used, one line each, worded like the
    other pages' notice (:func:`navlab.ui.widgets.url_problems`).
    """
    from navlab.params import MAX_EPOCHS, SEED_MAX
    from navlab.ui.widgets import _check_value

    numbers = {
        "rd_seed": ("the seed", 0, SEED_MAX),
        "rd_ep_": ("epochs", 0, MAX_EPOCHS),
        "rd_runs_": ("runs", 1, MAX_INJECTIONS),
    }
    out = []
    for key, raws in query.items():
        for raw in raws:
            why = None
            if key == "rd_rec" and raw not in RECORDINGS:
                why = f"no such recording (one of: {', '.join(RECORDINGS)})"
            elif key.startswith("rd_flt_") and raw not in usable_filters(key.removeprefix("rd_flt_")):
                why = "no filter that runs on this recording is registered under this key"
            for prefix, (name, lo, hi) in numbers.items():
                if key.startswith(prefix):
                    bad = _check_value({"lo": lo, "hi": hi}, 1, raw)
                    why = f"{name} {bad}" if bad else why
            if why:
                out.append(f"`{key}={raw}`: {why}")
    return out


def outlier_defaults(scenario: str) -> dict[str, Any]:
    """The mixture outlier model's parameters before the page changes them: the model's defaults
    with the scenario's preset over them (the one resolution, navlab.experiment.ParamGroup).
    """
    scls = get_scenario_class(scenario)
    return ParamGroup("ol", "mixture", OUTLIERS["mixture"], presets(scls, "ol", "mixture"), {}).defaults()


def scenario_of(recording: str) -> str:
    return UPLOADS.get(recording, recording)


def usable_filters(scenario: str) -> list[str]:
    """Registered filters that can run on real data (no oracle: it needs simulator truth)."""
    out = [k for k, c in registry().items() if c.family != "oracle"]
    if scenario in ("drive0708", "own-drive"):
        # the INS model's F is exact only through f(x); a model-free per-epoch solve still works
        out = [k for k in out if not getattr(registry()[k], "linear_only", False)]
    return out


def build_spec(
    recording: str,
    filters: Sequence[str],
    *,
    epochs: int,
    runs: int = 1,
    seed: int = 1,
    contamination: float = 0.0,
    outlier_scale: float = 10.0,
    scenario_params: Mapping[str, Any] | None = None,
) -> ExperimentSpec:
    """The experiment spec the page runs (CLI equivalent: ``python -m navlab run --config``)."""
    sp = dict(scenario_params or {})
    sp["epochs"] = int(epochs)
    return ExperimentSpec(
        scenario=scenario_of(recording),
        filters=tuple(filters),
        runs=int(runs),
        seed=int(seed),
        outliers="mixture",
        contamination=float(contamination),
        outlier_scale=float(outlier_scale),
        scenario_params=sp,
    )


#: Rough cost of one filter on one run for one epoch of a drive [µs], for the page's time estimate:
#: the own-drive CLI tables of issue 24 (10 Hz fixes, 7 filters) printed 250–680 µs per run·step
#: (IRAKF the dearest); the estimate takes a middle value and says it is rough.
DRIVE_US_PER_STEP = 400.0
#: the same for pseudoranges: the own-pseudoranges CLI table on 60 s of Berlin (issue 24, 7 default
#: filters, ~15 satellites an epoch) printed 2500–23500 µs per run·step (VB-EKF the dearest), mean ≈ 7600
PR_US_PER_STEP = 8000.0


def epochs_label(recording: str) -> str:
    """The Epochs box's label: what an epoch is on this recording and what 0 means."""
    return {
        "drive0708": "Epochs (1 Hz; 0 = the whole drive, ≈ 513)",
        "smartloc-berlin": "Epochs (5 Hz; 0 = all 1371)",
        "upload": "GNSS epochs (0 = the whole upload)",
        "upload-pr": "Pseudorange epochs (0 = the whole upload)",
    }[recording]


def epochs_default(recording: str) -> int:
    """The Epochs box's default: the bundled recordings a short first look, an upload all of it."""
    return {"drive0708": 120, "smartloc-berlin": 300, "upload": 0, "upload-pr": 0}[recording]


def time_estimate(spec: ExperimentSpec) -> str:
    """A rough run time of an upload's spec (its epochs × filters × runs), in words."""
    if spec.scenario == "own-pseudoranges":
        t = _pr_epochs(spec).t
        K, us = len(t) - 1, PR_US_PER_STEP
    else:
        _rec, setup, _ = plan(spec).scenario._setup()
        t, K, us = setup.t, setup.K, DRIVE_US_PER_STEP
    s = K * len(spec.filters) * spec.runs * us * 1e-6
    return (
        f"{K} epochs over {t[-1] - t[0]:.0f} s: roughly {max(s, 1.0):.0f} s to run (the first run "
        "after a server start also compiles the filters: up to a minute or two more)"
    )


def _pr_epochs(spec: ExperimentSpec):
    """An own-pseudoranges spec's epochs, cut to its ``epochs`` setting (0: all)."""
    from navlab.scenarios.smartloc_berlin import load_epochs

    ep = load_epochs(str(spec.scenario_params.get("data_dir", "")))
    K = int(spec.scenario_params.get("epochs") or 0)
    return ep.cut(min(K, len(ep.t) - 1)) if K else ep


def cli_line(spec: ExperimentSpec) -> str:
    """The command line that repeats ``spec`` exactly: every scenario parameter that differs from
    its default (data_dir included), the filters, runs, seed and outlier settings.
    """
    import dataclasses
    import shlex

    P = get_scenario_class(spec.scenario).Params
    defaults = {f.name: f.default for f in dataclasses.fields(P)}
    parts = [
        f"python -m navlab run --scenario {spec.scenario} --filters {','.join(spec.filters)}",
        f"--runs {spec.runs} --seed {spec.seed}",
    ]
    if spec.outliers:
        parts.append(f"--outliers {spec.outliers}")
    if spec.contamination is not None:
        parts.append(f"--contamination {spec.contamination!r}")
    if spec.outlier_scale is not None:
        parts.append(f"--outlier-scale {spec.outlier_scale!r}")
    for k, v in spec.scenario_params.items():
        if k in defaults and v == defaults[k] and k != "data_dir":
            continue
        if k == "data_dir" and not v:
            continue
        val = str(v).lower() if isinstance(v, bool) else (repr(v) if isinstance(v, float) else str(v))
        parts.append(shlex.quote(f"scenario.{k}={val}").join(("--set ", "")))
    return " ".join(parts)


def save_upload(imu: bytes, gnss: bytes, truth: bytes | None = None, *, uploads: SessionUploads) -> Path:
    """Write uploaded generic-format files into this session's upload folder and validate them.

    Raises NavlabError (naming the file, line and column) if a file is malformed; the broken
    files are removed at once. ``uploads`` owns the folder: it is removed when the session ends
    (:mod:`navlab.ui.uploads`).
    """
    sweep()
    d = uploads.folder(imu, gnss, truth)
    (d / "imu.csv").write_bytes(imu)
    (d / "gnss.csv").write_bytes(gnss)
    if truth:
        (d / "truth.csv").write_bytes(truth)
    elif (d / "truth.csv").exists():
        (d / "truth.csv").unlink()
    try:
        load_generic(d / "imu.csv", d / "gnss.csv", (d / "truth.csv") if truth else None, name="upload")
    except NavlabError as exc:  # the user sees the uploaded names, not the temp paths
        shutil.rmtree(d, ignore_errors=True)
        raise NavlabError(str(exc).replace(str(d) + "/", "uploaded ")) from None
    return d


def save_pr_upload(
    pr: bytes, odometry: bytes | None = None, truth: bytes | None = None, *, uploads: SessionUploads
) -> Path:
    """Write uploaded generic pseudorange files (pseudoranges.csv[, odometry.csv, truth.csv]) into
    this session's upload folder and validate them, as :func:`save_upload` does for a drive.
    """
    from navlab.data.loaders import read_pseudorange_csv

    sweep()
    d = uploads.folder(b"pr", pr, odometry, truth)
    for name, content in (("pseudoranges.csv", pr), ("odometry.csv", odometry), ("truth.csv", truth)):
        if content:
            (d / name).write_bytes(content)
        elif (d / name).exists():
            (d / name).unlink()
    try:
        read_pseudorange_csv(d)
    except NavlabError as exc:  # the user sees the uploaded names, not the temp paths
        shutil.rmtree(d, ignore_errors=True)
        raise NavlabError(str(exc).replace(str(d) + "/", "uploaded ")) from None
    return d


def upload_folder(
    st: Any,
    intro: str,
    files: Sequence[tuple[str, str, bool]],
    save: Callable[..., Path],
    uploads: SessionUploads,
) -> Path:
    """The upload block of a recording: ``intro``, one uploader per file (name, widget key,
    required) and the folder ``save(*contents, uploads=…)`` made; where a required file is missing
    or a file is broken, a message and the page stops there. ``st`` = streamlit.
    """
    st.markdown(intro)
    got = [
        c.file_uploader(name if required else f"{name} (optional)", type=["csv", "txt"], key=key)
        for c, (name, key, required) in zip(st.columns(len(files)), files, strict=True)
    ]
    missing = [name for (name, _, required), f in zip(files, got, strict=True) if required and f is None]
    if missing:
        st.info(f"Upload at least {' and '.join(missing)}.")
        st.stop()
    try:
        return save(*(None if f is None else f.getvalue() for f in got), uploads=uploads)
    except NavlabError as exc:
        st.error(str(exc))
        st.stop()
    raise AssertionError("unreachable: st.stop() ends the script")


def _pr_findings(spec: ExperimentSpec) -> list[Finding]:
    """What an own-pseudoranges run will be fed: epochs, satellites, clocks, odometry, truth."""
    ep = _pr_epochs(spec)
    dt = np.diff(ep.t)
    per_epoch = np.isfinite(ep.rho).sum(axis=1)
    out = [
        Finding(
            "note",
            f"pseudoranges: {len(ep.t)} epochs (the first starts the filters, {len(ep.t) - 1} are "
            f"filtered) at {1 / float(np.median(dt)):.3g} Hz over "
            f"{ep.t[-1] - ep.t[0]:.1f} s, {len(ep.names)} satellites "
            f"({int(np.median(per_epoch))} per epoch, median); one receiver clock per system: "
            + ", ".join(ep.clock_names),
        ),
        Finding(
            "note",
            "odometry: "
            + ("dead reckoning with odometry.csv" if ep.has_odometry else "none — a constant-velocity model")
            + "; truth: "
            + (
                "truth.csv (errors are measured)"
                if ep.has_truth
                else "none (no errors, only the filters' tracks)"
            ),
        ),
    ]
    few = int((per_epoch[1:] < 4 + len(ep.clock_names) - 1).sum()) if len(ep.t) > 1 else 0
    if few:
        out.append(
            Finding(
                "warning",
                f"{few} epoch(s) have fewer satellites than a single-epoch fix needs (3 + one clock per "
                "system): WLS has no fix there, the other filters lean on their motion model",
            )
        )
    return out


def prerun_findings(spec: ExperimentSpec) -> list[Finding]:
    """What the filters will be fed and the checks of the recording, before a run (own data)."""
    from navlab.data.checks import check_drive

    if spec.scenario == "own-pseudoranges":
        return _pr_findings(spec)
    scen = plan(spec).scenario
    rec, setup, _ = scen._setup()
    return [Finding("note", n) for n in setup.notes] + check_drive(rec, setup, scen.params.sigma_m)


def run_findings(res: Results) -> list[Finding]:
    """Notes, pre-run checks and the trust check of a finished run (navlab.data.checks)."""
    return run_messages(res)


#: A note that is the yardstick of the results (the trust check's raw-fix figure): shown in the open.
LEAD_NOTE = "3-D position RMS "


def show_findings(st: Any, findings: Sequence[Finding], expanded: bool = False) -> None:
    """Warnings as warnings (likely causes as a list), the trust check's figure (the raw fixes
    against the best filter) in the open, other notes in one expander; ``st`` = streamlit.
    """
    for f in findings:
        if f.level == "warning":
            st.warning(f.text + "".join(f"\n- {c}" for c in f.causes))
    for f in findings:
        if f.level != "warning" and f.text.startswith(LEAD_NOTE):
            st.info(f.text, icon=":material/straighten:")
    notes = [f.text for f in findings if f.level != "warning" and not f.text.startswith(LEAD_NOTE)]
    if notes:
        with st.expander("What the filters are fed, and the checks", expanded=expanded):
            st.markdown("\n".join(f"- {n}" for n in notes))


def run_with_progress(
    spec: ExperimentSpec, on_progress: Callable[[float, str], None] | None = None
) -> Results:
    """Run ``spec`` through the one Monte Carlo driver (one batch: a recording's runs are noise
    injections on the same data), reporting progress within the batch.
    """
    t0 = time.perf_counter()
    if on_progress:
        on_progress(0.0, "loading the recording and aligning the INS…")
    last = [0.0]

    def tick(runs_done: float) -> None:  # progress within the batch, at most every 2 %
        if on_progress and (runs_done - last[0] >= 0.02 * spec.runs or runs_done >= spec.runs):
            last[0] = runs_done
            on_progress(
                runs_done / spec.runs,
                f"{100 * runs_done / spec.runs:.0f} % · {time.perf_counter() - t0:.1f} s",
            )

    return list(iter_experiment(spec, on_epoch=tick))[-1]


def _dec(n: int) -> slice:
    return slice(None, None, max(1, -(-n // MAX_POINTS)))


def track_figure(res: Results, run: int = 0) -> go.Figure:
    """Truth vs estimates (and the aiding fixes) in local east/north metres."""
    d = res.data
    ie, inn = d.extras.get("xy_idx", (0, 1))
    colors = filter_colors(list(res.runs))
    fig = go.Figure()
    sl = _dec(d.K + 1)
    if d.has_truth:
        xt = d.x_true[run]
        fig.add_trace(
            go.Scattergl(
                x=xt[sl, ie].astype(np.float32),
                y=xt[sl, inn].astype(np.float32),
                mode="lines",
                name="truth",
                line={"color": TRUTH_COLOR, "width": 3},
            )
        )
    if hasattr(d.model, "fixes"):
        z = d.model.fixes(d.z)[run]  # metres, also when the channels are whitened
        fig.add_trace(
            go.Scattergl(
                x=z[sl, 1].astype(np.float32),
                y=z[sl, 0].astype(np.float32),
                mode="markers",
                name="GNSS fixes (aiding)",
                marker={"size": 4, "color": "rgba(120,120,120,0.5)"},
            )
        )
    for key, fr in res.runs.items():
        x = fr.x[run]
        fig.add_trace(
            go.Scattergl(
                x=x[sl, ie].astype(np.float32),
                y=x[sl, inn].astype(np.float32),
                mode="lines",
                name=fr.label,
                line={"color": colors[key], "width": 1.5},
            )
        )
    fig.update_layout(
        title=f"Track (run {run}) — local east/north, metres",
        height=560,
        xaxis_title="east (m)",
        yaxis_title="north (m)",
        yaxis={"scaleanchor": "x", "scaleratio": 1},
    )
    return readable(fig)


def horizontal_error(res: Results, fr: FilterRun) -> np.ndarray:
    """(B, K+1) horizontal error norm [m]."""
    d = res.data
    idx = list(d.groups["hpos"].idx)
    return np.linalg.norm(fr.x[..., idx] - d.x_true[..., idx], axis=-1)


def error_figure(res: Results, run: int = 0, log_y: bool = False) -> go.Figure:
    """Horizontal error against time per filter (run ``run``)."""
    d = res.data
    colors = filter_colors(list(res.runs))
    fig = go.Figure()
    sl = _dec(d.K + 1)
    for key, fr in res.runs.items():
        e = horizontal_error(res, fr)[run]
        fig.add_trace(
            go.Scattergl(
                x=d.t[sl].astype(np.float32),
                y=e[sl].astype(np.float32),
                mode="lines",
                name=fr.label,
                line={"color": colors[key]},
            )
        )
    fig.update_layout(
        title=f"Horizontal error (run {run})",
        height=400,
        xaxis_title="time (s)",
        yaxis_title="horizontal error (m)",
        yaxis_type="log" if log_y else "linear",
    )
    return readable(fig)


def rhat_figure(res: Results, channel: int, run: int = 0, *, log_y: bool = True) -> go.Figure:
    """√R̂ of one channel for the filters that estimate R, with √R0 (nominal) for reference.

    Log y axis by default (``log_y=False``: linear); the nominal √R0 is drawn last, in black on a
    white halo; the y range comes from the epochs without an injected outlier on this channel, so
    a filter's reaction to an injected gross error never flattens the rest (what lies beyond is
    cut off, and the subtitle says so).
    """
    d = res.data
    colors = filter_colors(list(res.runs))
    traces: list = []
    sl = _dec(d.K + 1)
    unit = d.channel_units[channel]
    r0 = float(np.sqrt(d.model.R0[channel, channel]))
    dirty = d.outlier_mask[run, :, channel]
    clean, drawn = [np.array([r0])], []
    for key, fr in res.runs.items():
        if fr.R_hat is None:
            continue
        with np.errstate(invalid="ignore"):
            s = np.sqrt(fr.R_hat[run, :, channel])
        clean.append(s[~dirty])
        drawn.append(s)
        traces.append(
            go.Scattergl(
                x=d.t[sl].astype(np.float32),
                y=s[sl].astype(np.float32),
                mode="lines",
                name=fr.label,
                line={"color": colors[key]},
            )
        )
    truth_line(traces, d.t[[0, -1]], np.array([r0, r0]), "nominal √R0", width=2.0, cls=go.Scattergl)
    traces[-1].line.dash = "dash"
    sub = ""
    yaxis: dict = {"title": {"text": f"√R̂ ({unit})" if unit else "√R̂"}}
    rng = value_range(clean, log_y)
    if rng is not None:
        yaxis.update(y_range_layout(*rng, log_y))
        top = 10 ** yaxis["range"][1] if log_y else yaxis["range"][1]
        if any(np.nanmax(v, initial=-np.inf) > top for v in drawn):
            sub = "y range from epochs without an injected outlier: values above it are cut off"
    fig = go.Figure(data=traces)
    fig.update_layout(
        title=title_layout(f"Estimated noise √R̂ — channel {d.channel_names[channel]}", sub),
        height=380,
        xaxis_title="time (s)",
        yaxis=yaxis,
    )
    return readable(fig)


def flags_figure(res: Results, run: int = 0) -> go.Figure:
    """Epochs where each filter rejected or down-weighted at least one channel."""
    d = res.data
    colors = filter_colors(list(res.runs))
    fig = go.Figure()
    labels = []
    for i, (key, fr) in enumerate(res.runs.items()):
        labels.append(fr.label)
        fl = fr.flags[run]
        w = fr.weights[run]
        rej = ((fl == 2) | (fl == 3) | (fl == 4)).sum(axis=1)
        down = ((fl == 1) | ((w < 0.999) & (fl == 0))).sum(axis=1)
        for cnt, name, sym in ((rej, "rejected", "x"), (down, "down-weighted", "circle-open")):
            k = np.flatnonzero(cnt > 0)
            if k.size:
                fig.add_trace(
                    go.Scattergl(
                        x=d.t[k].astype(np.float32),
                        y=np.full(k.size, i, np.float32),
                        mode="markers",
                        name=f"{fr.label}: {name}",
                        marker={"symbol": sym, "color": colors[key], "size": 6},
                        text=[f"{c} channel(s)" for c in cnt[k]],
                        showlegend=False,
                    )
                )
    fig.update_layout(
        title=title_layout(
            f"Rejected (×) or down-weighted (○), run {run}", "epochs at which a filter did so on any channel"
        ),
        height=140 + 30 * len(labels),
        xaxis_title="time (s)",
        yaxis={"tickvals": list(range(len(labels))), "ticktext": labels, "range": [-0.6, len(labels) - 0.4]},
        showlegend=False,
    )
    return readable(fig)


def flag_table(res: Results) -> pd.DataFrame:
    """Share of (epoch, channel) entries per flag code and filter, in %."""
    rows = []
    for fr in res.runs.values():
        present = np.isfinite(res.data.z[:, 1:])
        fl = fr.flags[:, 1:][present]
        row = {"filter": fr.label}
        for code, name in FLAG_NAMES.items():
            if code:
                row[name] = 100.0 * float(np.mean(fl == code)) if fl.size else 0.0
        rows.append(row)
    df = pd.DataFrame(rows).set_index("filter")
    return df.loc[:, (df != 0).any(axis=0)] if not df.empty else df


def metrics_table(res: Results) -> pd.DataFrame:
    """One row per filter: the real-data headline metrics, each with its 95 % interval over the
    runs where there is one (three significant figures), and the filter's run time.
    """
    from navlab.metrics import timed_steps
    from navlab.tables import cell

    df = summarize(res).set_index(["label", "metric"])
    B, K = res.data.B, res.data.K
    rows = []
    for fr in res.runs.values():
        lab = fr.label
        row = {"filter": lab}
        for m, name in TABLE_METRICS:
            if m == "runtime_s" and (lab, "us_per_run_step") in df.index:
                row[name] = cell(df.loc[(lab, "us_per_run_step"), "value"] * timed_steps(B, K) / 1e6)
            elif m == "diverged" and (lab, m) in df.index:
                row[name] = f"{int(df.loc[(lab, m), 'value'])} of {B}"
            elif (lab, m) in df.index:
                r = df.loc[(lab, m)]
                row[name] = cell(r["value"], r["ci_lo"], r["ci_hi"])
        rows.append(row)
    out = pd.DataFrame(rows).set_index("filter").fillna("—")
    return out.loc[:, (out != "—").any(axis=0)]

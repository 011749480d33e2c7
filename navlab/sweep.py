"""Parameter sweeps: which parameters can be swept, their grids, and 1-D / 2-D sweeps as tasks.

A sweepable parameter is any numeric, widget-visible parameter of the chosen scenario, noise
schedule, outlier model or filters. It has two names: the app's widget key
(``ol.mixture.contamination``, ``fp.chi2-kf.alpha``, ``sc.cv2d.sigma_r2`` …) and the CLI's
``--set`` name (``outliers.contamination``, ``chi2-kf.alpha``, ``scenario.sigma_r2``,
``noise.factor``); :func:`resolve` takes either. Its :attr:`Sweepable.label` says it in words.

Every point of a sweep is an ordinary :class:`~navlab.experiment.ExperimentSpec`, split into
tasks (:mod:`navlab.tasks`: one per filter and block of runs) that run through an executor
(:mod:`navlab.cluster`) and the results store (:mod:`navlab.store`): a task that does not
change between points (a filter whose parameter is not the one swept) is computed once, a
repeated sweep returns at once, an interrupted one resumes. The numbers of a point are exactly
those of ``navlab run`` on its spec (the same runs, the same per-run statistics).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from navlab import tasks as T
from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, param_groups, plan
from navlab.metrics import QUALITY_METRICS, summarize
from navlab.params import describe

MAX_POINTS = 15  # per axis
CLI_GROUP = {"ol": "outliers", "ns": "noise", "sc": "scenario"}  # --set group of each kind
# the metrics a sweep reports with intervals (besides every error group's RMSE)
SWEEP_METRICS = QUALITY_METRICS


@dataclass(frozen=True)
class Sweepable:
    """A numeric parameter that a sweep can vary."""

    id: str  # "ol.mixture.contamination"
    kind: str  # sc | ns | ol | fp
    owner: str
    name: str
    label: str  # in words: "outlier ratio α (outlier model: mixture)"
    default: float
    lo: float | None
    hi: float | None
    integer: bool
    help: str = ""

    @property
    def cli(self) -> str:
        """The ``--set`` name: ``outliers.contamination``, ``huber-kf.gamma`` …."""
        return f"{CLI_GROUP.get(self.kind, self.owner)}.{self.name}"


def _words(help_: str, name: str) -> str:
    """A parameter in words: its help text up to the first ';' (or its name)."""
    text = (help_ or "").split(";")[0].strip()
    if not text:
        return name.replace("_", " ")
    return text if len(text) <= 70 else text[:67].rstrip() + "…"


def sweepables(spec: ExperimentSpec) -> list[Sweepable]:
    """Numeric parameters of the spec's outlier model, noise schedule, scenario and filters."""
    where = {
        "ol": f"outlier model {spec.outliers}",
        "ns": f"noise schedule {spec.noise_schedule}",
        "sc": f"scenario {spec.scenario}",
    }
    order = [*where, "fp"]  # the outlier model's parameters first
    groups = sorted(param_groups(spec), key=lambda g: order.index(g.kind))
    out = []
    for g in groups:
        kind, owner = g.kind, g.owner
        place, defaults = where.get(kind) or g.cls.label, g.defaults()
        for p in describe(g.Params):
            d = defaults[p["name"]]
            if not p.get("ui", True) or isinstance(d, bool) or not isinstance(d, (int, float)):
                continue
            out.append(
                Sweepable(
                    id=f"{kind}.{owner}.{p['name']}",
                    kind=kind,
                    owner=owner,
                    name=p["name"],
                    label=f"{_words(p.get('help', ''), p['name'])} — {place}",
                    default=float(d),
                    lo=p.get("lo"),
                    hi=p.get("hi"),
                    integer=isinstance(d, int),
                    help=p.get("help", ""),
                )
            )
    return out


def resolve(spec: ExperimentSpec, name: str) -> Sweepable:
    """The sweepable parameter called ``name`` (``GROUP.NAME`` as in ``--set``, or a widget id)."""
    params = sweepables(spec)
    for s in params:
        if name in (s.id, s.cli):
            return s
    known = ", ".join(s.cli for s in params)
    raise NavlabError(
        f"--param {name!r} is not a numeric parameter of this experiment; choose one of: {known}"
    )


def default_range(s: Sweepable) -> tuple[float, float]:
    """A sensible default range: the admissible range clipped around the default."""
    d = s.default
    if s.id.endswith(".contamination"):
        lo, hi = 0.0, 0.3
    elif d > 0:
        lo, hi = d / 4, d * 4
    else:
        lo, hi = (s.lo if s.lo is not None else -1.0), (s.hi if s.hi is not None else 1.0)
    if s.lo is not None:
        lo = max(lo, s.lo)
    if s.hi is not None:
        hi = min(hi, s.hi)
    if s.integer:
        lo, hi = math.ceil(lo), math.floor(hi)
    return float(lo), float(hi)


def spaced(lo: float, hi: float, n: int, log: bool) -> np.ndarray:
    """``n`` values from lo to hi, linearly or log-spaced, at 12 significant digits: the values a
    user would type (0.05, not linspace's 0.049999999999999996, in every table and link).
    """
    v = np.geomspace(lo, hi, n) if log else np.linspace(lo, hi, n)
    return np.array([float(f"{x:.12g}") for x in v])


def grid(s: Sweepable, lo: float, hi: float, n: int, log: bool) -> np.ndarray:
    """``n`` values from lo to hi (log-spaced if ``log``), inside the admissible range."""
    if not 2 <= n <= MAX_POINTS:
        raise NavlabError(f"choose between 2 and {MAX_POINTS} sweep points")
    if not hi > lo:
        raise NavlabError("the sweep's upper end must be larger than its lower end")
    if (s.lo is not None and lo < s.lo) or (s.hi is not None and hi > s.hi):
        raise NavlabError(f"'{s.name}' must stay within [{s.lo}, {s.hi}]")
    if log and lo <= 0:
        raise NavlabError("a log-spaced sweep needs a positive lower end")
    v = spaced(lo, hi, n, log)
    if s.integer:
        v = np.unique(np.round(v).astype(int)).astype(float)
    return v


def check_values(s: Sweepable, values: Sequence[float]) -> np.ndarray:
    """Explicit sweep values (``--values``): finite, distinct, inside the admissible range."""
    v = np.asarray(values, dtype=float)
    if not 1 <= v.size <= MAX_POINTS:
        raise NavlabError(f"give between 1 and {MAX_POINTS} values for {s.cli}")
    if not np.isfinite(v).all():
        raise NavlabError(f"the values of {s.cli} must be finite numbers")
    if np.unique(v).size != v.size:
        raise NavlabError(f"the values of {s.cli} must be distinct")
    bad = [x for x in v if (s.lo is not None and x < s.lo) or (s.hi is not None and x > s.hi)]
    if bad:
        raise NavlabError(f"{s.cli} must stay within [{s.lo}, {s.hi}]; {bad[0]:g} is outside")
    if s.integer and not np.all(v == np.round(v)):
        raise NavlabError(f"{s.cli} takes whole numbers")
    return v


def apply(spec: ExperimentSpec, s: Sweepable, value: float) -> ExperimentSpec:
    """The spec with parameter ``s`` set to ``value`` (validated by :func:`plan`)."""
    v: Any = round(value) if s.integer else float(value)
    if s.kind == "sc":
        new = spec.replace(scenario_params={**spec.scenario_params, s.name: v})
        if s.name == "epochs":
            new = new.replace(epochs=None)
    elif s.kind == "ns":
        new = spec.replace(noise_params={**spec.noise_params, s.name: v})
    elif s.kind == "ol":
        extra = {}
        if s.name == "contamination":
            extra["contamination"] = None
        if s.name == "scale":
            extra["outlier_scale"] = None
        new = spec.replace(outlier_params={**spec.outlier_params, s.name: v}, **extra)
    elif s.kind == "fp":
        fp = {k: dict(d) for k, d in spec.filter_params.items()}
        fp.setdefault(s.owner, {})[s.name] = v
        new = spec.replace(filter_params=fp)
    else:
        raise NavlabError(f"unknown sweep parameter kind {s.kind!r}")
    plan(new)
    return new


# --------------------------------------------------------------------------- sweeps as tasks


@dataclass(frozen=True)
class Axis:
    """One axis of a sweep: a parameter and its values."""

    param: Sweepable
    values: tuple[float, ...]


@dataclass
class Sweep:
    """A 1-D or 2-D sweep: its points, and the tasks of every point."""

    spec: ExperimentSpec
    axes: tuple[Axis, ...]
    points: list[tuple[tuple[float, ...], ExperimentSpec]] = field(default_factory=list)
    tasks: list[dict[str, list[T.Task]]] = field(default_factory=list)

    def all_tasks(self) -> list[T.Task]:
        return [t for pt in self.tasks for ts in pt.values() for t in ts]


def make_sweep(spec: ExperimentSpec, axes: Sequence[Axis], block: int = T.BLOCK) -> Sweep:
    """The points (the product of the axes' values) and their tasks."""
    if not 1 <= len(axes) <= 2:
        raise NavlabError("a sweep has one or two parameters")
    if len(axes) == 2 and axes[0].param.id == axes[1].param.id:
        raise NavlabError("--param and --param2 must be different parameters")
    sw = Sweep(spec, tuple(axes))
    grids = [a.values for a in axes]
    combos = [(x,) for x in grids[0]] if len(axes) == 1 else [(x, y) for x in grids[0] for y in grids[1]]
    for combo in combos:
        s = spec
        for a, v in zip(axes, combo, strict=True):
            s = apply(s, a.param, v)
        sw.points.append((tuple(float(v) for v in combo), s))
        sw.tasks.append(T.tasks_for(s, block=block))
    return sw


def point_rows(spec: ExperimentSpec, parts: dict[str, list[T.TaskResult]]) -> pd.DataFrame:
    """The tidy metric rows of one point (:func:`navlab.metrics.summarize` with intervals on
    the sweep's metrics).
    """
    res = T.summary_results(spec, parts)
    head = [f"rmse_{g}" for g in res.data.groups] + ["mean_rmse_pos", *SWEEP_METRICS]
    head += list(res.data.extras.get("metrics", {}))
    return summarize(res, metrics=head)


@dataclass
class SweepResult:
    """The rows of the finished points; ``complete`` False after a stop (the finished tasks are
    in the store, so running it again resumes).
    """

    rows: pd.DataFrame
    done_points: int
    total_points: int
    tasks_done: int
    tasks_total: int
    cached: int  # tasks read from the store

    @property
    def complete(self) -> bool:
        return self.done_points == self.total_points


def run_sweep(
    sw: Sweep,
    *,
    store: Any = None,
    executor: Any = None,
    on_progress: Callable[[int, int], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    tick: Callable[[], None] | None = None,
) -> SweepResult:
    """Compute every point of ``sw`` (tasks through ``executor`` and ``store``) → tidy rows:
    ``param``, ``param_value`` (and ``param2``, ``param2_value``) beside the metric columns of
    :func:`navlab.metrics.summarize`.
    """
    tasks = sw.all_tasks()
    got = T.compute(
        tasks, store=store, executor=executor, on_progress=on_progress, should_stop=should_stop, tick=tick
    )
    frames = []
    done = 0
    for (combo, spec), pt in zip(sw.points, sw.tasks, strict=True):
        if not all(t.key in got for ts in pt.values() for t in ts):
            continue
        done += 1
        rows = point_rows(spec, {k: [got[t.key] for t in ts] for k, ts in pt.items()})
        cols: dict[str, Any] = {}
        for i, (a, v) in enumerate(zip(sw.axes, combo, strict=True)):
            tag = "param" if i == 0 else "param2"
            cols[tag] = a.param.cli
            cols[f"{tag}_value"] = int(v) if a.param.integer else v
        frames.append(pd.DataFrame([cols] * len(rows)).join(rows))
    rows = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    cached = sum(1 for r in got.values() if r.cached)
    unique = len({t.key for t in tasks})
    return SweepResult(rows, done, len(sw.points), len(got), unique, cached)


# --------------------------------------------------------------------------- the sweep's tables


def metric_tables(
    out: SweepResult, sw: Sweep, metric: str
) -> tuple[str, list[tuple[str, pd.DataFrame]], str]:
    """One metric of a sweep as display tables: (title, [(filter label or "", table)], how).

    One parameter: a table point × filter; two: a table point × point per filter. Cells are
    "value [lo, hi]"; ``how`` says how many tasks, points, runs and seeds, and the interval method.
    """
    from navlab import tables

    spec, axes = sw.spec, sw.axes
    df = out.rows
    d = df[df.metric == metric]
    if d.empty:
        raise NavlabError(
            f"--metric {metric}: not a metric of this sweep; e.g. {', '.join(dict.fromkeys(df.metric))}"
        )
    d = d.assign(cell=[tables.cell(v, lo, hi) for v, lo, hi in zip(d.value, d.ci_lo, d.ci_hi, strict=True)])
    unit = next((u for u in d.unit if isinstance(u, str) and u), "")
    p1 = axes[0].param
    title = f"{metric}{f' ({unit})' if unit else ''} [95 % interval] against {p1.cli} — {p1.label}"
    parts: list[tuple[str, pd.DataFrame]] = []
    if len(axes) == 1:
        wide = d.pivot_table(index="param_value", columns="label", values="cell", aggfunc="first", sort=False)
        wide.index.name = p1.cli
        parts.append(("", wide))
    else:
        p2 = axes[1].param
        title += f", and {p2.cli} — {p2.label}"
        for label, g in d.groupby("label", sort=False):
            wide = g.pivot_table(index="param_value", columns="param2_value", values="cell", aggfunc="first")
            wide.index.name = f"{p1.cli} \\ {p2.cli}"
            wide.columns = [f"{c:.4g}" for c in wide.columns]
            parts.append((str(label), wide))
    how = (
        f"{out.tasks_total} tasks ({out.cached} from the results store), {len(sw.points)} points × "
        f"{len(spec.filters)} filters × {spec.runs} runs, seed {spec.seed} (runs 0 to {spec.runs - 1} "
        f"at every point); {tables.interval_note(spec.runs)}"
    )
    return title, parts, how


def text(out: SweepResult, sw: Sweep, metric: str) -> str:
    """The CLI's sweep table(s) as plain text, with the line that says how they were made."""
    from navlab import tables

    title, parts, how = metric_tables(out, sw, metric)
    lines = [title]
    for label, wide in parts:
        lines += (["", label] if label else []) + [tables.text_table(wide)]
    lines.append(f"  {how}")
    return "\n".join(lines) + "\n"


def paper_tables(out: SweepResult, sw: Sweep, metric: str, fmt: str) -> str:
    """The sweep table(s) as Markdown or LaTeX booktabs (``navlab sweep --format``, the Sweep
    page's download): one table per filter for two parameters, captions naming runs, seeds and
    the interval method; no bold (the sweep's points carry no paired test).
    """
    from navlab import tables

    title, parts, how = metric_tables(out, sw, metric)
    texts = []
    for i, (label, wide) in enumerate(parts):
        cap = f"{label + ': ' if label else ''}{title}. {how} No bold: sweep points carry no paired test."
        texts.append(
            tables.render(tables.Table(wide.fillna("")), fmt, cap, label=f"tab:navlab-sweep-{i + 1}")
        )
    return "\n".join(texts)

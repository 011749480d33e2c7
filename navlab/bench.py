"""``navlab bench``: every registered filter, tuned on the same budget, on a fixed, versioned suite.

A suite (:data:`SUITES`) is a list of problems — scenario × noise schedule × outlier model ×
contamination level — with one tuning budget. On every problem each filter that runs on the
scenario (plugins included: the bench iterates the filter registry) is tuned by
:func:`navlab.tune.tune` — the same design size and successive-halving schedule for every
filter, candidates scored on TRAINING seeds only — and judged on disjoint TEST seeds
(docs/STATISTICS.md §6). Per problem (:func:`problem_table`), the tuned filters are ranked on the
headline pooled RMSE with

* its 95 % interval (the BCa bootstrap of :mod:`navlab.stats`, as every navlab table),
* the paired test against the filter with the lowest RMSE, Holm-corrected across the others,
  lost runs scored by the loss rule (§5) — "best" only when it is better than every other,
* the gap to the floor: RMSE / the posterior Cramér–Rao bound (:mod:`navlab.pcrb`), with the
  interval of the RMSE over the bound,
* diverged runs ("k of N"; more than 5 %: ranked below every reliable filter), and the cost in
  µs per run and step (a timing: it depends on the machine and on what else runs).

The overall standing (:func:`overall`) is the geometric mean over the problems of each filter's
gap to the floor — problems of different units and difficulty weigh alike — with a percentile
bootstrap interval that resamples the test runs of every problem independently (the same
resamples for every filter: paired), the paired ratio to the lowest filter, its two-sided
bootstrap p (§3) and Holm's correction across the filters. A run a filter lost is scored, for
that filter, as the worst per-run mean squared error any filter reached on the problem (§5's
loss rule, the worst over every filter so that one value serves every pair).

Every task goes through the results store and the executor (:mod:`navlab.tasks`,
:mod:`navlab.cluster`): a bench killed anywhere (even ``kill -9``) resumes from the finished
tasks; the numbers do not depend on where the tasks ran (serial, the embedded cluster, a Dask
cluster by address). The last bench is written as JSON (:func:`save`) for the Leaderboard page.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from navlab import metrics as M
from navlab import pcrb
from navlab import stats as S
from navlab import tune as TU
from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, plan
from navlab.filters import is_oracle, registry
from navlab.tables import Table, best_filter, cell, text_table, verdict_cell

SUITE_VERSION = "1"
ENV_DIR = "NAVLAB_BENCH_DIR"
LAST = "last-bench.json"
OVERALL_BOOT = 2000  # resamples of the overall standing
OVERALL_SEED = 27


@dataclass(frozen=True)
class Problem:
    """One problem of a suite: an experiment without filters (its seed is the test seed)."""

    name: str
    spec: ExperimentSpec


@dataclass(frozen=True)
class Suite:
    """A fixed list of problems and the tuning budget every filter gets on each."""

    name: str
    problems: tuple[Problem, ...]
    budget: int
    train_runs: int
    test_runs: int
    version: str = SUITE_VERSION

    def describe(self) -> str:
        return (
            f"suite '{self.name}' v{self.version}: {len(self.problems)} problems; per filter and "
            f"problem a tuning budget of {self.budget} candidates on {self.train_runs} training "
            f"runs (seed + 1), judged on {self.test_runs} test runs (the problem's seed)"
        )


def _problem(i: int, scenario: str, schedule: str, outliers: str, level: float | None) -> Problem:
    name = f"{scenario} · {schedule} · {outliers}" + (f" α={level:g}" if level is not None else "")
    spec = ExperimentSpec(
        scenario=scenario,
        filters=("kf",),
        seed=1000 + 2 * i,  # test seed; training seed + 1: disjoint across problems too
        noise_schedule=schedule,
        outliers=outliers,
        contamination=level,
    )
    return Problem(name, spec)


def _grid(scenarios, schedules, outliers) -> tuple[Problem, ...]:
    out, i = [], 0
    for sc in scenarios:
        for sch in schedules:
            for o, level in outliers:
                out.append(_problem(i, sc, sch, o, level))
                i += 1
    return tuple(out)


SMALL = Suite(
    "small",
    _grid(["cv2d"], ["constant", "step"], [("mixture", 0.05), ("mixture", 0.2)]),
    budget=8,
    train_runs=16,
    test_runs=100,
)
FULL = Suite(
    "full",
    _grid(
        ["cv2d", "sins-gps", "gps-ins-pseudorange"],
        ["constant", "step", "ramp"],
        [("none", None), ("mixture", 0.05), ("mixture", 0.1), ("mixture", 0.2), ("student-t", None)],
    ),
    budget=16,
    train_runs=32,
    test_runs=200,
)
# seconds, not minutes: the tests' and benchmarks/bench_scale.py's suite (and a first look)
TINY = Suite(
    "tiny",
    tuple(
        Problem(
            f"cv2d {o}",
            ExperimentSpec(scenario="cv2d", filters=("kf",), seed=50 + 2 * i, epochs=40, outliers=o),
        )
        for i, o in enumerate(["mixture", "student-t"])
    ),
    budget=4,
    train_runs=8,
    test_runs=12,
)
SUITES = {s.name: s for s in (TINY, SMALL, FULL)}


def get_suite(name: str) -> Suite:
    if name not in SUITES:
        raise NavlabError(f"--suite {name!r}: choose one of {', '.join(SUITES)}")
    return SUITES[name]


def applicable(
    spec: ExperimentSpec, filters: Sequence[str] | None = None
) -> tuple[list[str], dict[str, str]]:
    """The registered filters (or ``filters``) that run on ``spec``'s scenario, and why the
    others do not (their own message).
    """
    keys = list(filters) if filters else list(registry())
    ok, no = [], {}
    for k in keys:
        try:
            plan(spec.replace(filters=(k,), runs=1))
        except NavlabError as exc:
            no[k] = str(exc)
        else:
            ok.append(k)
    unknown = [k for k in keys if k not in registry()]
    if unknown:
        raise NavlabError(f"--filters: unknown filter(s) {', '.join(unknown)}; see navlab list filters")
    return ok, no


def setups(suite: Suite, filters: Sequence[str] | None = None) -> list[TU.Setup]:
    """The tuning set-up of every problem (validated before any work)."""
    out = []
    for p in suite.problems:
        keys, _ = applicable(p.spec, filters)
        if not keys:
            raise NavlabError(f"no chosen filter runs on problem {p.name}")
        if all(is_oracle(k) for k in keys):
            raise NavlabError(
                "--filters: choose at least one filter that is not an oracle (the oracle is the "
                "genie shown beside the ranking, never ranked)"
            )
        spec = p.spec.replace(filters=tuple(keys), runs=suite.test_runs)
        out.append(TU.setup(spec, budget=suite.budget, train_runs=suite.train_runs))
    return out


# --------------------------------------------------------------------------- running


@dataclass
class ProblemResult:
    problem: Problem
    tune: TU.TuneResult
    floor: tuple[float, float, float] | None  # pcrb of the headline group (value, lo, hi)
    group: str
    tuned: Any = None  # every filter's tuned variant (:func:`tuned_all`)
    table: pd.DataFrame = field(default_factory=pd.DataFrame)


@dataclass
class BenchResult:
    suite: Suite
    problems: list[ProblemResult]
    overall: pd.DataFrame
    wall_s: float
    computed: int
    cached: int
    where: str = ""


def run(
    suite: Suite,
    *,
    filters: Sequence[str] | None = None,
    store: Any = None,
    executor: Any = None,
    on_progress: Callable[[int, int], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    tick: Callable[[], None] | None = None,
) -> BenchResult:
    """Tune and judge every filter on every problem of ``suite`` (module note). Raises
    :class:`navlab.tasks.StoppedError` when stopped (finished tasks are in ``store``).
    """
    t0 = time.perf_counter()
    sts = setups(suite, filters)
    totals = [TU.count_tasks(st) for st in sts]
    total, base = sum(totals), 0
    out: list[ProblemResult] = []
    computed = cached = 0
    for p, st, n in zip(suite.problems, sts, totals, strict=True):

        def prog(done: int, _total: int, base: int = base) -> None:
            if on_progress is not None:
                on_progress(base + done, total)

        r = TU.tune(
            st,
            store=store,
            executor=executor,
            on_progress=prog,
            should_stop=should_stop,
            tick=tick,
            report=False,
        )
        base += n
        computed += r.computed
        cached += r.cached
        out.append(_judge(p, r))
    ov = overall(out)
    where = getattr(executor, "report", "") if executor is not None else ""
    return BenchResult(suite, out, ov, time.perf_counter() - t0, computed, cached, where)


def _headline_group(res: Any) -> str:
    from navlab.scenarios import scenario_registry

    head = scenario_registry()[res.spec.scenario].headline
    return next((g for g in head if g in res.data.groups), next(iter(res.data.groups)))


def tuned_all(r: TU.TuneResult) -> Any:
    """Every filter's tuned variant (the oracles' too), keyed by filter: the problem's
    experiment with the tuned parameters — what :meth:`navlab.tune.TuneResult.tuned_spec` gives
    Compare, so a Compare run of it shows these numbers (the judged runs are those every
    reliable filter of THIS set kept, STATISTICS.md §5).
    """
    from dataclasses import replace

    from navlab.experiment import FilterInfo

    res = r.test
    keys = list(r.setup.spec.filters)
    stats = {k: replace(res.stats[k + TU.TEST_SUFFIX], key=k) for k in keys}
    runs = {k: FilterInfo(k, res.runs[k + TU.TEST_SUFFIX].label) for k in keys}
    return replace(res, stats=stats, runs=runs)


def _judge(p: Problem, r: TU.TuneResult) -> ProblemResult:
    tres = tuned_all(r)
    g = _headline_group(tres)
    b = pcrb.bound(r.test.spec)
    floor = None
    if b is not None:
        grp = tres.data.groups[g]
        floor = b.floor(grp.idx, tres.data.window, grp.scale)
    pr = ProblemResult(p, r, floor, g, tres)
    pr.table = problem_table(pr)
    return pr


def problem_table(pr: ProblemResult) -> pd.DataFrame:
    """The ranked rows of one problem (tuned filters; the oracle as the genie's reference)."""
    r, g = pr.tune, pr.group
    metric = f"rmse_{g}"
    tres = pr.tuned
    sm = M.summary(tres)
    jd = sm.judgement
    best, vs = best_filter(tres, metric) if len(tres.stats) > 1 else (None, pd.DataFrame())
    among = [k for k in tres.stats if registry()[k].family != "oracle"]
    cand = str(vs["vs"].iloc[0]) if len(vs) else (among[0] if among else "")
    vs = vs.set_index("filter") if len(vs) else vs
    unit = tres.data.groups[g].unit
    B, K = tres.data.B, tres.data.K
    steps = M.timed_steps(B, K)
    rows = []
    fl = pr.floor
    reg = registry()
    for k, st in tres.stats.items():
        e = sm.estimate(k, metric) if metric in sm.metrics_of(k) else S.Estimate(math.nan)
        row = dict(
            problem=pr.problem.name,
            filter=k,
            label=tres.runs[k].label,
            metric=metric,
            unit=unit,
            value=e.value,
            ci_lo=e.lo if e.has_ci else math.nan,
            ci_hi=e.hi if e.has_ci else math.nan,
            diverged=jd.lost(k),
            runs=jd.n_runs,
            reliable=bool(jd.reliable[k]),
            us_per_run_step=1e6 * st.runtime_s / steps,
            tuned=TU._values_text(r, k),
        )
        if fl is not None and fl[0] > 0:
            row.update(gap=e.value / fl[0], gap_lo=row["ci_lo"] / fl[2], gap_hi=row["ci_hi"] / fl[1])
        if is_oracle(k):  # the genie: shown, never ranked
            row.update(label=reg[k].label, verdict="genie (told the outliers and the true R): not ranked")
        elif k == cand:
            row.update(verdict="best" if best else "lowest (not significantly)")
        elif len(vs) and k in vs.index:
            v = vs.loc[k]
            row.update(
                verdict=str(v["verdict"]),
                delta=float(v["value"]),
                delta_lo=float(v["ci_lo"]),
                delta_hi=float(v["ci_hi"]),
                p_holm=float(v["p_holm"]),
                vs_text=verdict_cell(v, tres.runs[cand].label, short=True),
            )
        rows.append(row)
    df = pd.DataFrame(rows)
    ranked = df[~df["verdict"].astype(str).str.startswith("genie")].copy()
    ranked["_u"] = ~ranked["reliable"].astype(bool)
    ranked = ranked.sort_values(["_u", "value"], kind="stable").drop(columns="_u")
    ranked.insert(0, "rank", np.arange(1, len(ranked) + 1))
    rest = df[df["verdict"].astype(str).str.startswith("genie")].copy()
    rest.insert(0, "rank", pd.NA)
    return pd.concat([ranked, rest], ignore_index=True)


def _per_run(pr: ProblemResult) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Per filter the per-run squared-error sums of the headline group, lost runs scored as the
    worst per-run mean square of any filter on the problem; and the epochs per run.
    """
    tres = pr.tuned
    g = pr.group
    jd = M.summary(tres).judgement
    sse = {k: np.asarray(st.sse[g], dtype=float) for k, st in tres.stats.items()}
    n = float(next(iter(tres.stats.values())).epochs)
    kept = [v[jd.valid[k]] for k, v in sse.items() if jd.valid[k].any()]
    kept_all = np.concatenate(kept) if kept else np.array([np.nan])
    kept_all = kept_all[np.isfinite(kept_all)]
    worst = float(kept_all.max()) if kept_all.size else math.nan
    out = {}
    for k, v in sse.items():
        v = v.copy()
        v[~jd.valid[k]] = worst
        out[k] = v
    return out, np.full(jd.n_runs, n)


def overall(results: Sequence[ProblemResult]) -> pd.DataFrame:
    """The overall standing (module note): geometric mean of the gap to the floor over the
    problems, percentile bootstrap interval, paired ratio to the lowest filter with Holm.
    """
    usable = [pr for pr in results if pr.floor is not None and pr.floor[0] > 0]
    if not usable:
        return pd.DataFrame()
    keys = set.intersection(*(set(pr.table.loc[pr.table["rank"].notna(), "filter"]) for pr in usable))
    keys = [k for k in usable[0].table["filter"] if k in keys]
    if not keys:
        return pd.DataFrame()
    rng = np.random.default_rng(np.random.SeedSequence([OVERALL_SEED, len(usable)]))
    logs = {k: np.zeros(OVERALL_BOOT) for k in keys}
    point = dict.fromkeys(keys, 0.0)
    unreliable: dict[str, int] = dict.fromkeys(keys, 0)
    for pr in usable:
        sse, n = _per_run(pr)
        N = n.size
        W = S.resample_counts(N, OVERALL_BOOT, rng).astype(float)  # (B, N): the same for all
        for k in keys:
            point[k] += math.log(math.sqrt(sse[k].sum() / n.sum()) / pr.floor[0])
            with np.errstate(divide="ignore", invalid="ignore"):
                logs[k] += np.log(np.sqrt((W @ sse[k]) / (W @ n)) / pr.floor[0])
            row = pr.table[pr.table["filter"] == k].iloc[0]
            unreliable[k] += int(not bool(row["reliable"]))
    P = len(usable)
    score = {k: math.exp(point[k] / P) for k in keys}
    boot = {k: logs[k] / P for k in keys}
    reliable = [k for k in keys if unreliable[k] == 0]
    pool = reliable or keys
    cand = min(pool, key=lambda k: score[k])
    pvals, bounds, deltas = {}, {}, {}
    for k in keys:
        if k == cand:
            continue
        d = boot[k] - boot[cand]
        d = d[np.isfinite(d)]
        p = 2 * min(float(np.mean(d <= 0)), float(np.mean(d >= 0))) if d.size else math.nan
        floor_p = 1.0 / OVERALL_BOOT
        bounds[k] = bool(d.size) and p < floor_p
        pvals[k] = max(p, floor_p) if d.size else math.nan
        lo, hi = np.quantile(d, [0.025, 0.975]) if d.size else (math.nan, math.nan)
        deltas[k] = (math.exp(math.log(score[k]) - math.log(score[cand])), math.exp(lo), math.exp(hi))
    adj, adj_bound = S.holm_bounds(pvals, bounds)
    rows = []
    for k in keys:
        b = np.exp(boot[k][np.isfinite(boot[k])])
        lo, hi = np.quantile(b, [0.025, 0.975]) if b.size else (math.nan, math.nan)
        row = dict(
            filter=k,
            label=registry()[k].label,
            score=score[k],
            ci_lo=float(lo),
            ci_hi=float(hi),
            problems=P,
            problems_unreliable=unreliable[k],
        )
        if k in deltas:
            ratio, rlo, rhi = deltas[k]
            ph = adj.get(k, math.nan)
            sig = np.isfinite(ph) and ph < 0.05
            verdict = ("worse" if ratio > 1 else "better") if sig else "indistinguishable"
            row.update(ratio=ratio, ratio_lo=rlo, ratio_hi=rhi, p=pvals[k], p_holm=ph)
            row["p_holm_bound"] = "<" if adj_bound.get(k) else ""
            row["verdict"] = verdict
        rows.append(row)
    df = pd.DataFrame(rows)
    others = df[df["filter"] != cand]
    best = len(others) > 0 and (others["verdict"] == "worse").all() and unreliable[cand] == 0
    df.loc[df["filter"] == cand, "verdict"] = "best" if best else "lowest (not significantly)"
    df["_u"] = df["problems_unreliable"] > 0
    df = df.sort_values(["_u", "score"], kind="stable").drop(columns="_u").reset_index(drop=True)
    df.insert(0, "rank", np.arange(1, len(df) + 1))
    return df


# --------------------------------------------------------------------------- output


def rows(b: BenchResult) -> pd.DataFrame:
    """Tidy rows: ``kind`` "problem" (every filter on every problem) and "overall"."""
    parts = []
    for pr in b.problems:
        t = pr.table.copy()
        t.insert(0, "kind", "problem")
        if pr.floor is not None:
            t["pcrb"], t["pcrb_lo"], t["pcrb_hi"] = pr.floor
        parts.append(t)
    if len(b.overall):
        o = b.overall.copy()
        o.insert(0, "kind", "overall")
        parts.append(o)
    return pd.concat(parts, ignore_index=True)


def _gap_cell(r: Any) -> str:
    g = r.get("gap", math.nan)
    if not np.isfinite(g):
        return "—"
    return cell(g, r.get("gap_lo", math.nan), r.get("gap_hi", math.nan))


def problem_text_table(pr: ProblemResult) -> Table:
    t = pr.table
    unit = str(t["unit"].iloc[0]) if len(t) else ""
    cells = []
    for r in t.to_dict("records"):
        div = r.get("diverged", math.nan)
        div = int(div) if np.isfinite(div) else 0
        runs = r.get("runs", math.nan)
        cells.append(
            {
                "rank": "" if pd.isna(r["rank"]) else int(r["rank"]),
                "filter": r["label"],
                f"RMSE ({unit})": cell(r["value"], r["ci_lo"], r["ci_hi"]),
                "gap to floor (×)": _gap_cell(r),
                "diverged": f"{div} of {int(runs)}" if div else ("0" if np.isfinite(runs) else ""),
                "µs/run·step": S.sig3(r["us_per_run_step"])
                if np.isfinite(r.get("us_per_run_step", math.nan))
                else "",
                "verdict": r.get("vs_text") if isinstance(r.get("vs_text"), str) else r["verdict"],
            }
        )
    df = pd.DataFrame(cells).set_index("rank")
    notes = []
    if pr.floor is not None:
        v, lo, hi = pr.floor
        notes.append(
            f"floor (posterior Cramér–Rao bound of the {pr.group} RMSE): {S.sig3(v)} {unit}"
            + (f" [{S.sig3(lo)}, {S.sig3(hi)}]" if hi > lo else " (exact)")
        )
    return Table(df, notes)


def overall_text_table(b: BenchResult) -> Table:
    """The overall standing as a display table (empty cells where a value does not apply)."""
    o = b.overall
    cells = pd.DataFrame(
        {
            "rank": o["rank"],
            "filter": o["label"],
            "gap to floor, geometric mean (×)": [cell(r.score, r.ci_lo, r.ci_hi) for r in o.itertuples()],
            "÷ lowest": [
                ""
                if not np.isfinite(getattr(r, "ratio", math.nan))
                else cell(r.ratio, r.ratio_lo, r.ratio_hi)
                for r in o.itertuples()
            ],
            "p (Holm)": [
                ""
                if not np.isfinite(getattr(r, "p_holm", math.nan))
                else f"{r.p_holm_bound}{S.sig3(r.p_holm)}"
                for r in o.itertuples()
            ],
            "verdict": o["verdict"],
            "unreliable on": [f"{r.problems_unreliable} of {r.problems}" for r in o.itertuples()],
        }
    ).set_index("rank")
    return Table(cells, [])


def text(b: BenchResult) -> str:
    lines = [b.suite.describe() + "."]
    for pr in b.problems:
        lines += [
            "",
            f"== {pr.problem.name} (tuned; test seed {pr.problem.spec.seed}) ==",
            problem_text_table(pr).text(),
        ]
    if len(b.overall):
        n = int(b.overall["problems"].iloc[0])
        lines += ["", f"== overall standing over {n} problems ==", text_table(overall_text_table(b).cells)]
    lines += ["", *(f"  {n}" for n in notes(b))]
    return "\n".join(lines) + "\n"


def paper(b: BenchResult, fmt: str) -> str:
    """The overall standing and every problem's table as Markdown or LaTeX (``navlab bench
    --format markdown|latex``), each with its caption; the notes under the overall standing.
    """
    from navlab.tables import render

    out = []
    if len(b.overall):
        t = overall_text_table(b)
        t.notes = notes(b)
        n = int(b.overall["problems"].iloc[0])
        out.append(
            render(
                t,
                fmt,
                f"navlab bench, {b.suite.describe()}: overall standing over {n} problems.",
                "tab:bench",
            )
        )
    for i, pr in enumerate(b.problems):
        cap = (
            f"{pr.problem.name}: tuned filters on test seed {pr.problem.spec.seed}, {b.suite.test_runs} runs."
        )
        out.append(render(problem_text_table(pr), fmt, cap, f"tab:bench-{i}"))
    return "\n\n".join(out) + "\n"


def notes(b: BenchResult) -> list[str]:
    st0 = b.problems[0].tune.setup if b.problems else None
    out = [
        "Tuning: "
        + (st0.schedule.text() if st0 else "")
        + f"; objective {st0.objective.name if st0 else ''} "
        "on the training seed; every number here is on the test seed (STATISTICS.md §6).",
        "Per problem: RMSE with its 95 % BCa bootstrap interval over the test runs; verdict: paired "
        "difference from the filter with the lowest RMSE, Holm-corrected across the others; lost "
        f"runs: {M.LOSS_RULE}; a filter diverging in more than 5 % of the runs ranks below.",
        "Gap to floor: RMSE / the posterior Cramér–Rao bound (navlab.pcrb), the RMSE's interval "
        "over the bound's; the oracle, a genie told the outliers, may go below 1.",
        "Overall: geometric mean over the problems of the gap to the floor; 95 % percentile "
        f"bootstrap interval (B = {OVERALL_BOOT}, every problem's test runs resampled on their "
        "own, the same resamples for every filter); ÷ lowest: paired ratio to the filter with the "
        "lowest score, two-sided bootstrap p, Holm across the filters; a lost run scores the "
        "problem's worst per-run mean square.",
        "µs/run·step: the filter's own time per run and epoch in the task that ran it (a timing "
        "of this machine, not a statistic).",
        f"Tasks: {b.computed} computed, {b.cached} from the results store; wall time {b.wall_s:.1f} s"
        + (f"; ran {b.where}" if b.where else "")
        + ".",
    ]
    return out


def default_dir() -> Path:
    from navlab.store import default_dir as store_dir

    return Path(os.environ.get(ENV_DIR) or store_dir().parent / "bench")


def to_json(b: BenchResult) -> dict[str, Any]:
    probs = []
    for pr in b.problems:
        spec = pr.tune.tuned_spec()  # every filter tuned, on the test seed: Compare's experiment
        probs.append(
            {
                "name": pr.problem.name,
                "spec": json.loads(spec.to_json()),
                "group": pr.group,
                "floor": list(pr.floor) if pr.floor is not None else None,
                "rows": json.loads(pr.table.to_json(orient="records", double_precision=15)),
            }
        )
    return {
        "suite": b.suite.name,
        "version": b.suite.version,
        "description": b.suite.describe(),
        "created": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "problems": probs,
        "overall": json.loads(b.overall.to_json(orient="records", double_precision=15))
        if len(b.overall)
        else [],
        "notes": notes(b),
        "wall_s": b.wall_s,
        "tasks": {"computed": b.computed, "cached": b.cached},
    }


def save(b: BenchResult, folder: str | Path | None = None) -> Path:
    """Write the bench as JSON (atomically) to ``folder`` (default :func:`default_dir`)."""
    d = Path(folder) if folder is not None else default_dir()
    try:
        d.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".json", dir=d)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(to_json(b), f, indent=1)
        os.replace(tmp, d / LAST)
    except OSError as exc:
        raise NavlabError(f"cannot write the bench to {d}: {exc.strerror}; choose --outdir DIR") from None
    return d / LAST


def load(folder: str | Path | None = None) -> dict[str, Any] | None:
    """The last bench written to ``folder`` (None: none yet, or unreadable)."""
    p = (Path(folder) if folder is not None else default_dir()) / LAST
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


# --------------------------------------------------------------------------- cost on paper


def _tasks_of(st: TU.Setup) -> list[list[tuple[str, int]]]:
    """The suite problem's batches (one per successive-halving rung, then the test), each a
    list of (filter, runs) tasks — the order :func:`navlab.tune.tune` sends them in.
    """
    from navlab import tasks as T

    batches: list[list[tuple[str, int]]] = []
    sched = st.schedule
    for j, c in enumerate(sched.configs):
        lo = sched.runs[j - 1] if j else 0
        b = []
        for k, dims in st.dims.items():
            if not dims:
                continue
            for _ in range(c * len(st.train_seeds)):
                b += [(k, hi - lo2) for lo2, hi in T.blocks(lo, sched.runs[j])]
        batches.append(b)
    test = []
    for k in st.spec.filters:
        variants = 2 if st.dims.get(k) else 1  # nothing to tune: the tuned variant is the same task
        for _ in range(variants * len(st.test_seeds)):
            test += [(k, hi - lo) for lo, hi in T.blocks(0, st.test_runs)]
    batches.append(test)
    return batches


def task_model(
    spec: ExperimentSpec, keys: Sequence[str], probe_runs: int = 8
) -> dict[str, tuple[float, float]]:
    """Per filter (a, b): a task of r runs of ``spec`` takes a + b·r seconds in this process,
    from two timed tasks (1 and ``probe_runs`` runs) after a warm-up (compiled kernels).
    """
    from navlab import tasks as T

    out = {}
    for k in keys:
        one = T.one_filter(spec.replace(filters=tuple(keys)), k)
        T.run_task(T.Task(one.replace(runs=1), 0))  # warm-up: imports, compiled kernels
        t1 = T.run_task(T.Task(one.replace(runs=1), 0, keep_epochs=False)).elapsed_s
        tn = T.run_task(T.Task(one.replace(runs=probe_runs), 0, keep_epochs=False)).elapsed_s
        b = max(0.0, (tn - t1) / (probe_runs - 1))
        out[k] = (max(0.0, t1 - b), b)
    return out


def estimate(
    suite: Suite,
    filters: Sequence[str] | None = None,
    workers: Sequence[int] = (1, 2, 8, 64),
    probe_runs: int = 8,
    on_scenario: Callable[[str], None] | None = None,
) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The suite's cost on paper: tasks, CPU-hours, and the wall time on ``workers`` workers.

    Each task's time is the per-filter model of :func:`task_model` (measured once per scenario);
    the wall time on W workers is Σ over the batches (problems, then rungs, run one after the
    other as the bench sends them) of max(batch CPU time / W, its longest task) — dispatch and
    transfer left out, so a lower bound for a busy cluster.
    """
    sts = setups(suite, filters)
    models: dict[str, dict[str, tuple[float, float]]] = {}
    rows = []
    wall = dict.fromkeys(workers, 0.0)
    n_tasks = 0
    cpu = 0.0
    for p, st in zip(suite.problems, sts, strict=True):
        sc = p.spec.scenario
        if sc not in models:
            if on_scenario is not None:
                on_scenario(sc)
            models[sc] = task_model(st.spec, st.spec.filters, probe_runs)
        m = models[sc]
        p_cpu, p_tasks = 0.0, 0
        for batch in _tasks_of(st):
            secs = [m[k][0] + m[k][1] * r for k, r in batch]
            if not secs:
                continue
            p_cpu += sum(secs)
            p_tasks += len(secs)
            for w in workers:
                wall[w] += max(sum(secs) / w, max(secs))
        rows.append(dict(problem=p.name, filters=len(st.spec.filters), tasks=p_tasks, cpu_s=p_cpu))
        n_tasks += p_tasks
        cpu += p_cpu
    return pd.DataFrame(rows), {
        "tasks": n_tasks,
        "cpu_hours": cpu / 3600,
        "wall_s": {int(w): v for w, v in wall.items()},
        "models": models,
    }

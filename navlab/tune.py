"""Fair tuning: every filter tuned on the same budget on training seeds, judged on test seeds.

The rules are those of the statistics spec (STATISTICS.md §6):

* **Split seeds.** Candidates are scored on TRAINING seeds only; every reported number comes from
  disjoint TEST seeds. On a real recording (one truth) the analysis window is split too: tuned
  on its first half, reported on its second half (:data:`REAL_SPLIT`), and the report says so.
* **Equal budget.** Every filter with a tunable parameter gets the same design size ``budget``
  and the same successive-halving schedule (the same number of objective evaluations on the
  same runs); a filter with fewer parameters is not penalised.
* **Declared ranges.** A filter's tunable hyper-parameters and their search ranges are declared
  where the filter declares its parameters (``param(..., tune=(lo, hi))``); ``--range`` narrows,
  widens (inside the admissible range) or adds one. The search is on a log scale where a range
  spans a decade or more — of the value, or of 1 − value for forgetting factors near 1.
* **Method.** A scrambled Sobol design (``scipy.stats.qmc.Sobol``, seeded from ``seed`` and the
  filter's key: deterministic, and independent of which other filters are tuned) of
  ``budget − 1`` points plus the filter's default, then successive halving: all candidates on
  the first rung's runs, the better half on twice as many, … until two remain on the full
  training runs; the best of those is the tuned value. Each rung adds runs to the previous
  rung's (run r always draws from its own seed), so only the new runs are computed. Where
  halving dropped the default early, it is scored on the full training runs as well (after the
  choice, which it does not enter), so that the report's "default → tuned" compares the same runs.
* **Objective.** A metric to minimise (default ``rmse_pos``; the scenario's headline error) or
  its consistency-aware variant ``consistent_<metric>`` = metric × max(1, ANEES / hi, lo / ANEES)
  with [lo, hi] the χ² 95 % band of the ANEES over the runs (ANIS where there is no truth): a
  filter tuned for RMSE alone can become badly overconfident. A candidate that diverges in more
  than 5 % of the runs scores +∞; one whose parameters are invalid together scores +∞ too.
* **Report.** Default and tuned variants of every filter run as separate experiments on the SAME
  test seeds and runs: the measurements are identical (they do not depend on the filters), so
  their per-run statistics pair run by run and one
  :class:`~navlab.experiment.SummaryResults` holds both variants of every filter — the paired
  test of the trust core (``<metric>_diff``, tuned − default, ``vs = "default"``, Holm across the
  filters) and the comparison of the tuned filters against each other come from the existing
  :mod:`navlab.metrics` machinery unchanged. Each tuned value says whether it lies at the end of
  its search range (then the range, not the filter, limited it).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from navlab import metrics as M
from navlab import stats as S
from navlab import tasks as T
from navlab.errors import NavlabError
from navlab.experiment import MAX_RUNS, ExperimentSpec, filter_group, plan
from navlab.filters import is_oracle, registry
from navlab.params import describe
from navlab.scenarios import scenario_registry
from navlab.stats import holm_bounds
from navlab.tables import best_filter, comparison_metrics

REAL_SPLIT = ((0.0, 0.5), (0.5, 1.0))  # real recordings: tune on the first half, report on the second
BOUNDARY = 0.05  # a tuned value this close to an end of its range (search scale) is "on the boundary"
MIN_RUNG_RUNS = 2  # the first rung scores every candidate on at least this many runs per seed
DEFAULT_BUDGET = 16
MAX_BUDGET = 4096  # candidates per filter (a Sobol design of 2¹²)
DEFAULT_TRAIN_RUNS = 32
TEST_SUFFIX = "@tuned"


# --------------------------------------------------------------------------- search space


@dataclass(frozen=True)
class Dim:
    """One tunable parameter: its search range and scale."""

    filter: str
    name: str
    lo: float
    hi: float
    scale: str  # "linear", "log", or "log1m" (log of 1 − value)
    integer: bool
    default: float

    @property
    def cli(self) -> str:
        return f"{self.filter}.{self.name}"

    def value(self, u: float) -> float:
        """The parameter value at unit coordinate u ∈ [0, 1]."""
        if self.scale == "log":
            v = math.exp(math.log(self.lo) + u * (math.log(self.hi) - math.log(self.lo)))
        elif self.scale == "log1m":
            a, b = math.log(1 - self.lo), math.log(1 - self.hi)
            v = 1 - math.exp(a + u * (b - a))
        else:
            v = self.lo + u * (self.hi - self.lo)
        v = min(max(v, self.lo), self.hi)
        return float(round(v)) if self.integer else float(v)

    def unit(self, v: float) -> float:
        """The unit coordinate of value v (outside [0, 1] when v is outside the range)."""
        if self.scale == "log":
            return (math.log(v) - math.log(self.lo)) / (math.log(self.hi) - math.log(self.lo))
        if self.scale == "log1m":
            a, b = math.log(1 - self.lo), math.log(1 - self.hi)
            return (math.log(1 - v) - a) / (b - a) if v < 1 else float("inf")
        return (v - self.lo) / (self.hi - self.lo)


def scale_of(lo: float, hi: float) -> str:
    """Log where the range spans a decade or more (of the value, or of 1 − value below 1)."""
    if lo > 0 and hi / lo >= 10:
        return "log"
    if 0 <= lo < hi < 1 and (1 - lo) / (1 - hi) >= 10:
        return "log1m"
    return "linear"


def parse_range(text: str) -> tuple[str, float, float]:
    """``FILTER.NAME=LO:HI`` → (``FILTER.NAME``, lo, hi)."""
    try:
        name, rng = text.split("=", 1)
        lo_s, hi_s = rng.split(":", 1)
        lo, hi = float(lo_s), float(hi_s)
    except ValueError:
        raise NavlabError(
            f"--range takes FILTER.NAME=LO:HI (e.g. huber-kf.gamma=0.5:10), got {text!r}"
        ) from None
    if "." not in name or not (math.isfinite(lo) and math.isfinite(hi)) or not lo < hi:
        raise NavlabError(f"--range {text!r}: give FILTER.NAME=LO:HI with LO < HI, finite")
    return name.strip(), lo, hi


def space(spec: ExperimentSpec, key: str, ranges: dict[str, tuple[float, float]] | None = None) -> list[Dim]:
    """The tunable parameters of filter ``key`` in ``spec`` (declared ``tune`` ranges, overridden
    or added by ``ranges`` {"FILTER.NAME": (lo, hi)}); defaults are the spec's values.
    """
    cls = registry()[key]
    base = filter_group(spec, key).settings()
    ranges = {k: v for k, v in (ranges or {}).items() if k.split(".", 1)[0] == key}
    known = {p["name"]: p for p in describe(cls.Params)}
    for name in ranges:
        pname = name.split(".", 1)[1]
        p = known.get(pname)
        if p is None or isinstance(p["default"], bool) or not isinstance(p["default"], (int, float)):
            numeric = [
                n
                for n, q in known.items()
                if isinstance(q["default"], (int, float)) and not isinstance(q["default"], bool)
            ]
            raise NavlabError(
                f"--range {name}: '{key}' has no numeric parameter '{pname}'; its numeric "
                f"parameters: {', '.join(numeric) or '(none)'}"
            )
    out = []
    for name, p in known.items():
        rng = ranges.get(f"{key}.{name}", p.get("tune"))
        if rng is None:
            continue
        lo, hi = float(rng[0]), float(rng[1])
        if (p["lo"] is not None and lo < p["lo"]) or (p["hi"] is not None and hi > p["hi"]):
            raise NavlabError(
                f"--range {key}.{name}={lo:g}:{hi:g} leaves the admissible range [{p['lo']}, {p['hi']}]"
            )
        integer = isinstance(p["default"], int)
        d = base.get(name, p["default"])
        out.append(Dim(key, name, lo, hi, scale_of(lo, hi), integer, float(d)))
    return out


def candidates(dims: Sequence[Dim], budget: int, seed: int) -> list[dict[str, float]]:
    """The filter's default, then ``budget − 1`` points of a scrambled Sobol design (seeded from
    ``seed`` and the filter's key), as {parameter: value}.
    """
    if not dims:
        return [{}]
    first = {d.name: d.default for d in dims}
    n = budget - 1
    if n <= 0:
        return [first]
    salt = zlib.crc32(dims[0].filter.encode("utf-8"))
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), salt]))
    from scipy.stats import qmc  # here: scipy.stats slows every process's start

    sob = qmc.Sobol(d=len(dims), scramble=True, seed=rng)
    U = sob.random_base2(max(0, math.ceil(math.log2(n))))[:n]
    out = [first]
    for u in U:
        out.append({d.name: d.value(float(x)) for d, x in zip(dims, u, strict=True)})
    return out


# --------------------------------------------------------------------------- objective


@dataclass(frozen=True)
class Objective:
    """``metric`` to minimise (by its direction), optionally × the consistency penalty."""

    metric: str
    consistent: bool = False

    @property
    def name(self) -> str:
        return f"consistent_{self.metric}" if self.consistent else self.metric

    @property
    def needs_epochs(self) -> bool:
        return self.metric.startswith("mean_rmse_") or self.metric.startswith("h_err")

    def score(self, res: Any, key: str) -> float:
        """The objective of filter ``key`` in summary results ``res`` (lower is better; +∞ for
        a filter diverging in more than 5 % of the runs, or without a value).
        """
        sm = M.summary(res)
        if not sm.judgement.reliable[key]:
            return math.inf
        ests = sm.metrics_of(key)
        if self.metric not in ests:
            raise NavlabError(
                f"--objective {self.name}: no metric '{self.metric}' here; choose one of "
                + ", ".join(m for m in ests if M.direction(m) != 0)
            )
        d = M.direction(self.metric)
        v = d * ests[self.metric][0].point()
        if self.consistent:
            v *= self.penalty(res, key)
        return float(v) if np.isfinite(v) else math.inf

    def penalty(self, res: Any, key: str) -> float:
        """max(1, ε̄ / hi, lo / ε̄) with [lo, hi] the χ² 95 % band of the ANEES (ANIS)."""
        sm = M.summary(res)
        ests = sm.metrics_of(key)
        name = "anees" if "anees" in ests else "anis"
        eps = ests[name][0].point()
        n = int(sm.judgement.judged[key].sum())
        dof = res.data.n if name == "anees" else res.data.m
        lo, hi = M.chi2_band(dof, n)
        if not eps > 0:
            return math.inf
        return float(max(1.0, eps / hi, lo / eps))


def truth_free_objectives(spec: ExperimentSpec) -> list[str]:
    """``["nlpd"]`` when a filter of ``spec`` states its predictive density (``nlpd`` needs no
    truth: the way to tune on a recording of one's own), else ``[]``.
    """
    return ["nlpd"] if any(registry()[k].predictive_density for k in spec.filters) else []


def parse_objective(text: str | None, spec: ExperimentSpec) -> Objective:
    """``rmse_pos`` (default: the scenario's headline RMSE) or ``consistent_rmse_pos``."""
    if not text:
        head = scenario_registry()[spec.scenario].headline
        text = f"rmse_{head[0] if head else 'pos'}"
    consistent = text.startswith("consistent_")
    metric = text[len("consistent_") :] if consistent else text
    if M.direction(metric) == 0:
        raise NavlabError(
            f"--objective {text}: a metric with a direction to optimise (e.g. rmse_pos, "
            "mean_rmse_pos, h_err_median), or consistent_<metric> for the consistency-aware variant"
        )
    return Objective(metric, consistent)


# --------------------------------------------------------------------------- budget


@dataclass(frozen=True)
class Schedule:
    """Successive halving: rung j scores ``configs[j]`` candidates on the first ``runs[j]`` runs
    of every training seed.
    """

    budget: int
    configs: tuple[int, ...]
    runs: tuple[int, ...]

    @staticmethod
    def make(budget: int, train_runs: int) -> Schedule:
        if not 1 <= budget <= MAX_BUDGET:
            raise NavlabError(
                f"--budget must be between 1 (the default alone) and {MAX_BUDGET}, got {budget}"
            )
        if not 1 <= train_runs <= MAX_RUNS:
            raise NavlabError(f"--train-runs must be between 1 and {MAX_RUNS}, got {train_runs}")
        rungs = max(1, math.ceil(math.log2(budget))) if budget > 1 else 1
        rungs = min(rungs, 1 + max(0, math.floor(math.log2(max(1, train_runs // MIN_RUNG_RUNS)))))
        configs, runs = [], []
        n = budget
        for j in range(rungs):
            configs.append(n)
            runs.append(max(1, train_runs >> (rungs - 1 - j)))
            n = max(1, math.ceil(n / 2))
        return Schedule(budget, tuple(configs), tuple(runs))

    @property
    def evaluations(self) -> int:
        """Objective evaluations per filter (every rung's candidates)."""
        return sum(self.configs)

    def text(self) -> str:
        rungs = ", ".join(f"{c} × {r} runs" for c, r in zip(self.configs, self.runs, strict=True))
        return (
            f"budget {self.budget} candidates per filter (the default + {self.budget - 1} Sobol points), "
            f"successive halving: {rungs} ({self.evaluations} objective evaluations per filter; for the "
            f"report the default is also scored on the last rung's {self.runs[-1]} runs, beside the tuned)"
        )


# --------------------------------------------------------------------------- tuning


@dataclass(frozen=True)
class Setup:
    """What a tuning run is: the experiment, the filters' search spaces, seeds, budget, objective."""

    spec: ExperimentSpec
    dims: dict[str, tuple[Dim, ...]]
    objective: Objective
    schedule: Schedule
    train_seeds: tuple[int, ...]
    test_seeds: tuple[int, ...]
    test_runs: int
    split: tuple[T.Window, T.Window]  # analysis-window shares (train, test); None: whole window
    seed: int

    @property
    def real(self) -> bool:
        return self.split[0] is not None

    def describe(self) -> list[str]:
        out = [
            f"Objective: {self.objective.name} (lower is better), scored on "
            f"{_seeds('training', self.train_seeds)}; "
            f"reported on {_seeds('test', self.test_seeds)} × {self.test_runs} runs.",
            "Search: " + self.schedule.text() + "; the same for every filter with a tunable parameter.",
        ]
        if self.real:
            out.append(
                "Real recording (one truth): tuned on the first half of the analysis window, "
                "reported on the second half (the filters run through the whole recording)."
            )
        return out


def default_train_runs(spec: ExperimentSpec) -> int:
    """:data:`DEFAULT_TRAIN_RUNS`, or the scenario's ``default_runs`` when that is smaller (a
    recording whose runs are all alike: more runs add no information).
    """
    return min(DEFAULT_TRAIN_RUNS, scenario_registry()[spec.scenario].default_runs)


def setup(
    spec: ExperimentSpec,
    *,
    budget: int = DEFAULT_BUDGET,
    objective: str | None = None,
    train_seeds: Sequence[int] | None = None,
    test_seeds: Sequence[int] | None = None,
    train_runs: int | None = None,
    ranges: Sequence[str] | dict[str, tuple[float, float]] = (),
) -> Setup:
    """Validate a tuning of ``spec`` (its filters, ``spec.runs`` test runs per test seed).

    ``train_runs`` defaults to :func:`default_train_runs`.

    Test seeds default to ``spec.seed`` (so a default variant's numbers are those of ``navlab
    run`` with the same options), training seeds to ``spec.seed + 1``; they must be disjoint.
    """
    plan(spec)
    test = tuple(int(s) for s in (test_seeds or (spec.seed,)))
    train = tuple(int(s) for s in (train_seeds or (spec.seed + 1,)))
    both = sorted(set(train) & set(test))
    if both:
        raise NavlabError(
            f"training and test seeds must be disjoint; {', '.join(map(str, both))} is in both "
            "(--train-seeds, --test-seeds)"
        )
    if isinstance(ranges, dict):
        rng = dict(ranges)
    else:
        rng = {}
        for text in ranges:
            name, lo, hi = parse_range(text)
            rng[name] = (lo, hi)
    unknown = sorted({k.split(".", 1)[0] for k in rng} - set(spec.filters))
    if unknown:
        raise NavlabError(f"--range names filter(s) not being tuned: {', '.join(unknown)}")
    dims = {k: tuple(space(spec, k, rng)) for k in spec.filters}
    real = not scenario_registry()[spec.scenario].simulated
    if train_runs is None:
        train_runs = default_train_runs(spec)
    return Setup(
        spec=spec,
        dims=dims,
        objective=parse_objective(objective, spec),
        schedule=Schedule.make(int(budget), int(train_runs)),
        train_seeds=train,
        test_seeds=test,
        test_runs=int(spec.runs),
        split=REAL_SPLIT if real else (None, None),
        seed=int(spec.seed),
    )


def variant(spec: ExperimentSpec, key: str, values: dict[str, float], dims: Sequence[Dim]) -> ExperimentSpec:
    """``spec`` reduced to filter ``key`` with parameter ``values`` (whole numbers kept whole)."""
    ints = {d.name for d in dims if d.integer}
    base = {d.name: d.default for d in dims}
    fp = dict(spec.filter_params.get(key, {}))
    # a value equal to the default is left as the spec has it: the same task, the same store key
    fp.update({k: round(v) if k in ints else float(v) for k, v in values.items() if v != base.get(k)})
    one = T.one_filter(spec, key)
    return one.replace(filter_params={key: fp} if fp else {})


@dataclass
class Trial:
    """One objective evaluation: a candidate of a filter on a rung."""

    filter: str
    candidate: int
    rung: int
    runs: int
    values: dict[str, float]
    objective: float
    note: str = ""


@dataclass
class TuneResult:
    """What :func:`tune` found and how the variants did on the test seeds."""

    setup: Setup
    tuned: dict[str, dict[str, float]]  # filter -> tuned values (empty: nothing to tune)
    trials: list[Trial]
    test: Any  # SummaryResults: "<key>" (default) and "<key>@tuned" on the test seeds
    train_objective: dict[str, tuple[float, float]]  # filter -> (default, tuned) on the last rung
    cached: int = 0
    computed: int = 0
    failed: list[str] = field(default_factory=list)  # every candidate diverged: default kept
    rows: pd.DataFrame = field(default_factory=pd.DataFrame)

    def tuned_spec(self, key: str | None = None) -> ExperimentSpec:
        """The experiment with the tuned parameters (of filter ``key`` only, or of every filter),
        on the first test seed — what ``navlab run --config`` reads back.
        """
        st = self.setup
        keys = [key] if key else list(st.spec.filters)
        fp = {k: dict(v) for k, v in st.spec.filter_params.items() if k in keys}
        for k in keys:
            ints = {d.name for d in st.dims[k] if d.integer}
            for n, v in self.tuned.get(k, {}).items():
                fp.setdefault(k, {})[n] = round(v) if n in ints else float(v)
        return st.spec.replace(filters=tuple(keys), filter_params=fp, seed=st.test_seeds[0])


class _Runner:
    """Runs the tasks of one tuning through the store and executor, counting progress."""

    def __init__(self, store, executor, on_progress, should_stop, tick, total: int) -> None:
        self.store, self.executor = store, executor
        self.on_progress, self.should_stop, self.tick = on_progress, should_stop, tick
        self.total, self.done = total, 0
        self.cached = self.computed = 0
        self.results: dict[str, T.TaskResult] = {}

    def run(self, tasks: list[T.Task]) -> dict[str, T.TaskResult]:
        base = self.done
        n_unique = len({t.key for t in tasks})

        def prog(done: int, total: int) -> None:
            if self.on_progress is not None:
                self.on_progress(base + done, self.total)

        got = T.compute(
            tasks,
            store=self.store,
            executor=self.executor,
            on_progress=prog,
            should_stop=self.should_stop,
            tick=self.tick,
        )
        if len(got) < n_unique:
            raise T.StoppedError(
                f"stopped after {self.done + len(got)} of {self.total} tasks; the finished ones are "
                "in the results store: run again to resume"
            )
        self.done += n_unique
        self.results.update(got)
        self.cached += sum(1 for r in got.values() if r.cached)
        self.computed += sum(1 for r in got.values() if not r.cached)
        return got


def _train_tasks(st: Setup, key: str, values: dict[str, float], rung: int) -> list[T.Task]:
    """The new tasks of one candidate on rung ``rung`` (runs [runs[rung − 1], runs[rung]))."""
    lo = st.schedule.runs[rung - 1] if rung else 0
    hi = st.schedule.runs[rung]
    spec = variant(st.spec, key, values, st.dims[key])
    keep = st.objective.needs_epochs
    out = []
    for seed in st.train_seeds:
        s = spec.replace(seed=seed, runs=hi)
        out += T.tasks_for(s, lo, window=st.split[0], keep_epochs=keep)[key]
    return out


def _cand_tasks(st: Setup, key: str, values: dict[str, float], rung: int) -> list[T.Task]:
    """Every task of a candidate up to rung ``rung`` (in seed, run order)."""
    spec = variant(st.spec, key, values, st.dims[key])
    keep = st.objective.needs_epochs
    out = []
    for seed in st.train_seeds:
        s = spec.replace(seed=seed, runs=st.schedule.runs[rung])
        out += _blocks_upto(s, key, st.schedule.runs[: rung + 1], st.split[0], keep)
    return out


def _blocks_upto(spec: ExperimentSpec, key: str, rungs: Sequence[int], window, keep) -> list[T.Task]:
    out, lo = [], 0
    for hi in rungs:
        out += T.tasks_for(spec.replace(runs=hi), lo, window=window, keep_epochs=keep)[key]
        lo = hi
    return out


def _test_tasks(st: Setup, spec1: ExperimentSpec, key: str) -> list[T.Task]:
    out = []
    for seed in st.test_seeds:
        out += T.tasks_for(spec1.replace(seed=seed, runs=st.test_runs), window=st.split[1])[key]
    return out


def _score(st: Setup, key: str, results: list[T.TaskResult]) -> float:
    spec = st.spec.replace(seed=st.train_seeds[0])
    res = T.summary_results(spec, {key: results}, window=st.split[0])
    return st.objective.score(res, key)


def count_tasks(st: Setup) -> int:
    """An upper bound of the tasks a tuning runs (for progress)."""
    n = 0
    for _key, dims in st.dims.items():
        if dims:
            for j, c in enumerate(st.schedule.configs):
                lo = st.schedule.runs[j - 1] if j else 0
                n += c * len(st.train_seeds) * len(T.blocks(lo, st.schedule.runs[j]))
            n += len(st.train_seeds) * len(T.blocks(0, st.schedule.runs[-1]))  # the default's (report)
        n += 2 * len(st.test_seeds) * len(T.blocks(0, st.test_runs))
    return n


def tune(
    st: Setup,
    *,
    store: Any = None,
    executor: Any = None,
    on_progress: Callable[[int, int], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    tick: Callable[[], None] | None = None,
    report: bool = True,
) -> TuneResult:
    """Tune every filter of ``st`` on its training seeds, then evaluate default and tuned
    variants on the test seeds (module note). Raises :class:`navlab.tasks.StoppedError` when stopped
    (the finished tasks are in ``store``). ``report`` off: no :func:`rows` (every metric of every
    variant with its interval; the bench, which judges the tuned variants itself, skips them).
    """
    run = _Runner(store, executor, on_progress, should_stop, tick, count_tasks(st))
    cands = {k: candidates(d, st.schedule.budget, st.seed) for k, d in st.dims.items() if d}
    alive = {k: list(range(len(c))) for k, c in cands.items()}
    trials: list[Trial] = []
    last: dict[str, dict[int, float]] = {}
    for j in range(len(st.schedule.configs)):
        todo = [t for k, idx in alive.items() for i in idx for t in _train_tasks(st, k, cands[k][i], j)]
        run.run(todo)
        for k, idx in alive.items():
            scores = {}
            for i in idx:
                tasks = _cand_tasks(st, k, cands[k][i], j)
                have = [run.results[t.key] for t in tasks]
                note = ""
                try:
                    s = _score(st, k, have)
                except NavlabError as exc:  # parameters invalid together (e.g. k0 above k1)
                    s, note = math.inf, str(exc)
                scores[i] = s
                trials.append(Trial(k, i, j, st.schedule.runs[j], cands[k][i], s, note))
            last[k] = scores
            order = sorted(idx, key=lambda i: (scores[i], i))
            if j + 1 < len(st.schedule.configs):
                alive[k] = order[: st.schedule.configs[j + 1]]
            else:
                alive[k] = order[:1]
    tuned = {k: dict(cands[k][alive[k][0]]) for k in cands}
    # the default (candidate 0) on the last rung's runs as well, wherever halving dropped it
    # earlier: the report's "default → tuned" on the training seeds compares the same runs (not 4
    # against 16); the bench (no report) judges on the test seeds alone and skips it (NaN)
    J = len(st.schedule.configs) - 1
    dropped = [k for k in cands if 0 not in last[k]] if report else []
    tasks = {k: _cand_tasks(st, k, cands[k][0], J) for k in dropped}
    run.run([t for ts in tasks.values() for t in ts if t.key not in run.results])  # runs not scored yet
    for k in dropped:
        try:
            s0, note = _score(st, k, [run.results[t.key] for t in tasks[k]]), ""
        except NavlabError as exc:
            s0, note = math.inf, str(exc)
        trials.append(Trial(k, 0, J, st.schedule.runs[J], cands[k][0], s0, note))
        last[k][0] = s0
    train_obj = {k: (last[k].get(0, math.nan), last[k][alive[k][0]]) for k in cands}
    failed = sorted(k for k, v in train_obj.items() if math.isinf(v[1]))
    for k in failed:  # nothing to choose from: keep the default, and say so
        tuned[k] = dict(cands[k][0])
    # ---- the test seeds: default and tuned variants of every filter, paired run by run
    parts_tasks: dict[str, list[T.Task]] = {}
    for k in st.spec.filters:
        parts_tasks[k] = _test_tasks(st, T.one_filter(st.spec, k), k)
        tv = variant(st.spec, k, tuned.get(k, {}), st.dims[k])
        parts_tasks[k + TEST_SUFFIX] = _test_tasks(st, tv, k)
    got = run.run([t for ts in parts_tasks.values() for t in ts])
    reg = registry()
    labels = {}
    for k in st.spec.filters:
        labels[k] = f"{reg[k].label} (default)"
        labels[k + TEST_SUFFIX] = f"{reg[k].label} (tuned)"
    test_spec = st.spec.replace(seed=st.test_seeds[0])
    test = T.summary_results(
        test_spec, {n: [got[t.key] for t in ts] for n, ts in parts_tasks.items()}, labels, st.split[1]
    )
    out = TuneResult(st, tuned, trials, test, train_obj, run.cached, run.computed, failed)
    if report:
        out.rows = rows(out)
    return out


# --------------------------------------------------------------------------- report


def _seeds(kind: str, seeds: Sequence[int]) -> str:
    """'training seed 2' / 'training seeds 2, 3'."""
    return f"{kind} seed{'s' if len(seeds) > 1 else ''} {', '.join(map(str, seeds))}"


def boundary(d: Dim, v: float) -> str:
    """'lo' / 'hi' when v lies within BOUNDARY of an end of the range (search scale), else ''."""
    u = d.unit(v)
    if u <= BOUNDARY:
        return "lo"
    if u >= 1 - BOUNDARY:
        return "hi"
    return ""


def param_rows(r: TuneResult) -> pd.DataFrame:
    rows = []
    for k, dims in r.setup.dims.items():
        for d in dims:
            v = r.tuned[k][d.name]
            rows.append(
                dict(
                    kind="param",
                    filter=k,
                    name=d.name,
                    default=d.default,
                    tuned=int(v) if d.integer else v,
                    lo=d.lo,
                    hi=d.hi,
                    scale=d.scale,
                    on_boundary=boundary(d, v),
                )
            )
    return pd.DataFrame(rows)


def diff_rows(r: TuneResult, metrics: list[str]) -> pd.DataFrame:
    """Tuned − default per filter (paired over the test runs), Holm across the filters."""
    res = r.test
    sm = M.summary(res)
    jd = sm.judgement
    out = []
    for metric in metrics:
        part, pvals, bounds = [], {}, {}
        for k in r.setup.spec.filters:
            got = sm.paired(k + TEST_SUFFIX, k, metric)
            if got is None:
                continue
            c = got.c
            row = M.diff_row(k, res.runs[k + TEST_SUFFIX].label, metric, got, "default")
            if not r.tuned.get(k):
                row["note"] = "; ".join(
                    x for x in (row["note"], "no tunable parameter: tuned = default") if x
                )
            elif k in r.failed or not changed(r, k):
                why = (
                    "every candidate diverged in training" if k in r.failed else "the default won in training"
                )
                row["note"] = "; ".join(x for x in (row["note"], f"{why}: tuned = default") if x)
            else:
                pvals[k], bounds[k] = c.p_value, c.at_floor
            part.append(row)
        adj, adj_bound = holm_bounds(pvals, bounds)
        for row in part:
            k = row["filter"]
            row["p_holm"] = adj.get(k, np.nan)
            row["p_holm_bound"] = "<" if adj_bound.get(k) else ""
            verdict, extra = M.verdict(metric, row, jd, k + TEST_SUFFIX, k)
            row["verdict"] = verdict if k in pvals else ""
            if extra and k in pvals:
                row["note"] = "; ".join(x for x in (row["note"], extra) if x)
        out += part
    df = pd.DataFrame(out, columns=M.COLUMNS + M.DIFF_COLUMNS)
    df.insert(0, "kind", "diff")
    df.insert(2, "variant", "tuned")
    return df


def contenders(r: TuneResult) -> list[str]:
    """The filters the tuned comparison ranks: all but the oracles (the accuracy floor)."""
    return [k for k in r.setup.spec.filters if not is_oracle(k)]


def tuned_only(r: TuneResult) -> Any:
    """The tuned variants of the :func:`contenders` alone, keyed by filter (for comparing tuned
    filters with each other).
    """
    from dataclasses import replace

    from navlab.experiment import FilterInfo

    res = r.test
    stats = {k: replace(res.stats[k + TEST_SUFFIX], key=k) for k in contenders(r)}
    runs = {k: FilterInfo(k, res.runs[k + TEST_SUFFIX].label) for k in stats}
    return replace(res, stats=stats, runs=runs)


def rows(r: TuneResult) -> pd.DataFrame:
    """Every output row: ``param``, ``objective``, ``metric`` (test seeds, by variant),
    ``diff`` (tuned − default) and ``vs_tuned`` (tuned filters against the best tuned one; the
    oracles, the accuracy floor, are not ranked).
    """
    st = r.setup
    res = r.test
    head = comparison_metrics(res)
    metric_df = M.summarize(res, metrics=head)
    variant_col = np.where(metric_df["filter"].str.endswith(TEST_SUFFIX), "tuned", "default")
    metric_df["filter"] = metric_df["filter"].str.replace(TEST_SUFFIX, "", regex=False)
    metric_df.insert(0, "kind", "metric")
    metric_df.insert(2, "variant", variant_col)
    obj = []
    for k in st.spec.filters:
        d_train, t_train = r.train_objective.get(k, (math.nan, math.nan))
        for variant_name, name in (("default", k), ("tuned", k + TEST_SUFFIX)):
            obj.append(
                dict(
                    kind="objective",
                    filter=k,
                    variant=variant_name,
                    metric=st.objective.name,
                    train=d_train if variant_name == "default" else t_train,
                    value=st.objective.score(res, name),
                )
            )
    diff = diff_rows(r, [m for m in head if M.direction(m) != 0 or m == "anees"])
    metric = st.objective.metric
    vs = pd.DataFrame()
    tres = tuned_only(r)
    if len(tres.stats) > 1 and metric in M.summary(tres).metrics_of(next(iter(tres.stats))):
        best, vs = best_filter(tres, metric)
        vs = vs.copy()
        vs.insert(0, "kind", "vs_tuned")
        vs.insert(2, "variant", "tuned")
        vs["vs"] = vs["vs"].astype(str) + "@tuned"
        vs["best"] = best or ""
    return pd.concat([param_rows(r), pd.DataFrame(obj), metric_df, diff, vs], ignore_index=True)


def influential(r: TuneResult, key: str, top: int = 2) -> list[str]:
    """The filter's one or two most influential parameters: |Spearman ρ| between a parameter's
    search coordinate and the objective over the first rung's candidates (all on the same runs).
    """
    from scipy.stats import spearmanr

    dims = {d.name: d for d in r.setup.dims.get(key, ())}
    t0 = [t for t in r.trials if t.filter == key and t.rung == 0 and np.isfinite(t.objective)]
    if len(dims) <= 1 or len(t0) < 3:
        return list(dims)[:top]
    y = np.array([t.objective for t in t0])
    strength = {}
    for name, d in dims.items():
        x = np.array([d.unit(t.values[name]) for t in t0])
        if np.ptp(x) == 0 or np.ptp(y) == 0:
            strength[name] = 0.0
            continue
        rho = spearmanr(x, y).statistic
        strength[name] = abs(float(rho)) if np.isfinite(rho) else 0.0
    return sorted(dims, key=lambda n: -strength[n])[:top]


def trials_frame(r: TuneResult) -> pd.DataFrame:
    """Every objective evaluation: filter, candidate, rung, runs, objective and the values."""
    rows = []
    for t in r.trials:
        row = dict(filter=t.filter, candidate=t.candidate, rung=t.rung, runs=t.runs, objective=t.objective)
        row.update({f"p.{k}": v for k, v in t.values.items()})
        row["note"] = t.note
        rows.append(row)
    return pd.DataFrame(rows)


def _fmt(d: Dim, v: float) -> str:
    """Three significant figures; of 1 − v for a forgetting factor near 1 (0.9999, not 1.00)."""
    if d.scale == "log1m" and v < 1:
        digits = max(3, 2 - math.floor(math.log10(1 - v)))
        return f"{v:.{digits}f}".rstrip("0")
    return S.sig3(v)


def _values_text(r: TuneResult, key: str) -> str:
    dims = r.setup.dims.get(key, ())
    if not dims:
        return "(nothing to tune)"
    parts = []
    for d in dims:
        v = r.tuned[key][d.name]
        txt = f"{d.name} = {_fmt(d, v)} (default {_fmt(d, d.default)}"
        b = boundary(d, v)
        if b:
            txt += f"; at the {'lower' if b == 'lo' else 'upper'} end of {_fmt(d, d.lo)}–{_fmt(d, d.hi)}"
        parts.append(txt + ")")
    return ", ".join(parts)


def changed(r: TuneResult, key: str) -> bool:
    """Whether tuning moved any parameter of filter ``key`` off its default."""
    dims = r.setup.dims.get(key, ())
    return any(r.tuned[key][d.name] != d.default for d in dims)


def caption(r: TuneResult) -> str:
    """The seeds and runs of a tuning and the interval method of its test table, one sentence."""
    from navlab import tables

    st = r.setup
    return (
        f"objective {st.objective.name} scored on {_seeds('training', st.train_seeds)}, "
        f"reported on {_seeds('test', st.test_seeds)} x {st.test_runs} runs "
        f"({r.test.data.B} Monte Carlo runs). " + tables.interval_note(r.test.data.B)
    )


def paper_table(r: TuneResult, fmt: str) -> str:
    """:func:`report` as Markdown or a LaTeX booktabs table (``navlab tune --format``, the Tune
    page's download) with a caption naming the seeds, runs and interval method.
    """
    from navlab import tables

    cap = (
        f"Default and tuned filters on {r.setup.spec.scenario}, {caption(r)} No bold: the best tuned "
        "filter, where the paired test backs one, is named in the last column and the notes."
    )
    return tables.render(report(r), fmt, cap, label="tab:navlab-tune")


def report(r: TuneResult) -> Any:
    """The fair-tuning table (:class:`navlab.tables.Table`): per filter the tuned values, the
    objective on the training seeds, the metric on the test seeds for default and tuned with
    their intervals, the paired tuned − default verdict and the tuned filters against the best.
    """
    from navlab import tables

    st, res = r.setup, r.test
    metric = st.objective.metric
    sm = M.summary(res)
    name = tables.metric_name(metric, res.data)
    df = r.rows
    diff = df[(df.kind == "diff") & (df.metric == f"{metric}_diff")].set_index("filter")
    vs = df[df.kind == "vs_tuned"].set_index("filter") if "vs_tuned" in set(df.kind) else pd.DataFrame()
    best = str(vs["best"].iloc[0]) if len(vs) else ""
    best_label = res.runs[best + TEST_SUFFIX].label if best else ""
    cand = str(vs["vs"].iloc[0]).replace(TEST_SUFFIX, "") if len(vs) else ""
    rows = []
    for k in st.spec.filters:
        d_tr, t_tr = r.train_objective.get(k, (math.nan, math.nan))
        row = {"filter": registry()[k].label, "tuned parameters": _values_text(r, k)}
        show = lambda v: S.sig3(v) if math.isfinite(v) else "diverged"  # noqa: E731
        row[f"train {st.objective.name}: default → tuned"] = (
            f"{show(d_tr)} → {show(t_tr)}" if r.tuned.get(k) else ""
        )
        for variant_name, n in (("default", k), ("tuned", k + TEST_SUFFIX)):
            e = sm.estimate(n, metric) if metric in sm.metrics_of(n) else None
            row[f"test {name}, {variant_name}"] = tables.cell(e.value, e.lo, e.hi) if e else ""
        if k in r.failed:
            row["tuned − default (paired, test)"] = "tuned = default (every candidate diverged in training)"
        elif k in diff.index and changed(r, k):
            row["tuned − default (paired, test)"] = tables.verdict_cell(diff.loc[k], "default")
        elif r.tuned.get(k):
            row["tuned − default (paired, test)"] = "tuned = default (the default won on the training seeds)"
        else:
            row["tuned − default (paired, test)"] = "tuned = default"
        if len(vs):
            if is_oracle(k):
                row["tuned, against the best tuned"] = "(the accuracy floor: not ranked)"
            elif k == cand:
                row["tuned, against the best tuned"] = "best" if best else "lowest (not significantly)"
            elif k in vs.index:
                row["tuned, against the best tuned"] = tables.verdict_cell(
                    vs.loc[k], res.runs[cand + TEST_SUFFIX].label
                )
            else:
                row["tuned, against the best tuned"] = "no test (no run to judge)"
        rows.append(row)
    cells = pd.DataFrame(rows).set_index("filter")
    notes = st.describe()
    tuned_n = sum(1 for k in st.spec.filters if r.tuned.get(k))
    notes.append(
        f"tuned − default: Δ over the same test runs with its 95 % interval; better/worse when "
        f"Holm-corrected p < 0.05 across the {tuned_n} tuned filters."
    )
    if len(vs):
        notes.append(
            f"Best tuned filter on {name}: {best_label}"
            if best
            else f"No tuned filter is better than every other on {name} after Holm's correction "
            f"(lowest: {res.runs[cand + TEST_SUFFIX].label})."
        )
    edge = [f"{d.cli}" for k, dims in st.dims.items() for d in dims if boundary(d, r.tuned[k][d.name])]
    if edge:
        notes.append(
            "At an end of its search range (the range, not the filter, may limit it; widen it with "
            "--range FILTER.NAME=LO:HI): " + ", ".join(edge) + "."
        )
    if r.failed:
        names = ", ".join(registry()[k].label for k in r.failed)
        notes.append(
            f"{names}: every candidate diverged in more than 5 % of the training runs (or was "
            "invalid), so the default is kept; the search range may not hold a working value."
        )
    notes.append(f"Tasks: {r.computed} computed, {r.cached} from the results store.")
    notes += tables.footnotes(res, sm)
    return tables.Table(cells, notes)

"""Independent Monte Carlo tasks: one filter's configuration × a block of runs → per-run statistics.

Sweeps and tunings are many experiments; each experiment is split into :class:`Task` s (one per
filter and block of runs) that run anywhere — in this process, on an embedded Dask cluster or on
a remote one (:mod:`navlab.cluster`) — and are kept in the results store (:mod:`navlab.store`).

Why the numbers never depend on how the work is split:

* run r draws from its own seed (``SeedSequence([seed, r])``), whatever block it is simulated in,
  and the simulated runs do not depend on the filters in the experiment, so a filter run alone
  sees exactly the measurements it sees beside the others;
* every metric is a function of per-run statistics (:class:`navlab.metrics.RunStats`), so a task
  returns those and the parent concatenates the blocks of every filter and judges them together
  (:func:`summary_results`: the same :class:`~navlab.experiment.SummaryResults` a summary run
  gives, so :func:`navlab.metrics.summarize`, the paired comparisons and the tables work on it).

A task's per-run sums stay float64 (the metrics equal ``navlab run``'s); its per-epoch squared
errors and quantile samples (for the mean of the per-epoch RMSE and quantile metrics) are kept as
float32, or dropped when ``keep_epochs`` is off.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from navlab import __version__, memory
from navlab.errors import NavlabError
from navlab.experiment import (
    MAX_SUMMARY_RUNS,
    DataInfo,
    ExperimentSpec,
    FilterInfo,
    SummaryResults,
    fixed_chunks,
    iter_chunks,
    plan,
    run_size,
)
from navlab.metrics import RunStats, run_stats
from navlab.store import Store, key_of

BLOCK = 100  # runs per task by default (aligned blocks: [0, 100), [100, 200), …)

Window = tuple[float, float] | None  # a share (from, to) of the analysis window's epochs


@dataclass(frozen=True)
class Task:
    """Filter ``spec.filters[0]`` of ``spec`` over runs [``start``, ``spec.runs``).

    ``window`` restricts the analysis window to a share of its epochs (tuning on real recordings:
    one segment to tune on, another to report on); ``keep_epochs`` keeps the per-epoch squared
    errors (mean of the per-epoch RMSE, quantile metrics).
    """

    spec: ExperimentSpec
    start: int
    window: Window = None
    keep_epochs: bool = True

    @property
    def stop(self) -> int:
        return int(self.spec.runs)

    @property
    def filter(self) -> str:
        return self.spec.filters[0]

    def config(self) -> dict[str, Any]:
        """Everything that decides the task's numbers (its store key hashes this + the version)."""
        d = self.spec.to_dict()
        d.pop("runs")
        return {
            "experiment": d,
            "runs": [self.start, self.stop],
            "window": None if self.window is None else list(self.window),
            "keep_epochs": self.keep_epochs,
        }

    @functools.cached_property
    def key(self) -> str:
        return key_of(self.config())

    def probe(self) -> Task:
        """One run of this task: warms a new worker up (imports, the filter's compiled kernels)."""
        return Task(self.spec.replace(runs=self.start + 1), self.start, self.window, self.keep_epochs)


@dataclass(eq=False)
class TaskResult:
    """A task's per-run statistics (one row per run of its block) and how it was made."""

    stats: RunStats
    any_outliers: bool
    elapsed_s: float
    version: str = __version__
    cached: bool = False  # read from the store


def one_filter(spec: ExperimentSpec, key: str) -> ExperimentSpec:
    """``spec`` reduced to filter ``key`` (its parameters only)."""
    fp = {key: spec.filter_params[key]} if key in spec.filter_params else {}
    return spec.replace(filters=(key,), filter_params=fp)


def blocks(start: int, stop: int, size: int = BLOCK) -> list[tuple[int, int]]:
    """Runs [start, stop) as blocks aligned to multiples of ``size``."""
    out, lo = [], int(start)
    while lo < stop:
        hi = min(int(stop), (lo // size + 1) * size)
        out.append((lo, hi))
        lo = hi
    return out


def tasks_for(
    spec: ExperimentSpec,
    start: int = 0,
    *,
    window: Window = None,
    keep_epochs: bool = True,
    block: int = BLOCK,
) -> dict[str, list[Task]]:
    """The tasks of runs [start, spec.runs) of ``spec``: {filter key: its tasks, block by block}."""
    out: dict[str, list[Task]] = {}
    for key in spec.filters:
        one = one_filter(spec, key)
        out[key] = [
            Task(one.replace(runs=hi), lo, window, keep_epochs) for lo, hi in blocks(start, spec.runs, block)
        ]
    return out


def _windowed(window: Any, share: Window) -> np.ndarray:
    W = np.asarray(window, dtype=bool)
    if share is None:
        return W
    a, b = share
    idx = np.flatnonzero(W)
    keep = idx[round(a * idx.size) : round(b * idx.size)]
    out = np.zeros_like(W)
    out[keep] = True
    return out


def run_task(task: Task) -> TaskResult:
    """Simulate the task's runs, run its filter over them, reduce to per-run statistics."""
    t0 = time.perf_counter()
    p = plan(task.spec, max_runs=MAX_SUMMARY_RUNS)
    ch = next(iter_chunks(p, fixed_chunks(task.stop - task.start), task.start))
    data = ch.data
    if task.window is not None:
        data = dataclasses.replace(data, window=_windowed(data.window, task.window))
    st = run_stats(data, ch.runs[task.filter])
    f32 = lambda d: {k: np.asarray(v, dtype=np.float32) for k, v in d.items()}  # noqa: E731
    st = dataclasses.replace(
        st, sq=f32(st.sq) if task.keep_epochs else {}, samples=f32(st.samples) if task.keep_epochs else {}
    )
    return TaskResult(st, bool(data.outlier_mask.any()), time.perf_counter() - t0)


# --------------------------------------------------------------------------- store format


def encode(r: TaskResult) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """A task result as (JSON header, arrays) for :class:`navlab.store.Store`."""
    st = r.stats
    head = {
        "filter": st.key,
        "label": st.label,
        "runtime_s": st.runtime_s,
        "epochs": st.epochs,
        "estimates_R": st.estimates_R,
        "any_outliers": r.any_outliers,
        "elapsed_s": r.elapsed_s,
        "version": r.version,
    }
    arrays = {"diverged": np.asarray(st.diverged, dtype=bool)}
    for part in ("sse", "sq", "sums", "samples"):
        for name, v in getattr(st, part).items():
            arrays[f"{part}/{name}"] = np.asarray(v)
    return head, arrays


def decode(head: dict[str, Any], arrays: dict[str, np.ndarray]) -> TaskResult:
    parts: dict[str, dict[str, np.ndarray]] = {"sse": {}, "sq": {}, "sums": {}, "samples": {}}
    for name, v in arrays.items():
        if "/" in name:
            part, sub = name.split("/", 1)
            parts[part][sub] = v
    st = RunStats(
        key=head["filter"],
        label=head["label"],
        diverged=np.asarray(arrays["diverged"], dtype=bool),
        runtime_s=float(head["runtime_s"]),
        epochs=int(head["epochs"]),
        estimates_R=bool(head["estimates_R"]),
        **parts,
    )
    return TaskResult(st, bool(head["any_outliers"]), float(head["elapsed_s"]), head["version"], True)


def stored_result(task: Task, head: dict[str, Any], arrays: dict[str, np.ndarray]) -> TaskResult | None:
    """The stored result of ``task``, or None when the entry does not fit it (a header without
    its fields, arrays of another length than the task's runs or epochs).
    """
    try:
        res = decode(head, arrays)
    except (KeyError, ValueError, TypeError):
        return None
    st, runs = res.stats, task.stop - task.start
    per_epoch = [*st.sq.values(), *st.samples.values()]
    ok = (
        st.diverged.shape == (runs,)
        and all(v.ndim >= 1 and v.shape[0] == runs for d in (st.sse, st.sums) for v in d.values())
        and all(v.ndim == 2 and v.shape == (runs, st.epochs) for v in per_epoch)
    )
    return res if ok else None


# --------------------------------------------------------------------------- running tasks


class StoppedError(NavlabError):
    """Raised by :func:`compute` (``strict``) when stopped before every task finished."""


Progress = Callable[[int, int], None]  # (tasks done, tasks in all)


def check_memory(tasks: Iterable[Task]) -> None:
    """Refuse (NavlabError) a task that would not fit the memory budget, before any work."""
    seen: set[str] = set()
    for t in tasks:
        d = t.spec.to_dict()
        d["runs"] = t.stop - t.start
        ck = json.dumps(d, sort_keys=True)
        if ck in seen:
            continue
        seen.add(ck)
        size = run_size(plan(t.spec.replace(runs=max(1, t.stop - t.start))))
        memory.check(size, size.full())


def compute(
    tasks: Sequence[Task],
    *,
    store: Store | None = None,
    executor: Any = None,
    on_progress: Progress | None = None,
    should_stop: Callable[[], bool] | None = None,
    tick: Callable[[], None] | None = None,
    task_fn: Callable[[Task], TaskResult] | None = None,
) -> dict[str, TaskResult]:
    """Results of ``tasks`` by task key: from the store, the rest computed by ``executor``
    (default: in this process) and stored as each finishes.

    ``on_progress(done, total)`` after each task; ``should_stop()`` is asked between tasks (and
    ``tick()`` called while waiting on a cluster): when it says stop, the remaining tasks are
    cancelled and the finished ones returned (they are in the store: nothing finished is lost).
    ``task_fn`` replaces :func:`run_task` (tests).
    """
    from navlab.cluster import SerialExecutor

    unique = {t.key: t for t in tasks}
    out: dict[str, TaskResult] = {}
    if store is not None:
        for k, task in unique.items():
            hit = store.get(k)
            if hit is not None:
                res = stored_result(task, *hit)
                if res is None:
                    store.discard(k)  # damaged: recomputed below
                else:
                    out[k] = res
    todo = [t for k, t in unique.items() if k not in out]
    total = len(unique)
    if on_progress is not None:
        on_progress(len(out), total)
    if not todo:
        return out
    check_memory(todo)

    def keep(task: Task, res: TaskResult) -> None:
        if res.version != __version__:
            raise NavlabError(
                f"a Dask worker runs navlab {res.version}, this process {__version__}: install the "
                "same navlab on every worker"
            )
        out[task.key] = res
        if store is not None:
            store.put(task.key, *encode(res))

    def done(task: Task, res: TaskResult) -> None:
        keep(task, res)
        if on_progress is not None:
            on_progress(len(out), total)

    ex = executor if executor is not None else SerialExecutor()
    ex.run(task_fn or run_task, todo, done, keep, should_stop=should_stop, tick=tick)
    return out


def concat(results: Sequence[TaskResult]) -> RunStats:
    """One filter's per-run statistics from its blocks (in run order)."""
    return RunStats.concat([r.stats for r in results])


@functools.lru_cache(maxsize=128)
def _probe(spec_json: str, window: Window) -> DataInfo:
    """What the metrics need of an experiment's data (one simulated run; cached)."""
    spec = ExperimentSpec.from_json(spec_json)
    p = plan(spec.replace(runs=1))
    d = p.scenario.simulate(p.schedule, p.outliers, [0], spec.seed)
    return DataInfo(
        scenario=d.scenario,
        t=d.t,
        model=d.model,
        groups=d.groups,
        window=_windowed(d.window, window),
        has_truth=d.has_truth,
        extras={k: v for k, v in d.extras.items() if k in ("metrics", "notes", "findings")},
        divergence_bound=d.divergence_bound,
        B=0,
        K=d.K,
        n=int(d.x0.shape[1]),
        m=int(d.z.shape[2]),
        any_outliers=False,
    )


def data_info(spec: ExperimentSpec, runs: int, any_outliers: bool, window: Window = None) -> DataInfo:
    """The :class:`DataInfo` of ``spec`` over ``runs`` runs (filters do not change it)."""
    base = spec.replace(filters=spec.filters[:1], filter_params={}, runs=1)
    info = _probe(base.to_json(), window)
    return dataclasses.replace(info, B=int(runs), any_outliers=bool(any_outliers))


def summary_results(
    spec: ExperimentSpec,
    parts: dict[str, Sequence[TaskResult]],
    labels: dict[str, str] | None = None,
    window: Window = None,
) -> SummaryResults:
    """The experiment ``spec`` as :class:`SummaryResults` from its filters' task results.

    ``parts`` maps a name (a filter key, or a variant such as ``huber-kf@tuned``) to its results
    in run order; every name must cover the same runs (the pairing of every comparison).
    ``labels`` renames them for display.
    """
    stats = {}
    n_runs = None
    outliers = False
    elapsed = 0.0
    for name, rs in parts.items():
        st = dataclasses.replace(concat(rs), key=name)
        if labels and name in labels:
            st = dataclasses.replace(st, label=labels[name])
        n = int(st.diverged.shape[0])
        if n_runs is not None and n != n_runs:
            raise ValueError(f"'{name}' covers {n} runs, the others {n_runs}: not paired")
        n_runs = n
        stats[name] = st
        outliers = outliers or any(r.any_outliers for r in rs)
        elapsed += sum(r.elapsed_s for r in rs)
    info = data_info(spec, n_runs or 0, outliers, window)
    runs = {k: FilterInfo(k, st.label) for k, st in stats.items()}
    return SummaryResults(spec.replace(runs=max(1, n_runs or 1)), info, stats, runs, elapsed)

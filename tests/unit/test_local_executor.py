"""Where the default executor runs a job: in this process while the estimated work is below what
starting the embedded cluster costs, starting the cluster in the background (never waiting for
it) when the work is long, and on a warm cluster when one is up and the work pays for it.

No cluster and no clock: the tasks report their own cost (``elapsed_s``, as a TaskResult does)
and the embedded cluster is a stand-in that records what it is asked.
"""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import pytest

from navlab import cluster as C

_IDS = itertools.count()


class Task(SimpleNamespace):
    def probe(self) -> Task:
        return Task(key=f"{self.key}-probe", filter=self.filter, cost=0.0)


def _tasks(n: int, cost: float, filters=("a", "b")) -> list[Task]:
    run = next(_IDS)  # filter names never seen before: their first task counts as warm-up
    return [Task(key=f"t{run}-{i}", filter=f"{filters[i % len(filters)]}{run}", cost=cost) for i in range(n)]


def _fn(task: Task) -> SimpleNamespace:
    return SimpleNamespace(elapsed_s=task.cost, key=task.key)


class Stand:
    """The embedded cluster's interface: never ready, records the starts."""

    error = None

    def __init__(self) -> None:
        self.starts: list[tuple[int, list]] = []

    def start_cost(self) -> float:
        return 10.0

    def ready(self, n: int):
        return None

    def start(self, n, fn=None, probes=()) -> bool:
        """Like the real one: True only for the call that starts it."""
        self.starts.append((n, [p.filter for p in probes]))
        return len(self.starts) == 1


def _run(ex: C.LocalExecutor, tasks) -> list[str]:
    got: list[str] = []
    ex.run(_fn, tasks, lambda t, r: got.append(r.key), lambda t, r: None)
    return got


def test_a_short_job_runs_in_this_process_and_starts_no_cluster():
    stand = Stand()
    ex = C.LocalExecutor(2, embedded=stand)
    tasks = _tasks(36, 0.05)  # 1.8 s of work, far below 2 × 10 s
    assert _run(ex, tasks) == [t.key for t in tasks]
    assert stand.starts == []
    assert ex.here == 36 and ex.there == 0
    assert ex.report.startswith("36 tasks in this process in 1.8 s")
    assert "below what starting the embedded Dask cluster costs" in ex.report


def test_a_long_job_starts_the_cluster_in_the_background_and_never_waits_for_it():
    stand = Stand()
    ex = C.LocalExecutor(2, embedded=stand)
    tasks = _tasks(40, 1.0)  # 40 s of work: above 2 × 10 s
    seen: list[str] = []
    ex.run(_fn, tasks, lambda t, r: seen.append(ex.now), lambda t, r: None)
    assert len(seen) == 40  # every task ran here: the cluster never came up
    assert seen[2] == "in this process" and "starts in the background" in seen[3]
    # decided after the first warm task (the first of each filter loads its kernels), with a
    # small task of each filter to warm the workers up
    n, probes = stand.starts[0]
    assert n == 2 and probes == [tasks[3].filter, tasks[4].filter]
    assert "not ready before they finished" in ex.report


def test_the_first_task_of_each_filter_is_not_taken_as_the_cost():
    stand = Stand()
    tasks = _tasks(20, 0.05, filters=("a", "b", "c"))
    for t in tasks[:3]:
        t.cost = 5.0  # loading three filters' kernels: 19 × 5 s would look like 95 s of work
    _run(C.LocalExecutor(2, embedded=stand), tasks)
    assert stand.starts == []


def test_one_core_or_one_task_never_starts_a_cluster():
    stand = Stand()
    _run(C.LocalExecutor(1, embedded=stand), _tasks(40, 1.0))
    _run(C.LocalExecutor(2, embedded=stand), _tasks(1, 100.0))
    assert stand.starts == []


class Warm(Stand):
    """A cluster that is up: the job goes to ``executor`` once the work pays."""

    def __init__(self) -> None:
        super().__init__()
        self.client = object()

    def ready(self, n: int):
        return self.client


def test_a_warm_cluster_takes_the_rest_of_a_job_only_when_it_pays(monkeypatch):
    sent: list[list[str]] = []

    def fake_run(self, fn, tasks, done, keep, **kw):
        sent.append([t.key for t in tasks])
        for t in tasks:
            done(t, fn(t))

    monkeypatch.setattr(C.DaskExecutor, "__init__", lambda self, client, name, fix=None: None)
    monkeypatch.setattr(C.DaskExecutor, "run", fake_run)
    warm = Warm()
    short = _tasks(10, 0.05)  # 0.5 s: below PAYS_S
    ex = C.LocalExecutor(2, embedded=warm)
    _run(ex, short)
    assert sent == [] and "too little work" in ex.report
    long = _tasks(30, 1.0)
    ex = C.LocalExecutor(2, embedded=warm)
    assert sorted(_run(ex, long)) == sorted(t.key for t in long)
    # the first two tasks (one per filter: kernels) and one warm task here, the rest there
    assert sent == [[t.key for t in long[3:]]]
    assert ex.here == 3 and ex.there == 27 and warm.starts == []
    assert ex.report.startswith("27 tasks on the embedded Dask cluster (2 workers) and 3 tasks in this")


@pytest.mark.parametrize("text", ["0", "-1", "nan", "inf", "soon"])
def test_the_no_worker_limit_must_be_a_positive_number(monkeypatch, text):
    monkeypatch.setenv(C.NO_WORKERS_ENV, text)
    with pytest.raises(C.NavlabError, match=C.NO_WORKERS_ENV):
        C.no_workers_s()

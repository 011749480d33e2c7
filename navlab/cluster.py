"""Where tasks run: in this process, on an embedded Dask cluster, or on an existing one.

Sweeps and tunings hand their :class:`navlab.tasks.Task` s to an executor:

* ``local`` (the default): this machine (:class:`LocalExecutor`). The tasks run in this process
  while the work is short: a cluster pays only when it is long. The estimate comes from the
  tasks already run (the first task of each filter in a process is left out: it loads the
  filter's compiled kernels). When the estimated work left exceeds :data:`START_FACTOR` × the
  cluster's start-up cost (:data:`START_S`, measured with ``benchmarks/sweep_dask.py``), an
  embedded ``distributed.LocalCluster`` — one worker process per core, one thread each, no
  dashboard, 127.0.0.1 only — starts in the background while this process goes on computing;
  once its workers are up and warm, the tasks not yet started move to it. It then stays up for
  every later job of the process (one per process, closed when the process exits), and takes a
  job whose estimated work exceeds :data:`PAYS_S`. A job never waits for a cluster to start.
* ``tcp://HOST:8786`` (``--scheduler``, or ``NAVLAB_DASK_SCHEDULER`` for the app and the CLI): an
  existing cluster (``dask scheduler`` and ``dask worker tcp://HOST:8786`` on the machines; every
  worker needs the same navlab installed and, for real recordings, the data at the same path);
* ``serial``: this process, no Dask (tests, debugging).

Every executor says where the last job ran and why (``report``). Tasks are submitted under their
store key, so two sessions on one cluster asking for the same task share one computation. A
worker that dies mid-task (killed, out of memory, restarted) loses nothing: the scheduler runs
its task again on another worker. A cluster left without workers (all died, or none started),
or whose scheduler stops answering, ends the job after :data:`NO_WORKERS_S` seconds
(``NAVLAB_DASK_NO_WORKERS_S``) with a message naming the scheduler; the finished tasks are kept.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import statistics
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from navlab.errors import NavlabError

ENV = "NAVLAB_DASK_SCHEDULER"
POLL_S = 0.2  # while waiting on a cluster, call tick() this often (the app processes Stop)
# The embedded cluster's start-up on this 2-core machine: LocalCluster up in 2.8–3.5 s, then its 2
# workers import navlab and load the kernels in 8.7–16 s (load average 3); ≈ 6 s in all when the
# machine is idle (benchmarks/sweep_dask.py). A job starts it only for more work than
# START_FACTOR × this: the start competes with the job for the 2 cores, and 2 workers are at
# best 1.6× one.
START_S = 12.0
START_FACTOR = 2.0
# A warm cluster takes a job only above this much estimated work (dispatch, result transfer, and a
# speed-up of 1.1–1.8× on 2 busy cores: benchmarks/sweep_dask.py).
PAYS_S = 2.0
NO_WORKERS_ENV = "NAVLAB_DASK_NO_WORKERS_S"
NO_WORKERS_S = 60.0  # a job ends after this long without a worker (or an answer from its scheduler)
CHECK_S = 2.0  # how often a waiting job asks its scheduler how many workers it has

Done = Callable[[Any, Any], None]


class ClusterError(NavlabError):
    """A Dask cluster could not start, or lost every worker while a job waited on it."""


class SerialExecutor:
    """Every task in this process, one after the other."""

    name = "this process (serial)"
    workers = 1
    report = now = "in this process (--scheduler serial / NAVLAB_DASK_SCHEDULER=serial)"

    def run(
        self,
        fn: Callable[[Any], Any],
        tasks: Sequence[Any],
        done: Done,
        keep: Done,
        *,
        should_stop: Callable[[], bool] | None = None,
        tick: Callable[[], None] | None = None,
    ) -> None:
        for t in tasks:
            if should_stop is not None and should_stop():
                return
            done(t, fn(t))


class DaskExecutor:
    """Tasks on a ``distributed.Client``'s cluster, collected as they finish."""

    def __init__(self, client: Any, name: str, *, fix: str | None = None) -> None:
        self.client = client
        self.name = name
        # what to do when the cluster has no workers
        self.fix = fix or (
            f"start workers (dask worker {_address(client)}) and run again to resume, or run in this "
            f"process (--scheduler serial, or {ENV}=serial for the app)"
        )
        self.report = self.now = f"on {name}"

    @property
    def workers(self) -> int:
        return max(1, n_workers(self.client) or 0)

    def run(
        self,
        fn: Callable[[Any], Any],
        tasks: Sequence[Any],
        done: Done,
        keep: Done,
        *,
        should_stop: Callable[[], bool] | None = None,
        tick: Callable[[], None] | None = None,
    ) -> None:
        from distributed import KilledWorker, as_completed

        futs = {self.client.submit(fn, t, key=f"navlab-task-{t.key}", pure=True): t for t in tasks}
        handled: set[Any] = set()
        ac = as_completed(futs, loop=self.client.loop)
        watch = _Watch(self.client, no_workers_s())
        try:
            while not ac.is_empty():
                if should_stop is not None and should_stop():
                    return
                if not ac.has_ready():
                    _wait_ready(ac)
                    if not ac.has_ready():
                        if tick is not None:
                            tick()
                        if watch.lost():
                            raise ClusterError(self._lost(watch, len(handled), len(futs)))
                        continue
                for f in ac.next_batch(block=False):
                    try:
                        res = f.result()  # a task's error is raised here
                    except KilledWorker as exc:
                        raise ClusterError(
                            f"a task killed {exc.allowed_failures + 1} workers of {self.name} in a "
                            "row (out of memory, or killed from outside): lower the runs or the "
                            "epochs, or run in this process (--scheduler serial) to see the error"
                        ) from None
                    done(futs[f], res)
                    handled.add(f)
        finally:
            # stopped or interrupted: keep every task that finished meanwhile, cancel the rest
            for f in set(futs) - handled:
                if f.status == "finished":
                    with contextlib.suppress(Exception):
                        keep(futs[f], f.result())
            left = [f for f in futs if f.status == "pending"]
            if left:
                with contextlib.suppress(Exception):
                    self.client.cancel(left)

    def _lost(self, watch: _Watch, finished: int, total: int) -> str:
        addr = _address(self.client)
        who = self.name if addr in self.name else f"{self.name} at {addr}"
        what = "has had no workers" if watch.answered else "has not answered"
        return (
            f"{who} {what} for {watch.limit_s:g} s (its workers died, or none were started); "
            f"{finished} of the {total} tasks sent to it finished (kept in the results store). "
            f"{self.fix[0].upper()}{self.fix[1:]}"
        )


def no_workers_s() -> float:
    """How long a job waits on a cluster without a worker (NAVLAB_DASK_NO_WORKERS_S)."""
    text = os.environ.get(NO_WORKERS_ENV, "").strip()
    if not text:
        return NO_WORKERS_S
    try:
        v = float(text)
    except ValueError:
        v = -1.0
    if not 0 < v < float("inf"):
        raise NavlabError(f"{NO_WORKERS_ENV} must be a positive number of seconds, got {text!r}")
    return v


def n_workers(client: Any, timeout: float = 5.0) -> int | None:
    """The workers of ``client``'s scheduler, or None when it does not answer within ``timeout``."""
    try:
        if client.status not in ("running", "connecting"):
            return None
        info = client.sync(client.scheduler.identity, n_workers=0, callback_timeout=timeout)
        return int(info.get("n_workers", 0))
    except Exception:
        return None


def _address(client: Any) -> str:
    with contextlib.suppress(Exception):
        return str(client.scheduler.address)
    return "unknown"


class _Watch:
    """Whether a cluster has been without workers (or an answer) for ``limit_s`` seconds."""

    def __init__(self, client: Any, limit_s: float) -> None:
        self.client, self.limit_s = client, limit_s
        self.checked = -float("inf")
        self.since: float | None = None  # first seen without workers
        self.answered = True

    def lost(self) -> bool:
        now = time.monotonic()
        if now - self.checked >= min(CHECK_S, self.limit_s / 4):
            self.checked = now
            n = n_workers(self.client)
            self.answered = n is not None
            if n:
                self.since = None
            elif self.since is None:
                self.since = now
        return self.since is not None and now - self.since >= self.limit_s


def _wait_ready(ac: Any) -> None:
    """Wait up to POLL_S for a finished future of ``ac`` (distributed.as_completed)."""
    cond = getattr(ac, "thread_condition", None)
    if cond is None:
        time.sleep(POLL_S / 10)
        return
    with cond:
        if not ac.has_ready():
            cond.wait(timeout=POLL_S)


class LocalExecutor:
    """On this machine: in this process while the work is short, on the embedded cluster when it
    pays (module note). ``report`` says where its jobs ran and why, ``now`` where it works now.
    """

    name = "this machine"

    def __init__(self, n_workers: int | None = None, embedded: Embedded | None = None) -> None:
        self.n_workers = int(n_workers or cpu_count())
        self.embedded = embedded or EMBEDDED
        self.now = "in this process"
        self.here = self.there = 0  # tasks computed in this process, on the cluster
        self.here_s = 0.0
        self.why = ""  # the reason of the last choice

    @property
    def workers(self) -> int:
        return self.n_workers

    @property
    def report(self) -> str:
        """Where the tasks ran (every job of this executor), and why."""
        if not self.here + self.there:
            return "nothing: every task came from the results store"
        here = f"{self.here} task{'s' * (self.here != 1)} in this process in {self.here_s:.1f} s"
        if not self.there:
            return f"{here}{self.why}"
        return (
            f"{self.there} tasks on the embedded Dask cluster ({self.n_workers} workers) and {here}{self.why}"
        )

    def run(self, fn, tasks, done, keep, *, should_stop=None, tick=None) -> None:
        """As :meth:`SerialExecutor.run`."""
        emb, todo = self.embedded, list(tasks)
        est, started = _Estimate(), False
        self.now = "in this process"
        for i, t in enumerate(todo):
            if should_stop is not None and should_stop():
                break
            work = est.work(len(todo) - i)
            if work is not None and self.n_workers > 1:
                client = emb.ready(self.n_workers)
                if client is not None and work > PAYS_S:
                    cause = "started in the background" if started else "already running"
                    self.why = f": ≈ {work:.0f} s of work left, above {PAYS_S:g} s (cluster {cause})"
                    name = f"the embedded Dask cluster ({self.n_workers} workers)"
                    self.now = f"on {name}"
                    count = _Count(done)
                    try:
                        DaskExecutor(client, name, fix=_EMBEDDED_FIX).run(
                            fn, todo[i:], count, keep, should_stop=should_stop, tick=tick
                        )
                    except ClusterError:
                        emb.discard(client)
                        raise
                    finally:
                        self.there += count.n
                    return
                if work > START_FACTOR * emb.start_cost() and emb.start(
                    self.n_workers, fn, _probes(todo[i:])
                ):
                    started = True
                    self.now = "in this process, while the embedded Dask cluster starts in the background"
            t0 = time.perf_counter()
            res = fn(t)
            seconds = float(getattr(res, "elapsed_s", time.perf_counter() - t0))  # a TaskResult's own
            est.add(t, seconds)
            self.here += 1
            self.here_s += seconds
            done(t, res)
        self.why = self._why(est, started)
        self.now = "in this process"

    def _why(self, est: _Estimate, started: bool) -> str:
        """Why the last job ran in this process, in words."""
        emb, cost = self.embedded, START_FACTOR * self.embedded.start_cost()
        if est.n < 2:
            return ""
        if self.n_workers < 2:
            return " (one core: a cluster cannot be faster)"
        if emb.error:
            return f" (the embedded Dask cluster could not start: {emb.error})"
        if started:
            return (
                " (the embedded Dask cluster, started in the background, was not ready before they finished)"
            )
        if emb.ready(self.n_workers) is not None:
            return f" (too little work for the embedded Dask cluster to pay: ≤ {PAYS_S:g} s)"
        return (
            f" (below what starting the embedded Dask cluster costs: it starts above ≈ {cost:.0f} s of work)"
        )


class _Count:
    """``done`` that counts its calls."""

    def __init__(self, done: Done) -> None:
        self.done, self.n = done, 0

    def __call__(self, task: Any, res: Any) -> None:
        self.n += 1
        self.done(task, res)


_EMBEDDED_FIX = (
    "run again to resume (a new embedded cluster is started), or run in this process "
    f"(--scheduler serial, or {ENV}=serial for the app)"
)
_SEEN: set[Any] = set()  # filters whose first task this process has run (its kernels are loaded)


class _Estimate:
    """Seconds per task from the tasks run in this process; the first task of each filter in the
    process is left out (it loads the filter's compiled kernels, many times a task's cost).
    """

    def __init__(self) -> None:
        self.warm: list[float] = []
        self.n = 0

    def add(self, task: Any, seconds: float) -> None:
        self.n += 1
        kind = getattr(task, "filter", None)
        if kind in _SEEN:
            self.warm.append(seconds)
        _SEEN.add(kind)

    def work(self, left: int) -> float | None:
        """The estimated seconds of ``left`` more tasks, or None before any warm task."""
        return statistics.median(self.warm) * left if self.warm else None


def _probes(tasks: Sequence[Any]) -> list[Any]:
    """One small task of each filter among ``tasks`` (``Task.probe``), to warm a new worker."""
    out: dict[Any, Any] = {}
    for t in tasks:
        probe = getattr(t, "probe", None)
        if probe is not None and t.filter not in out:
            out[t.filter] = probe()
    return list(out.values())


def _warm(fn: Callable[[Any], Any], probes: Sequence[Any]) -> int:
    for p in probes:
        fn(p)
    return len(probes)


def cpu_count() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


class Embedded:
    """The process's embedded LocalCluster: started in a background thread (its workers warmed up
    on a small task of each filter before it counts as ready), then kept for every later job.
    """

    TIMEOUT_S = 600.0  # a start that takes longer than this has failed

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.client: Any = None
        self.n = 0
        self.thread: threading.Thread | None = None
        self.error: str | None = None
        self.start_s: float | None = None  # the measured start-up of this process's cluster

    def start_cost(self) -> float:
        """Seconds a start costs: measured in this process if it started one, else START_S."""
        return self.start_s or START_S

    def ready(self, n: int) -> Any:
        """The client of a started and warmed cluster of ``n`` workers, or None."""
        with self._lock:
            c = self.client
            if c is not None and self.n == n and c.status == "running":
                return c
            return None

    def start(self, n: int, fn: Callable[[Any], Any] | None = None, probes: Sequence[Any] = ()) -> bool:
        """Start a cluster of ``n`` workers in the background unless one runs, starts or failed to
        start; True if this call started it.
        """
        with self._lock:
            if self.error or (self.thread is not None and self.thread.is_alive()):
                return False
            if self.client is not None and self.client.status == "running" and self.n == n:
                return False
            self.thread = threading.Thread(
                target=self._start, args=(n, fn, list(probes)), name="navlab-dask-start", daemon=True
            )
            self.thread.start()
            return True

    def wait(self, n: int, fn: Callable[[Any], Any] | None = None, probes: Sequence[Any] = ()) -> Any:
        """Start (if needed) and wait for the cluster: its client (ClusterError if it cannot start)."""
        self.start(n, fn, probes)
        th = self.thread
        if th is not None:
            th.join(self.TIMEOUT_S)
        client = self.ready(n)
        if client is None:
            raise ClusterError(
                f"could not start the embedded Dask cluster ({self.error or 'timed out'}); run with "
                "--scheduler serial, or start one yourself (dask scheduler; dask worker tcp://…) "
                "and pass --scheduler tcp://HOST:8786"
            )
        return client

    def _start(self, n: int, fn: Callable[[Any], Any] | None, probes: list[Any]) -> None:
        t0 = time.perf_counter()
        client = cluster = None
        try:
            from distributed import Client, LocalCluster

            logging.getLogger("distributed").setLevel(logging.ERROR)
            cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",  # no fixed port: sessions never collide
                host="127.0.0.1",
                silence_logs=logging.ERROR,
            )
            client = Client(cluster, set_as_default=False)
            client.wait_for_workers(n, timeout=self.TIMEOUT_S)
            if fn is not None and probes:
                workers = list(client.scheduler_info(n_workers=-1)["workers"])
                futs = [client.submit(_warm, fn, probes, workers=[w], pure=False) for w in workers]
                for f in futs:
                    f.result(timeout=self.TIMEOUT_S)
        except ImportError:
            self.error = "Dask is not installed: pip install 'dask[distributed]'"
        except Exception as exc:
            self.error = (
                f"{type(exc).__name__}: {str(exc).strip().splitlines()[0] if str(exc).strip() else ''}"
            )
        if self.error:
            _close(client, cluster)
            return
        with self._lock:
            self.client, self.n = client, n
            self.start_s = time.perf_counter() - t0
        atexit.register(_close, client, cluster)

    def discard(self, client: Any) -> None:
        """Forget ``client``'s cluster (it lost its workers) and close it; a later job starts anew."""
        with self._lock:
            if self.client is client:
                self.client, self.n = None, 0
        threading.Thread(target=_close, args=(client, getattr(client, "cluster", None)), daemon=True).start()

    def close(self) -> None:
        with self._lock:
            client, self.client, self.n = self.client, None, 0
        if client is not None:
            _close(client, getattr(client, "cluster", None))


EMBEDDED = Embedded()


def _close(client: Any, cluster: Any) -> None:
    for c in (client, cluster):
        if c is not None:
            with contextlib.suppress(Exception):
                c.close()


_CLIENTS: dict[str, Any] = {}
_LOCK = threading.Lock()


def remote_client(address: str) -> Any:
    """A client of the scheduler at ``address`` (cached per address)."""
    with _LOCK:
        client = _CLIENTS.get(address)
        if client is not None and client.status == "running":
            return client
        try:
            from distributed import Client
        except ImportError:
            raise NavlabError("Dask is not installed: pip install 'dask[distributed]'") from None
        try:
            client = Client(address, timeout="10s", set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise NavlabError(
                f"cannot reach the Dask scheduler at {address} ({exc}); start one with "
                "'dask scheduler' and workers with 'dask worker tcp://HOST:8786', or leave "
                f"--scheduler / {ENV} unset for the embedded cluster"
            ) from None
        _CLIENTS[address] = client
        atexit.register(_close_remote, client)
        return client


def _close_remote(client: Any) -> None:
    with contextlib.suppress(Exception):
        client.close()


def executor(address: str | None = None, n_workers: int | None = None) -> Any:
    """The executor for ``address``: None → ``NAVLAB_DASK_SCHEDULER`` → ``local``; ``serial``;
    ``local``; or a scheduler address (``tcp://HOST:8786``, ``HOST:8786``).
    """
    where = (address or os.environ.get(ENV) or "local").strip()
    if where == "serial":
        return SerialExecutor()
    if where == "local":
        return LocalExecutor(n_workers)
    if "://" not in where and ":" not in where:
        raise NavlabError(
            f"--scheduler must be 'local', 'serial' or a Dask scheduler address such as "
            f"tcp://HOST:8786, got {where!r}"
        )
    return DaskExecutor(remote_client(where), f"the Dask cluster at {where}")

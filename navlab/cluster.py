"""Where tasks run: in this process, on an embedded Dask cluster, or on an existing one.

Sweeps and tunings hand their :class:`navlab.tasks.Task` s to an executor:

* ``local`` (the default): an embedded ``distributed.LocalCluster`` on this machine — one worker
  process per core, one thread each, no dashboard, listening on 127.0.0.1 only — started the
  first time two or more tasks need computing (a single task runs in this process: starting a
  cluster costs ≈ 1 s) and closed when the process exits;
* ``tcp://HOST:8786`` (``--scheduler``, or ``NAVLAB_DASK_SCHEDULER`` for the app and the CLI): an
  existing cluster (``dask scheduler`` and ``dask worker tcp://HOST:8786`` on the machines; every
  worker needs the same navlab installed and, for real recordings, the data at the same path);
* ``serial``: this process, no Dask (tests, debugging).

Tasks are submitted under their store key, so two sessions on one cluster asking for the same
task share one computation. A worker that dies mid-task (killed, out of memory, restarted) loses
nothing: the scheduler runs its task again on another worker.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from navlab.errors import NavlabError

ENV = "NAVLAB_DASK_SCHEDULER"
POLL_S = 0.2  # while waiting on a cluster, call tick() this often (the app processes Stop)

Done = Callable[[Any, Any], None]


class ClusterError(NavlabError):
    """The embedded cluster could not start (the app then runs the tasks in its own process)."""


class SerialExecutor:
    """Every task in this process, one after the other."""

    name = "this process (serial)"
    workers = 1

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

    def __init__(self, client: Any, name: str) -> None:
        self.client = client
        self.name = name

    @property
    def workers(self) -> int:
        return max(1, len(self.client.scheduler_info(n_workers=-1).get("workers", {})))

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
        from distributed import as_completed

        futs = {self.client.submit(fn, t, key=f"navlab-task-{t.key}", pure=True): t for t in tasks}
        handled: set[Any] = set()
        ac = as_completed(futs, loop=self.client.loop)
        try:
            while not ac.is_empty():
                if should_stop is not None and should_stop():
                    return
                if not ac.has_ready():
                    _wait_ready(ac)
                    if not ac.has_ready():
                        if tick is not None:
                            tick()
                        continue
                for f in ac.next_batch(block=False):
                    done(futs[f], f.result())  # a task's error is raised here
                    handled.add(f)
        finally:
            # stopped or interrupted: keep every task that finished meanwhile, cancel the rest
            for f in set(futs) - handled:
                if f.status == "finished":
                    with contextlib.suppress(Exception):
                        keep(futs[f], f.result())
            left = [f for f in futs if f.status == "pending"]
            if left:
                self.client.cancel(left)


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
    """The embedded cluster, started on first need; one task alone runs in this process."""

    name = "an embedded Dask cluster on this machine"

    def __init__(self, n_workers: int | None = None) -> None:
        self.n_workers = n_workers

    @property
    def workers(self) -> int:
        return self.n_workers or cpu_count()

    def run(self, fn, tasks, done, keep, *, should_stop=None, tick=None) -> None:
        if len(tasks) < 2:
            SerialExecutor().run(fn, tasks, done, keep, should_stop=should_stop, tick=tick)
            return
        ex = DaskExecutor(local_client(self.n_workers), self.name)
        ex.run(fn, tasks, done, keep, should_stop=should_stop, tick=tick)


def cpu_count() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


_LOCAL: dict[int, Any] = {}
_CLIENTS: dict[str, Any] = {}
_LOCK = threading.Lock()


def local_client(n_workers: int | None = None) -> Any:
    """The process's embedded LocalCluster client (``n_workers`` processes, default one per core)."""
    n = int(n_workers or cpu_count())
    with _LOCK:
        client = _LOCAL.get(n)
        if client is not None and client.status == "running":
            return client
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise ClusterError(
                "Dask is not installed: pip install 'dask[distributed]' (or use --scheduler serial)"
            ) from None
        logging.getLogger("distributed").setLevel(logging.ERROR)
        try:
            cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",  # no fixed port: sessions never collide
                host="127.0.0.1",
                silence_logs=logging.ERROR,
            )
            client = Client(cluster, set_as_default=False)
        except Exception as exc:
            raise ClusterError(
                f"could not start the embedded Dask cluster ({type(exc).__name__}: {exc}); run with "
                "--scheduler serial, or start one yourself (dask scheduler; dask worker tcp://…) "
                "and pass --scheduler tcp://HOST:8786"
            ) from None
        _LOCAL[n] = client
        atexit.register(_close, client)
        return client


def _close(client: Any) -> None:
    try:
        cluster = client.cluster
        client.close()
        if cluster is not None:
            cluster.close()
    except Exception:
        pass


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

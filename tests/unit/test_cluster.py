"""A distributed.LocalCluster (2 workers) started here gives the serial path's numbers for a sweep
and a tune, and a task whose worker is killed halfway is recomputed: nothing is lost. A cluster
whose workers all died ends the job with a message naming its scheduler (the library, and the
CLI: exit 2, progress lines on a non-terminal), and the default executor hands a long job's
remaining tasks to a warm embedded cluster with the serial path's numbers.

Never timing-based: the kill waits for the task to say it has started (a marker file), and
waits have only generous fail-safe limits.
"""

from __future__ import annotations

import functools
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest

distributed = pytest.importorskip("distributed")
cloudpickle = pytest.importorskip("cloudpickle")

from navlab import cluster as C  # noqa: E402
from navlab import sweep as SW  # noqa: E402
from navlab import tasks as T  # noqa: E402
from navlab import tune as TU  # noqa: E402
from navlab.cluster import DaskExecutor  # noqa: E402
from navlab.experiment import ExperimentSpec  # noqa: E402
from navlab.store import Store  # noqa: E402

pytestmark = pytest.mark.slow
TIMING = ["us_per_run_step", "steps_per_s"]
SPEC = ExperimentSpec(filters=("kf", "huber-kf"), runs=10, seed=4, epochs=30, contamination=0.1)
SAFE_S = 300  # fail-safe limit of every wait (a loaded 2-core machine)
ROOT = Path(__file__).resolve().parents[2]

cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import tests/


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", host="127.0.0.1"
    )
    c = distributed.Client(cluster, set_as_default=False)
    c.wait_for_workers(2, timeout=SAFE_S)
    yield c
    c.close()
    cluster.close()


def _numbers(df: pd.DataFrame) -> pd.DataFrame:
    return df[~df.metric.isin(TIMING)].reset_index(drop=True)


def test_sweep_on_the_cluster_equals_serial(client):
    axes = [SW.Axis(SW.resolve(SPEC, "huber-kf.gamma"), (1.0, 2.0, 4.0))]
    serial = SW.run_sweep(SW.make_sweep(SPEC, axes, block=4))
    par = SW.run_sweep(SW.make_sweep(SPEC, axes, block=4), executor=DaskExecutor(client, "test"))
    assert par.complete and par.tasks_total == serial.tasks_total
    pd.testing.assert_frame_equal(_numbers(par.rows), _numbers(serial.rows))


def test_tune_on_the_cluster_equals_serial(client):
    st = TU.setup(SPEC, budget=4, train_runs=8)
    serial = TU.tune(st)
    par = TU.tune(st, executor=DaskExecutor(client, "test"))
    assert par.tuned == serial.tuned
    a, b = par.rows, serial.rows
    keep = ~a.metric.isin(TIMING)
    pd.testing.assert_frame_equal(a[keep].reset_index(drop=True), b[keep].reset_index(drop=True))


def _stall_once(marker: str, task: T.Task) -> T.TaskResult:
    """Runs the task, except the first time for (kf, runs from 0): says so and hangs until killed."""
    m = Path(marker)
    if task.filter == "kf" and task.start == 0 and not m.exists():
        m.write_text(str(os.getpid()))
        time.sleep(SAFE_S)
    return T.run_task(task)


def test_a_task_whose_worker_dies_is_recomputed(client, tmp_path):
    marker = tmp_path / "started"
    ts = T.tasks_for(SPEC, block=5)
    tasks = [t for v in ts.values() for t in v]
    want = T.compute(tasks)  # serial reference
    store = Store(tmp_path / "store")
    got: dict = {}
    err: list[BaseException] = []

    def work() -> None:
        try:
            got.update(
                T.compute(
                    tasks,
                    store=store,
                    executor=DaskExecutor(client, "test"),
                    task_fn=functools.partial(_stall_once, str(marker)),
                )
            )
        except BaseException as exc:
            err.append(exc)

    th = threading.Thread(target=work)
    th.start()
    deadline = time.monotonic() + SAFE_S
    while not marker.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert marker.exists(), "the stalling task never started"
    time.sleep(0.2)  # let the pid be written completely
    os.kill(int(marker.read_text()), signal.SIGKILL)  # the worker dies halfway through the task
    th.join(SAFE_S)
    assert not th.is_alive() and not err, err
    assert set(got) == {t.key for t in tasks}
    for t in tasks:
        assert store.get(t.key) is not None  # every task stored
        a, b = got[t.key].stats, want[t.key].stats
        assert (a.sse["pos"] == b.sse["pos"]).all() and (a.diverged == b.diverged).all()


def _in_thread(work) -> tuple[threading.Thread, list[BaseException]]:
    err: list[BaseException] = []

    def run() -> None:
        try:
            work()
        except BaseException as exc:
            err.append(exc)

    th = threading.Thread(target=run, daemon=True)  # daemon: a hang fails the test, not the run
    th.start()
    return th, err


def test_a_cluster_without_workers_ends_the_job_naming_its_scheduler(monkeypatch):
    monkeypatch.setenv(C.NO_WORKERS_ENV, "2")
    cluster = distributed.LocalCluster(
        n_workers=0, processes=False, dashboard_address=":0", host="127.0.0.1", protocol="tcp"
    )
    client = distributed.Client(cluster, set_as_default=False)
    try:
        tasks = [t for v in T.tasks_for(SPEC, block=5).values() for t in v]
        ticks: list[int] = []
        th, err = _in_thread(
            lambda: T.compute(
                tasks,
                executor=DaskExecutor(client, "the test cluster"),
                tick=lambda: ticks.append(1),
            )
        )
        th.join(120)  # the limit is 2 s; before, the job waited forever
        assert not th.is_alive(), "the job still waits on a cluster without workers"
        (exc,) = err
        assert isinstance(exc, C.ClusterError)
        msg = str(exc)
        assert cluster.scheduler_address in msg and "has had no workers for 2 s" in msg, msg
        assert "0 of the 4 tasks" in msg and "dask worker" in msg and "--scheduler serial" in msg
        assert "\n" not in msg and ticks  # one line; the caller's tick ran while it waited
    finally:
        client.close()
        cluster.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)  # its own session: the nanny and the worker too
    proc.wait(SAFE_S)


def test_cli_sweep_on_a_cluster_whose_workers_died_exits_2_with_one_line(tmp_path):
    addr = f"tcp://127.0.0.1:{_free_port()}"
    log = (tmp_path / "dask.log").open("w")
    dask = [sys.executable, "-m"]
    run = functools.partial(subprocess.Popen, stdout=log, stderr=log, start_new_session=True)
    sched = run(
        [
            *dask,
            "distributed.cli.dask_scheduler",
            "--host",
            "127.0.0.1",
            "--port",
            addr.rsplit(":", 1)[1],
            "--no-dashboard",
        ]
    )
    worker = run([*dask, "distributed.cli.dask_worker", addr, "--nthreads", "1", "--no-dashboard"])
    try:
        with distributed.Client(addr, timeout=SAFE_S, set_as_default=False) as client:
            client.wait_for_workers(1, timeout=SAFE_S)
            _kill(worker)  # kill -9: every worker of the cluster is gone
            deadline = time.monotonic() + SAFE_S
            while C.n_workers(client) and time.monotonic() < deadline:
                time.sleep(0.1)
            assert C.n_workers(client) == 0
        cmd = [sys.executable, "-m", "navlab", "sweep", "--scheduler", addr, "--filters", "kf"]
        cmd += ["--runs", "4", "--epochs", "20", "--param", "outliers.contamination", "--values", "0,0.1"]
        cmd += ["--store", str(tmp_path / "store")]
        env = {**os.environ, C.NO_WORKERS_ENV: "7", "PYTHONPATH": str(ROOT)}
        try:  # stderr is a pipe, not a terminal
            out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=180)
        except subprocess.TimeoutExpired:
            pytest.fail("navlab sweep still waits on a cluster without workers after 180 s")
        err = out.stderr.strip().splitlines()
        assert out.returncode == 2, out.stderr
        assert err[-1].startswith("navlab: error: the Dask cluster at " + addr), err
        assert "has had no workers for 7 s" in err[-1] and "dask worker" in err[-1]
        assert any(line.startswith("navlab: 0/2 tasks after ") for line in err[:-1]), err
        assert "internal error" not in out.stderr and "Traceback" not in out.stderr
    finally:
        _kill(worker)
        _kill(sched)
        log.close()


def test_the_default_executor_hands_a_job_to_its_warm_cluster_with_the_serial_numbers(monkeypatch):
    monkeypatch.setattr(C, "PAYS_S", 0.0)  # any work pays: the job moves once a cost is known
    monkeypatch.setattr(C.Embedded, "TIMEOUT_S", SAFE_S)
    axes = [SW.Axis(SW.resolve(SPEC, "huber-kf.gamma"), (1.0, 2.0, 4.0))]
    serial = SW.run_sweep(SW.make_sweep(SPEC, axes, block=4))
    emb = C.Embedded()
    try:
        tasks = SW.make_sweep(SPEC, axes, block=4).all_tasks()
        emb.wait(2, T.run_task, C._probes(tasks))
        assert emb.start(2) is False  # one cluster: a running one is not started again
        ex = C.LocalExecutor(2, embedded=emb)
        par = SW.run_sweep(SW.make_sweep(SPEC, axes, block=4), executor=ex)
        assert ex.there > 0 and ex.report.startswith(f"{ex.there} tasks on the embedded Dask cluster")
        assert ex.here + ex.there == serial.tasks_total
        pd.testing.assert_frame_equal(_numbers(par.rows), _numbers(serial.rows))
    finally:
        emb.close()

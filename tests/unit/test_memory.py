"""Bounded memory: a run's size is estimated before anything is computed and refused above the
budget with a message saying what to change; summary runs keep per-run statistics only."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from navlab import memory
from navlab.cli import main
from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, run_experiment, run_summary
from navlab.metrics import summarize


def test_the_issue_run_is_refused_at_once_with_the_estimate_and_what_to_change(capsys):
    t0 = time.perf_counter()
    rc = main(["run", "--filters", "kf", "--runs", "20000", "--epochs", "100000", "--outliers", "none"])
    err = capsys.readouterr().err
    assert rc == 2 and time.perf_counter() - t0 < 60  # refused before simulating anything
    assert "would hold about" in err and "GB" in err and "memory budget" in err
    assert "--summary" in err and "fewer runs or epochs" in err
    rc = main(["run", "--runs", "30", "--epochs", "50", "--memory-budget", "1MB"])
    assert rc == 2 and "the budget asked for" in capsys.readouterr().err


def test_budget_parsing_and_env(monkeypatch):
    assert memory.parse_bytes("8GB") == 8 * 2**30 and memory.parse_bytes("500 mb") == 500 * 2**20
    assert memory.parse_bytes("123") == 123
    with pytest.raises(NavlabError, match="memory size"):
        memory.parse_bytes("lots")
    monkeypatch.setenv(memory.ENV, "3GB")
    assert memory.budget_bytes() == 3 * 2**30
    monkeypatch.delenv(memory.ENV)
    assert 0 < memory.budget_bytes() <= memory.available_bytes()
    for bad in (float("nan"), float("inf"), [8], True):  # a script's budget that is no number of bytes
        with pytest.raises(NavlabError, match="memory budget"):
            memory.budget_bytes(bad)


def test_estimate_matches_what_a_run_holds():
    from navlab.experiment import plan, run_size
    from navlab.ui.runner import results_nbytes

    spec = ExperimentSpec(filters=("kf", "chi2-kf", "vb-akf"), runs=200, epochs=200)
    est = run_size(plan(spec)).full()
    held = results_nbytes(run_experiment(spec))
    assert held <= est <= 2.5 * held  # an upper bound, not a wild one


def test_a_million_run_summary_fits_in_a_few_hundred_mb():
    size = memory.Size(runs=1_000_000, epochs=100, n=4, m=2, filters=3)
    assert size.full() > 50 * 2**30  # a full run: tens of GB
    from navlab.experiment import summary_chunk

    chunk = summary_chunk(size)
    assert 200 <= chunk <= 5000  # batched enough that the per-epoch overhead is paid rarely
    assert size.summary(chunk, keep_epochs=False) < 700 * 2**20


def test_summary_run_gives_the_full_runs_numbers():
    spec = ExperimentSpec(filters=("kf", "chi2-kf"), runs=60, epochs=40)
    full = summarize(run_experiment(spec)).set_index(["filter", "metric"])
    summ = summarize(run_summary(spec, chunk_runs=17)).set_index(["filter", "metric"])
    common = summ.index.intersection(full.index).drop(
        [i for i in summ.index if i[1] in ("us_per_run_step", "steps_per_s")]
    )
    assert len(common) > 30
    for col in ("value", "ci_lo", "ci_hi"):
        np.testing.assert_allclose(summ.loc[common, col], full.loc[common, col], rtol=2e-6)
    # without per-epoch arrays: no mean of the per-epoch RMSE, no in-band share, same rest
    lean = summarize(run_summary(spec, keep_epochs=False))
    assert "mean_rmse_pos" not in set(lean.metric) and "rmse_pos" in set(lean.metric)


def test_summary_runs_beyond_the_full_run_limit_are_allowed(capsys):
    rc = main(["run", "--filters", "kf", "--runs", "25000", "--epochs", "10", "--outliers", "none"])
    assert rc == 2 and "--summary" in capsys.readouterr().err
    rc = main(
        ["run", "--filters", "kf", "--runs", "25000", "--epochs", "10", "--outliers", "none", "--summary"]
    )
    out = capsys.readouterr().out
    assert rc == 0 and "delta method" in out


def test_ledger_queues_then_refuses_and_always_releases():
    led = memory.Ledger(100)
    with led.reserve(60):
        assert led.in_use == 60
        with pytest.raises(NavlabError, match="server is busy"), led.reserve(60, wait_s=0.05):
            pass
        done = []

        def later():
            with led.reserve(60, wait_s=5):
                done.append(led.in_use)

        t = threading.Thread(target=later)
        t.start()
        time.sleep(0.1)
        assert not done  # queued while the first holds its share
    t.join(5)
    assert done == [60] and led.in_use == 0
    with pytest.raises(NavlabError, match="more than this server allows"), led.reserve(1000):
        pass
    with pytest.raises(RuntimeError), led.reserve(10):
        raise RuntimeError("a failing run")
    assert led.in_use == 0

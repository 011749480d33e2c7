"""navlab bench: ranked tables with the floor, an overall standing, resumable through the store,
and the same numbers whatever the executor.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from navlab import bench as BN
from navlab.cli import main
from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec
from navlab.store import Store
from navlab.tasks import StoppedError

FILTERS = ["kf", "huber-kf", "chi2-kf", "oracle-kf"]
TIMING = ["us_per_run_step"]


def _numbers(b: BN.BenchResult) -> pd.DataFrame:
    df = BN.rows(b)
    return df.drop(columns=[c for c in TIMING if c in df.columns]).reset_index(drop=True)


def test_bench_ranks_every_filter_beside_the_floor_and_the_genie(tmp_path):
    b = BN.run(BN.TINY, filters=FILTERS, store=Store(tmp_path / "s"))
    df = BN.rows(b)
    per = df[df.kind == "problem"]
    for name, t in per.groupby("problem"):
        ranked = t[t["rank"].notna()]
        assert set(ranked["filter"]) == {"kf", "huber-kf", "chi2-kf"}, name
        assert list(ranked["rank"]) == [1, 2, 3]
        genie = t[t["filter"] == "oracle-kf"]
        assert len(genie) == 1 and genie["rank"].isna().all()
        assert (t["pcrb"] > 0).all() and np.allclose(t["gap"], t["value"] / t["pcrb"])
        # reliable filters in RMSE order
        assert (np.diff(ranked["value"].to_numpy()) >= 0).all()
    ov = df[df.kind == "overall"]
    assert set(ov["filter"]) == {"kf", "huber-kf", "chi2-kf"}
    assert ((ov.ci_lo <= ov.score) & (ov.score <= ov.ci_hi)).all()
    assert ov["verdict"].iloc[0] in ("best", "lowest (not significantly)")
    assert "overall standing over 2 problems" in BN.text(b)


def test_a_stopped_bench_resumes_from_the_store_with_the_same_numbers(tmp_path):
    suite = BN.TINY
    whole = BN.run(suite, filters=FILTERS, store=Store(tmp_path / "whole"))
    store = Store(tmp_path / "part")
    seen = {"n": 0}

    def stop() -> bool:  # as a kill would: after some tasks, nothing more
        seen["n"] += 1
        return seen["n"] > 25

    with pytest.raises(StoppedError):
        BN.run(suite, filters=FILTERS, store=store, should_stop=stop)
    kept = len(store.files())
    assert 0 < kept < whole.computed
    again = BN.run(suite, filters=FILTERS, store=store)
    assert again.cached >= kept and again.computed + again.cached == whole.computed
    pd.testing.assert_frame_equal(_numbers(again), _numbers(whole))
    third = BN.run(suite, filters=FILTERS, store=store)
    assert third.computed == 0


def test_last_bench_is_saved_for_the_leaderboard(tmp_path):
    b = BN.run(BN.TINY, filters=["kf", "huber-kf", "oracle-kf"], store=Store(tmp_path / "s"))
    p = BN.save(b, tmp_path / "out")
    d = BN.load(tmp_path / "out")
    assert p.exists() and d["suite"] == "tiny" and len(d["problems"]) == 2
    spec = ExperimentSpec.from_dict(d["problems"][0]["spec"])
    assert spec.seed == 50 and set(spec.filters) == {"kf", "huber-kf", "oracle-kf"}
    assert BN.load(tmp_path / "nothing") is None


def test_bench_cli_bad_input_is_one_line(capsys, tmp_path):
    rc = main(["bench", "--filters", "kf,nope", "--store", str(tmp_path), "-q"])
    _, err = capsys.readouterr()
    assert rc == 2 and "nope" in err and "Traceback" not in err
    with pytest.raises(NavlabError):
        BN.get_suite("huge")
    with pytest.raises(NavlabError, match="not an oracle"):
        BN.setups(BN.TINY, ["oracle-kf"])


def test_the_cost_on_paper_counts_the_tasks_tune_sends(tmp_path):
    from navlab import tune as TU

    suite = BN.Suite("one", BN.TINY.problems[:1], budget=4, train_runs=8, test_runs=12)
    st = BN.setups(suite, ["kf", "huber-kf"])[0]
    n = sum(len(b) for b in BN._tasks_of(st))
    ran = BN.run(suite, filters=["kf", "huber-kf"], store=Store(tmp_path / "s"))
    # at most what tune counts; at least what it computed (a tuned value equal to the default
    # is the default's task: one fewer)
    assert ran.computed <= n <= TU.count_tasks(st)
    assert n - ran.computed <= 1


@pytest.mark.slow
def test_the_bench_on_a_two_worker_cluster_equals_serial(tmp_path):
    distributed = pytest.importorskip("distributed")
    from navlab.cluster import DaskExecutor

    suite = BN.TINY
    serial = BN.run(suite, filters=FILTERS, store=Store(tmp_path / "a"))
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", host="127.0.0.1"
    )
    try:
        with distributed.Client(cluster, set_as_default=False) as c:
            c.wait_for_workers(2, timeout=300)
            par = BN.run(
                suite, filters=FILTERS, store=Store(tmp_path / "b"), executor=DaskExecutor(c, "test")
            )
    finally:
        cluster.close()
    pd.testing.assert_frame_equal(_numbers(par), _numbers(serial))
    assert json.dumps(BN.to_json(par)["overall"][0]["score"]) == json.dumps(
        BN.to_json(serial)["overall"][0]["score"]
    )


def test_the_problems_experiment_reproduces_its_table(tmp_path):
    # what a Leaderboard cell opens on Compare: every filter tuned, the test seed
    from navlab import metrics as M
    from navlab.experiment import run_experiment

    b = BN.run(BN.TINY, filters=FILTERS, store=Store(tmp_path / "s"))
    prob = BN.to_json(b)["problems"][0]
    res = run_experiment(ExperimentSpec.from_dict(prob["spec"]))
    sm = M.summary(res)
    for r in prob["rows"]:
        assert sm.estimate(r["filter"], r["metric"]).value == pytest.approx(r["value"], rel=1e-12)


@pytest.mark.parametrize("fmt", ["markdown", "latex"])
def test_bench_tables_for_a_paper(tmp_path, fmt):
    b = BN.run(BN.TINY, filters=["kf", "huber-kf", "oracle-kf"], store=Store(tmp_path / "s"))
    text = BN.paper(b, fmt)
    assert text.count("overall standing") == 1 and "cv2d student-t" in text
    assert (
        ("\\begin{table}" in text)
        if fmt == "latex"
        else ("| rank |" in text or "|rank|" in text.replace(" ", ""))
    )

"""Seed-robust reproductions: the verdict rules on claims whose truth is known independently, the
sets being the single-seed runs, every registered reproduction yielding a verdict per claim, and
the orderings a faithful implementation of ALGORITHMS.md §4 shows (never a paper value as a result)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from navlab.cli import main
from navlab.experiment import ExperimentSpec, run_experiment
from navlab.metrics import summarize
from navlab.reproduce import REPRODUCTIONS
from navlab.reproduce.engine import (
    VERDICTS,
    Alternative,
    Bound,
    Experiment,
    Margin,
    Number,
    Ranking,
    Ref,
    Reproduction,
    Untested,
    combine,
    component_error,
    iter_evaluate,
    pooled_rmse,
    replace_spec,
)
from navlab.reproduce.report import VERDICT_RULES, counts, latex, markdown, register_markdown, text

SPEC = ExperimentSpec(filters=("kf", "oracle-kf"), runs=12, epochs=40, outliers="mixture", contamination=0.2)


def _truth_rmse() -> float:
    """The oracle KF's pooled x-position RMSE from 4000 other runs (independent of the sets)."""
    res = run_experiment(SPEC.replace(runs=4000, seed=99))
    df = summarize(res, metrics=["rmse_x_pos"])
    return float(df[(df["filter"] == "oracle-kf") & (df.metric == "rmse_x_pos")].value.iloc[0])


def _rep(claims) -> Reproduction:
    q = pooled_rmse("rmse_x", "m", component_error((0,)))
    return Reproduction("test", "a test", "nobody 2026", (Experiment("e", SPEC),), (q,), tuple(claims))


def test_verdict_rules_on_claims_with_a_known_truth():
    truth = _truth_rmse()
    e = lambda k: Ref("e", k)  # noqa: E731
    rep = _rep(
        [
            Number("right", "oracle x RMSE = the truth", e("oracle-kf"), "rmse_x", truth),
            Number("off", "oracle x RMSE = twice the truth", e("oracle-kf"), "rmse_x", 2 * truth),
            Ranking("oracle-better", "the oracle beats the KF", e("oracle-kf"), (e("kf"),), "rmse_x"),
            Ranking("kf-better", "the KF beats the oracle", e("kf"), (e("oracle-kf"),), "rmse_x"),
            Bound("above", "oracle above 0.1 m", e("oracle-kf"), "rmse_x", 0.1, True),
            Bound("below", "oracle below 0.1 m", e("oracle-kf"), "rmse_x", 0.1, False),
            Margin("margin-off", "the oracle 99 % better", e("oracle-kf"), e("kf"), "rmse_x", -0.99),
        ]
    )
    v = rep.evaluate(seeds=8).verdicts.set_index("claim")
    assert v.loc["right", "verdict"] == "reproduced"
    assert v.loc["right", "ci_lo"] <= truth <= v.loc["right", "ci_hi"]
    assert v.loc["off", "verdict"] == "contradicted"
    assert (
        v.loc["oracle-better", "verdict"] == "reproduced"
        and v.loc["oracle-better", "share_of_seeds_holding"] == 1
    )
    assert v.loc["kf-better", "verdict"] == "contradicted"
    assert (v.loc["above", "verdict"], v.loc["below", "verdict"]) == ("reproduced", "contradicted")
    assert v.loc["margin-off", "verdict"] == "contradicted"
    assert (v["seeds"] == 8).all() and (v["runs_per_seed"] == 12).all()


def test_setup_dependent_and_not_testable_verdicts():
    """A verdict that flips under a documented alternative is setup-dependent (both shown); an
    alternative that does not decide, or agrees, leaves it; an untestable claim and a failed
    reconstruction give 'not testable'; a 'worst' ranking turns the claim round.
    """
    e = lambda k: Ref("e", k)  # noqa: E731
    oracle_better = Ranking("", "", e("oracle-kf"), (e("kf"),), "rmse_x")
    rep = _rep(
        [
            Ranking(
                "flips",
                "the KF beats the oracle",
                e("kf"),
                (e("oracle-kf"),),
                "rmse_x",
                alternatives=(Alternative("swapped reading", oracle_better),),
            ),
            Ranking(
                "shown-only",
                "the KF beats the oracle",
                e("kf"),
                (e("oracle-kf"),),
                "rmse_x",
                alternatives=(Alternative("not the paper's", oracle_better, decides=False),),
            ),
            Ranking(
                "kf-worst", "the KF worse than the oracle", e("kf"), (e("oracle-kf"),), "rmse_x", worst=True
            ),
            Ranking("needs-ok", "oracle better", e("oracle-kf"), (e("kf"),), "rmse_x", needs=("oracle-kf",)),
            Untested(
                "untested", "a shape the paper gives no measure of", "no measure is given", where="Fig. 9"
            ),
        ]
    )
    v = rep.evaluate(seeds=4).verdicts.set_index("claim")
    assert (
        v.loc["flips", "verdict"] == "setup-dependent" and v.loc["flips", "verdict_navlab"] == "contradicted"
    )
    assert "swapped reading: reproduced" in v.loc["flips", "note"]
    assert (
        v.loc["shown-only", "verdict"] == "contradicted" and "not the paper's" in v.loc["shown-only", "note"]
    )
    assert v.loc["kf-worst", "verdict"] == "reproduced"
    assert v.loc["needs-ok", "verdict"] == "reproduced"  # the reconstruction did not fail
    assert v.loc["untested", "verdict"] == "not testable" and "no measure" in v.loc["untested", "note"]
    alt = Alternative("x", oracle_better)
    assert combine("reproduced", "X diverges in 400 of 400 runs", []) == "not testable"
    assert combine("inconclusive", "", [(alt, "contradicted")]) == "inconclusive"  # no flip: not decisive
    assert combine("reproduced", "", [(alt, "reproduced")]) == "reproduced"
    assert set(VERDICT_RULES) == set(VERDICTS)


def test_claims_register_is_the_doc_and_every_entry_has_a_source():
    """docs/CLAIMS.md is generated from the declared claims (python tools/claims_register.py), and
    every entry names where in the paper it comes from and quotes it; an untested one says why.
    """
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "CLAIMS.md").read_text(encoding="utf-8")
    assert doc == register_markdown(), "docs/CLAIMS.md is stale: run python tools/claims_register.py"
    for key in REPRODUCTIONS:
        claims = REPRODUCTIONS[key].claims
        ids = [c.id for c in claims]
        assert len(set(ids)) == len(ids), key
        for c in claims:
            assert c.where and c.quote, f"{key}:{c.id} has no source"
            assert f"`{c.id}`" in doc
            if isinstance(c, Untested):
                assert len(c.reason) > 20
            for a in c.alternatives:
                assert a.label and not a.claim.alternatives


def test_seed_sets_are_the_single_seed_runs():
    """Set s of the base seed is runs s·N … s·N + N − 1: set 0 is the old single-seed result."""
    rep = _rep([Number("n", "x", Ref("e", "kf"), "rmse_x", 1.0)])
    ev = rep.evaluate(12, 3, 1, jobs=1).evaluator
    measured = ev.m
    per_set = ev.per_set(Ref("e", "kf"), "rmse_x")
    for s in range(3):
        spec = SPEC.replace(runs=12 * (s + 1))
        res = run_experiment(spec)
        x = res.runs["kf"].x[12 * s :, 1:, 0] - res.data.x_true[12 * s :, 1:, 0]
        assert per_set[s] == pytest.approx(np.sqrt(np.mean(x**2)), rel=1e-12)
    assert measured["e"].judged["kf"].shape == (36,)


@pytest.mark.parametrize(
    "key",
    # nnmfukf trains its RBF network: 9 s on this machine
    [pytest.param(k, marks=pytest.mark.slow) if k == "nnmfukf" else k for k in sorted(REPRODUCTIONS)],
)
def test_every_reproduction_gives_a_verdict_per_claim(key):
    rep = REPRODUCTIONS[key]
    short = {"hakf": 120, "nnmfukf": 700, "irakf": 100, "vbekf": 200}
    if key in ("hakf", "nnmfukf"):
        rep = replace_spec(rep, epochs=short[key])
    o = rep.evaluate(runs=3, seeds=2)
    v = o.verdicts
    assert list(v["claim"]) == [c.id for c in rep.claims]  # one row per register entry, in order
    assert set(v["verdict"]) <= set(VERDICTS) and sum(counts(o).values()) == len(v)
    assert (v.loc[v["verdict"] == "not testable", "note"].str.contains("not testable")).all()
    assert v["text"].str.len().min() > 10
    assert len(o.readings) >= len(rep.quantities) and o.curves
    out = text(o)
    assert "None" not in out and "nan" not in out.lower()
    md = markdown(o)
    assert md.count("\n|") >= len(rep.claims) and f"reproduce {key} --seeds 2" in md
    assert "None" not in md and "nan" not in md.lower()
    if "see note" in md:  # a row that points to a note has it beside the table
        assert "Notes (by claim number)" in md
    tex = latex(o)  # the table for a paper: ASCII booktabs, a row per claim, seeds and runs named
    assert tex.isascii() and "\\toprule" in tex and f"{o.seeds} seeds x {o.runs}" in tex
    assert len(tex.split("\\midrule\n")[1].split("\\bottomrule")[0].strip().splitlines()) == len(rep.claims)
    assert max(len(line) for line in out.splitlines() if not line.startswith(" ")) < 250
    assert max(len(line) for line in out.splitlines() if line.startswith("  ")) <= 100  # wrapped notes


@pytest.fixture(scope="module")
def irakf():
    return REPRODUCTIONS["irakf"].evaluate(runs=40, seeds=2)


def test_irakf_orderings_a_faithful_implementation_shows(irakf):
    r = irakf.readings.set_index(["experiment", "filter", "quantity"]).value
    iso = lambda k: r[("isolated", k, "rmse_x_pos")]  # noqa: E731
    assert iso("irakf") < 0.9 * iso("kf") and iso("irakf") < iso("rakf") and iso("irakf") < iso("rsshakf")
    cont = lambda k, q: r[("continuous", k, q)]  # noqa: E731
    assert cont("irakf", "rmse_x_vel") < cont("kf", "rmse_x_vel")
    assert cont("irakf", "run_peak_x_pos_window") < cont("kf", "run_peak_x_pos_window")
    assert cont("irakf", "peak_rmse_x_pos_window") < cont("rakf", "peak_rmse_x_pos_window")
    for exp in ("isolated", "continuous"):  # the oracle is the floor
        for k in ("kf", "rrae", "rakf", "rsshakf", "irakf"):
            assert r[(exp, "oracle-kf", "rmse_x_pos")] < r[(exp, k, "rmse_x_pos")]
    v = irakf.verdicts.set_index("claim")
    assert v.loc["iso-irakf-pos", "paper"] == 1.5942  # the paper's numbers are the claims'
    assert "not reproducible" in v.loc["cont-irakf-pos", "note"]


def test_cli_reproduce_json_and_details(capsys):
    rc = main(["reproduce", "vbekf", "--seeds", "2", "--runs", "4", "--format", "json"])
    rows = json.loads(capsys.readouterr().out)
    assert rc == 0 and {r["claim"] for r in rows} >= {"ekf-deviation", "ratio-rmse", "vbekf-better-rmse"}
    assert all(
        {"claim", "paper", "mean", "ci_lo", "ci_hi", "seeds", "share_of_seeds_holding", "verdict"} <= set(r)
        for r in rows
    )
    rc = main(["reproduce", "vbekf", "--seeds", "2", "--runs", "4", "--details", "--format", "csv"])
    out = capsys.readouterr().out
    assert rc == 0 and out.startswith("experiment,filter,label,quantity,value,ci_lo,ci_hi")
    rc = main(["reproduce", "vbekf", "--seeds", "0"])
    assert rc == 2 and "--seeds" in capsys.readouterr().err


@pytest.mark.slow
def test_worker_processes_and_blocks_give_the_same_numbers(monkeypatch):
    """Run r draws the same numbers in any block and any process: the verdicts and readings of
    2 worker processes over blocks of a few runs equal those of one process over one block.
    """
    from navlab.reproduce import engine

    rep = REPRODUCTIONS["irakf"]
    one = rep.evaluate(runs=5, seeds=2, jobs=1)  # 10 runs per experiment: one block each
    size = engine.run_size(engine.plan(rep.experiments[0].spec))
    per_run = engine.memory.Size(1, size.epochs, size.n, size.m, size.filters).full()
    monkeypatch.setattr(engine, "BLOCK_BYTES", 4 * per_run)  # blocks of 4 runs
    monkeypatch.setattr(engine, "POOL_MIN_STEPS", 0)
    first = rep.experiments[0].name
    blocks = [(t.start, t.stop) for t in engine._plan(rep, 5, 2, 1) if t.experiment == first]
    assert blocks == [(0, 2), (2, 5), (5, 7), (7, 10)]  # whole seeds, split into blocks of ≤ 4 runs
    # not streamed (the CLI): one seed range, in blocks of ≤ 4 runs
    flat = [(t.start, t.stop) for t in engine._plan(rep, 5, 2, 1, stream=False) if t.experiment == first]
    assert flat == [(0, 3), (3, 6), (6, 10)]
    seen = []
    two = rep.evaluate(runs=5, seeds=2, jobs=2, on_progress=lambda d, t: seen.append((d, t)))
    total = 5 * 2 * len(rep.experiments)
    tasks = engine._plan(rep, 5, 2, 1, stream=False)
    assert seen[0] == (0, total) and seen[-1] == (total, total) and len(seen) == 1 + len(tasks)
    serial = rep.evaluate(runs=5, seeds=2, jobs=1)
    streamed = rep.evaluate(runs=5, seeds=2, jobs=1, stream=True)
    for o in (two, serial, streamed):
        for name in ("verdicts", "readings"):
            a, b = getattr(one, name), getattr(o, name)
            assert list(a["note"]) == list(b["note"])  # the printed numbers
            num = a.select_dtypes("number").columns
            np.testing.assert_allclose(b[num].to_numpy(float), a[num].to_numpy(float), rtol=1e-12)
        for k, df in one.curves.items():
            np.testing.assert_allclose(o.curves[k].to_numpy(), df.to_numpy(), rtol=1e-6)
    for name in ("verdicts", "readings"):  # processes or not, the same blocks: bit for bit
        assert getattr(two, name).equals(getattr(serial, name))


def test_jobs_must_be_a_whole_number(monkeypatch, capsys):
    from navlab.errors import NavlabError
    from navlab.reproduce.engine import default_jobs

    rep = replace_spec(REPRODUCTIONS["vbekf"], epochs=20)
    for bad in (0, -1, 1.5, "two", True):
        with pytest.raises(NavlabError, match="whole number"):
            rep.evaluate(runs=2, seeds=1, jobs=bad)
    monkeypatch.setenv("NAVLAB_JOBS", "3")
    assert default_jobs() == 3
    monkeypatch.setenv("NAVLAB_JOBS", "many")
    with pytest.raises(NavlabError, match="NAVLAB_JOBS"):
        default_jobs()
    monkeypatch.delenv("NAVLAB_JOBS")
    assert default_jobs() >= 1
    rc = main(["reproduce", "vbekf", "--seeds", "1", "--runs", "2", "--jobs", "0"])
    assert rc == 2 and "--jobs" in capsys.readouterr().err
    # hundreds of workers (one per block: 456 for nnmfukf --seeds 400) would each hold navlab
    with pytest.raises(NavlabError, match="worker processes on this machine"):
        rep.evaluate(runs=2, seeds=1, jobs=100_000)
    monkeypatch.setenv("NAVLAB_JOBS", "100000")
    with pytest.raises(NavlabError, match="NAVLAB_JOBS 100000: at most"):
        default_jobs()


def _numbers(o) -> np.ndarray:
    return o.verdicts.select_dtypes("number").to_numpy(float)


def test_verdicts_stream_by_seed_blocks_and_equal_shorter_reproductions():
    """The provisional outcome after k seeds is exactly the k-seed reproduction's."""
    e = lambda k: Ref("e", k)  # noqa: E731
    rep = _rep(
        [
            Number("n", "oracle x RMSE 1 m", e("oracle-kf"), "rmse_x", 1.0),
            Ranking("r", "the oracle beats the KF", e("oracle-kf"), (e("kf"),), "rmse_x"),
        ]
    )
    outs = list(iter_evaluate(rep, 4, 5, 3, jobs=1))
    assert [o.seeds for o in outs] == [1, 2, 4, 5]
    assert [o.complete for o in outs] == [False, False, False, True]
    assert {o.seeds_asked for o in outs} == {5}
    for o in outs:
        alone = rep.evaluate(4, o.seeds, 3, jobs=1)
        np.testing.assert_array_equal(_numbers(o), _numbers(alone))
        assert list(o.verdicts["note"]) == list(alone.verdicts["note"])
    # one seed: a number has no interval, so it cannot be contradicted, only inconclusive or not
    first = outs[0].verdicts.set_index("claim")
    assert not np.isfinite(first.loc["n", "ci_lo"]) and first.loc["n", "verdict"] != "contradicted"


def test_store_keeps_finished_blocks_a_stopped_run_resumes(monkeypatch, tmp_path):
    """Stopped after the first blocks, a reproduction resumes from the store and computes only
    what is missing; a repeated one computes nothing; a longer one reuses the shorter one's
    seed blocks; the numbers are those of a run without a store.
    """
    from navlab.reproduce import engine
    from navlab.store import Store

    e = lambda k: Ref("e", k)  # noqa: E731
    rep = _rep([Ranking("r", "the oracle beats the KF", e("oracle-kf"), (e("kf"),), "rmse_x")])
    monkeypatch.setitem(REPRODUCTIONS, "test", rep)  # the store keeps registered reproductions only
    computed = []
    real = engine._measure_block

    def counting(rep_, spec, start, stop):
        computed.append((start, stop))
        return real(rep_, spec, start, stop)

    monkeypatch.setattr(engine, "_measure_block", counting)
    store = Store(tmp_path / "store")
    calls = iter(range(100))
    stopped = list(iter_evaluate(rep, 4, 5, 1, jobs=1, store=store, should_stop=lambda: next(calls) >= 2))
    assert [o.seeds for o in stopped] == [1, 2] and computed == [(0, 4), (4, 8)]
    computed.clear()
    shown = list(iter_evaluate(rep, 4, 5, 1, jobs=1, store=store, should_stop=lambda: True))
    assert [o.seeds for o in shown] == [2] and computed == []  # what the store holds, nothing computed
    resumed = rep.evaluate(4, 5, 1, jobs=1, store=store)
    assert computed == [(8, 16), (16, 20)]  # seeds 2–3 and 4
    computed.clear()
    again = rep.evaluate(4, 5, 1, jobs=1, store=store)
    assert computed == []
    longer = rep.evaluate(4, 6, 1, jobs=1, store=store)
    assert computed == [(16, 24)]  # seeds 0–3 from the store; seeds 4–5 are a new block
    monkeypatch.setattr(engine, "_measure_block", real)
    fresh = rep.evaluate(4, 5, 1, jobs=1)
    for o in (resumed, again):
        np.testing.assert_array_equal(_numbers(o), _numbers(fresh))
        for k, df in fresh.curves.items():
            np.testing.assert_array_equal(o.curves[k].to_numpy(), df.to_numpy())
    np.testing.assert_array_equal(_numbers(longer), _numbers(rep.evaluate(4, 6, 1, jobs=1)))


def _alive(pid: int) -> bool:
    import os

    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.slow
def test_closing_the_run_kills_its_worker_processes(monkeypatch, tmp_path):
    """A closed browser session closes the generator: the blocks not started are cancelled and
    the worker processes killed at once (not after the blocks in flight); the finished blocks are
    kept, and the resumed reproduction equals one never stopped.
    """
    import multiprocessing

    from navlab.reproduce import engine
    from navlab.store import Store

    rep = replace_spec(REPRODUCTIONS["irakf"], epochs=60)
    monkeypatch.setattr(engine, "POOL_MIN_STEPS", 0)
    killed = []
    real = engine._terminate

    def terminate(pool):
        killed.extend(pool._processes.values())
        real(pool)

    monkeypatch.setattr(engine, "_terminate", terminate)
    store = Store(tmp_path / "store")
    gen = iter_evaluate(rep, 100, 16, 1, jobs=2, store=store)
    # the first seeds of every experiment (seed 0, or more when the workers finished further
    # seed ranges before this process read the first: under load it read 4 once); the later
    # seeds queued or in flight
    first = next(gen)
    assert 1 <= first.seeds < 16
    gen.close()
    assert killed and all(p.exitcode != 0 for p in killed)  # killed, not finished
    for p in killed:  # gone (the pool's manager thread may be the one that reaps it: no exit code)
        deadline = time.monotonic() + 30
        while p.pid is not None and _alive(p.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(p.pid), p
    assert not [c for c in multiprocessing.active_children() if _alive(c.pid)]
    kept = len(store.files())
    blocks = len(engine._plan(rep, 100, 16, 1))  # 3 experiments (RSSHAKF's alternative too) × 5 seed ranges
    assert 2 <= kept < blocks  # at least seed 0 of each was kept; not every block ran

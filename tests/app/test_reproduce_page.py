"""AppTest of the Reproduce page: the default (fastest paper), empty registry, a small fast
reproduction streamed and resumed from the results store, a failing one, the charts of number
and of qualitative claims."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from apphelpers import assert_clean, plotly_figs

from navlab.experiment import ExperimentSpec
from navlab.reproduce import REPRODUCTIONS
from navlab.reproduce.engine import (
    VERDICTS,
    Close,
    Curve,
    Experiment,
    Number,
    Ranking,
    Ref,
    Reproduction,
    Untested,
    component_error,
    pooled_rmse,
)
from navlab.ui import reproduce as R
from navlab.ui import sweep as U

PAGE = "pages/4_Reproduce.py"

SPEC = ExperimentSpec(filters=("kf", "oracle-kf"), runs=4, epochs=25)
FAKE = Reproduction(
    key="aaa-fake",
    title="A small reproduction",
    paper="Nobody 2026",
    experiments=(Experiment("exp", SPEC),),
    quantities=(pooled_rmse("rmse_x", "m", component_error((0,))),),
    claims=(
        Number(
            "kf-x", "KF x RMSE 1 m", Ref("exp", "kf"), "rmse_x", 1.0, "the paper's run length is not stated"
        ),
        Ranking(
            "oracle-best", "the oracle beats the KF", Ref("exp", "oracle-kf"), (Ref("exp", "kf"),), "rmse_x"
        ),
        Untested("shape", "the KF fluctuates", "the paper gives no measure", where="Fig. 1", quote="…"),
    ),
    curves=(Curve("x", "m", component_error((0,))),),
    paper_runs=4,
)


def _broken(data, fr):
    raise RuntimeError("a broken reproduction")


FAILING = dataclasses.replace(
    FAKE, key="aab-failing", quantities=(dataclasses.replace(FAKE.quantities[0], features=_broken),)
)


@pytest.fixture(autouse=True)
def _fresh_store():
    """Each test's results store (conftest sets NAVLAB_STORE per test) and an empty memory."""
    U.app_store.clear()
    R._CACHE.clear()
    yield
    U.app_store.clear()
    R._CACHE.clear()


@pytest.fixture
def fake(monkeypatch):
    R._CACHE.clear()
    monkeypatch.setitem(REPRODUCTIONS, "aaa-fake", FAKE)
    monkeypatch.setitem(REPRODUCTIONS, "aab-failing", FAILING)
    yield
    R._CACHE.clear()


@pytest.fixture
def empty_registry():
    saved = dict(REPRODUCTIONS)
    REPRODUCTIONS.clear()
    yield
    REPRODUCTIONS.update(saved)


def test_page_works_with_no_reproduction(open_page, empty_registry):
    at = open_page(PAGE)
    assert_clean(at)
    assert any("No paper reproductions are registered" in i.value for i in at.info)


def test_opens_on_the_fastest_paper_and_says_what_the_seeds_mean(open_page):
    at = open_page(PAGE)
    assert_clean(at)
    assert at.selectbox(key="rep").value == R.DEFAULT_KEY == "irakf"
    assert at.number_input(key="rep_seeds").value == R.APP_SEEDS < 20
    captions = " ".join(c.value for c in at.caption)
    assert "answers in seconds" in captions and "`python -m navlab reproduce irakf --seeds 20`" in captions
    assert any("Press **Run**" in i.value for i in at.info)  # nothing computed before Run
    claims = at.table[0].value  # the claims, listed before they are judged
    n_untested = sum(isinstance(c, Untested) for c in REPRODUCTIONS["irakf"].claims)
    assert len(claims) == len(REPRODUCTIONS["irakf"].claims) and n_untested
    assert (claims["verdict"] == "not testable").sum() == n_untested  # known before any run
    assert set(claims["verdict"]) == {"not judged yet", "not testable"}
    # "IRAKF 27.43 % more accurate than RRAE" is listed as -27.43 %: the sign is explained
    assert "(A − B) / B, so negative means A has the lower error" in captions


def test_small_reproduction_streams_the_verdicts_and_keeps_them(open_page, fake, monkeypatch):
    at = open_page(PAGE, rep="aaa-fake", rep_seeds="3")
    assert_clean(at)
    assert any("Press **Run**" in i.value for i in at.info)
    at.button(key="rep_run").click().run()
    assert_clean(at)
    table = at.table[0].value
    assert list(table["claim"]) == ["KF x RMSE 1 m", "the oracle beats the KF", "the KF fluctuates"]
    assert set(table["verdict"]) <= set(VERDICTS) and table["verdict"].iloc[-1] == "not testable"
    assert "Judged on 3 seeds × 4 runs" in " ".join(c.value for c in at.caption)
    assert not at.warning  # complete: no "provisional"
    assert {m.label for m in at.metric} >= {"claims", *VERDICTS}  # every verdict kind counted
    assert {"Verdicts (CSV)", "Verdicts (LaTeX)"} <= {b.label for b in at.get("download_button")}
    figs = plotly_figs(at)
    assert len(figs) == 3  # the number claim, the ranking's evidence, one curve tab
    names = {t["name"] for t in figs[2]["data"]}
    assert names == {"KF", "Oracle KF"}  # no paper names declared: the filters' labels
    # the curve's tab and title in words, not the file name aaa-fake_exp_rmse_x.csv
    assert [t.label for t in at.tabs] == ["exp: RMSE of x"]
    assert "exp: RMSE of x" in figs[2]["layout"]["title"]["text"]
    bar = at.get("progress")[0].proto
    assert bar.value == 100 and bar.text.startswith(
        "12/12 runs"
    )  # 3 seeds × 4 runs  # progress ends at 100 %
    # another session (memory emptied): the verdicts come from the store, nothing is computed
    R._CACHE.clear()
    from navlab.reproduce import engine

    monkeypatch.setattr(engine, "_measure_block", lambda *a: pytest.fail("recomputed a stored block"))
    again = open_page(PAGE, rep="aaa-fake", rep_seeds="3")
    assert_clean(again)
    assert again.table[0].value["verdict"].tolist() == table["verdict"].tolist()


def test_a_stopped_reproduction_shows_its_seeds_and_run_resumes(open_page, fake, monkeypatch):
    from navlab.reproduce import engine

    FAKE.evaluate(runs=4, seeds=2, seed=1, store=U.app_store())  # what a run stopped after 2 seeds kept
    at = open_page(PAGE, rep="aaa-fake", rep_seeds="3")
    assert_clean(at)
    assert any("Provisional: judged on 2 seeds of 3" in w.value for w in at.warning)
    assert any("2 of 3 seeds judged and kept" in i.value for i in at.info)
    computed = []
    real = engine._measure_block
    monkeypatch.setattr(engine, "_measure_block", lambda *a: computed.append(a[2:]) or real(*a))
    at.button(key="rep_run").click().run()
    assert_clean(at)
    assert computed == [(8, 12)]  # only the missing seed
    assert not at.warning and "Judged on 3 seeds" in " ".join(c.value for c in at.caption)


def test_qualitative_claims_chart_their_evidence_never_an_empty_band():
    """A paper with only rankings and a 'close' claim: no number chart; the evidence chart has a
    dot with a finite interval for every paired difference."""
    e = lambda k: Ref("exp", k)  # noqa: E731
    rep = dataclasses.replace(
        FAKE,
        claims=(
            Ranking("r", "the oracle beats the KF", e("oracle-kf"), (e("kf"),), "rmse_x"),
            Close("c", "the KF and the oracle are close", (e("kf"), e("oracle-kf")), "rmse_x"),
        ),
    )
    o = rep.evaluate(runs=4, seeds=3, jobs=1)
    assert R.claims_figure(o) is None
    fig = R.evidence_figure(o)
    dots = [t for t in fig.data if t.error_x is not None and t.mode == "markers"][-1]
    assert list(dots.y) == ["2. KF vs Oracle KF", "1. Oracle KF vs KF"]
    x = np.asarray(dots.x, dtype=float)
    assert np.all(np.isfinite(x)) and x[1] < 0  # the oracle's error is lower than the KF's
    assert np.all(np.asarray(dots.error_x.array) > 0) and np.all(np.asarray(dots.error_x.arrayminus) > 0)
    assert len(fig.layout.shapes) >= 1  # the close claim's ±10 % band on its row


def test_a_failing_reproduction_gives_a_message(open_page, fake):
    at = open_page(PAGE, rep="aab-failing")
    at.button(key="rep_run").click().run()
    assert not at.exception
    # an internal error: its type only (a message can name server paths), the log has the rest
    assert any("internal error (RuntimeError)" in e.value for e in at.error)
    assert not any("a broken reproduction" in e.value for e in at.error)


def test_a_registered_reproduction_small_run(open_page):
    R._CACHE.clear()
    at = open_page(PAGE, rep="vbekf", rep_seeds="2", rep_runs_vbekf="3")
    at.button(key="rep_run").click().run()
    assert_clean(at)
    claims = at.table[0].value["claim"].tolist()
    assert "EKF/VB-EKF RMSE ratio 1.75 ‡" in claims  # ‡: τ_P = 10 was chosen on this scenario
    R._CACHE.clear()


def test_the_margin_note_only_where_the_paper_states_a_margin():
    assert R.margin_note(FAKE) is None  # a number, a ranking, an untested claim
    assert R.margin_note(REPRODUCTIONS["irakf"]).startswith("Margins (")

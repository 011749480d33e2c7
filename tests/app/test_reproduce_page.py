"""AppTest of the Reproduce page: empty registry, a small fast reproduction, a failing one."""

from __future__ import annotations

import dataclasses

import pytest
from apphelpers import assert_clean, plotly_figs

from navlab.experiment import ExperimentSpec
from navlab.reproduce import REPRODUCTIONS
from navlab.reproduce.engine import (
    Curve,
    Experiment,
    Number,
    Ranking,
    Ref,
    Reproduction,
    component_error,
    pooled_rmse,
)
from navlab.ui import reproduce as R

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
    ),
    curves=(Curve("x", "m", component_error((0,))),),
    paper_runs=4,
)


class Failing(Reproduction):
    def evaluate(self, *a, **k):
        raise RuntimeError("a broken reproduction")


@pytest.fixture
def fake(monkeypatch):
    R._CACHE.clear()
    monkeypatch.setitem(REPRODUCTIONS, "aaa-fake", FAKE)
    monkeypatch.setitem(
        REPRODUCTIONS,
        "aab-failing",
        Failing(**{f.name: getattr(FAKE, f.name) for f in dataclasses.fields(FAKE)} | {"key": "aab-failing"}),
    )
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


def test_small_reproduction_leads_with_the_verdicts_and_caches(open_page, fake):
    at = open_page(PAGE, rep="aaa-fake", rep_seeds="3")
    assert_clean(at)
    assert any("Press **Run**" in i.value for i in at.info)
    at.button(key="rep_run").click().run()
    assert_clean(at)
    table = at.dataframe[0].value
    assert list(table["claim"]) == ["KF x RMSE 1 m", "the oracle beats the KF"]
    assert set(table["verdict"]) <= {"reproduced", "contradicted", "inconclusive"}
    assert "3 seeds" in " ".join(c.value for c in at.caption)
    assert {m.label for m in at.metric} >= {"claims", "reproduced", "contradicted", "inconclusive"}
    figs = plotly_figs(at)
    assert len(figs) == 2  # the claims chart and one curve tab
    names = {t["name"] for t in figs[1]["data"]}
    assert names == {"KF", "Oracle KF"}  # no paper names declared: the filters' labels
    at.run()  # a rerun comes from the cache: the tables are still there
    assert at.dataframe[0].value["verdict"].tolist() == table["verdict"].tolist()


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
    claims = at.dataframe[0].value["claim"].tolist()
    assert "EKF/VB-EKF RMSE ratio 1.75" in claims
    R._CACHE.clear()

"""AppTest of the Reproduce page: empty registry, a fake fast reproduction, a real small run."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from apphelpers import assert_clean, plotly_figs

from navlab.errors import NavlabError
from navlab.reproduce import REPRODUCTIONS, Reproduction
from navlab.ui import reproduce as R

PAGE = "pages/4_Reproduce.py"
CALLS: list[tuple] = []


def fake_run(runs=None, seed=1, outdir=None, on_progress=None):
    """A fast stand-in with the reproduction interface: two paper numbers, a curve CSV."""
    runs = 7 if runs is None else runs
    CALLS.append((runs, seed))
    for d in range(1, runs + 1):
        if on_progress is not None:
            on_progress(d, runs)
    rows = [
        dict(
            experiment="exp",
            filter="kf",
            metric="rmse_pos",
            value=2.0,
            paper=1.0,
            rel_diff=1.0,
            unit="m",
            note="the paper's run length is not stated",
        ),
        dict(
            experiment="exp",
            filter="chi2-kf",
            metric="rmse_pos",
            value=1.05,
            paper=1.0,
            rel_diff=0.05,
            unit="m",
            note="",
        ),
        dict(
            experiment="exp",
            filter="kf",
            metric="runtime",
            value=3.0,
            paper=None,
            rel_diff=None,
            unit="µs",
            note="",
        ),
    ]
    if outdir is not None:
        Path(outdir).mkdir(parents=True, exist_ok=True)
        pd.DataFrame({"epoch": range(5), "kf": [3, 2, 2, 1, 1.0], "chi2-kf": [3, 2, 1, 1, 1.0]}).to_csv(
            Path(outdir) / "fake_curves.csv", index=False
        )
    return pd.DataFrame(rows)


def failing_run(runs=None, seed=1, outdir=None):
    raise NavlabError("runs must be at least 2 for this experiment")


@pytest.fixture
def fake(monkeypatch):
    CALLS.clear()
    R._CACHE.clear()
    monkeypatch.setitem(
        REPRODUCTIONS,
        "aaa-fake",
        Reproduction(key="aaa-fake", title="A fake reproduction", paper="Nobody 2026", run=fake_run),
    )
    monkeypatch.setitem(
        REPRODUCTIONS,
        "aab-failing",
        Reproduction(key="aab-failing", title="Always fails", paper="Nobody 2026", run=failing_run),
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


def test_fake_reproduction_runs_shows_paper_vs_ours_and_caches(open_page, fake):
    at = open_page(PAGE, rep="aaa-fake", rep_runs="3", rep_seed="5")
    assert_clean(at)
    assert at.selectbox(key="rep").value == "aaa-fake"
    assert at.number_input(key="rep_runs").value == 3
    assert not plotly_figs(at)  # nothing before Run
    at.button[0].click().run()
    assert_clean(at)
    assert CALLS == [(3, 5)]
    figs = plotly_figs(at)
    assert len(figs) == 3  # relative differences, paper-vs-navlab bars, curves
    bars = figs[1]["data"]
    assert [t["name"] for t in bars] == ["paper", "navlab"]
    curve_names = {t["name"] for t in figs[2]["data"]}
    assert curve_names == {"KF", "χ²-gated KF"}  # the filters' labels (coloured by key)
    (diff,) = [d.value for d in at.dataframe if "verdict" in d.value.columns]
    assert list(diff["filter"]) == ["kf", "chi2-kf"]  # largest disagreement first
    assert list(diff["verdict"]) == ["far", "close"]
    assert diff["note"].iloc[0] == "the paper's run length is not stated"
    labels = {m.label: m.value for m in at.metric}
    assert labels["numbers the paper gives"] == "2"
    assert labels["far (> 25 %)"] == "1" and labels["close (≤ 10 %)"] == "1"
    assert len(at.get("download_button")) == 2  # the curves CSV and the table
    # same configuration again: served from the cache, the reproduction is not re-run
    at.button[0].click().run()
    assert CALLS == [(3, 5)]
    assert len(plotly_figs(at)) == 3
    # the paper's count: runs=None reaches the reproduction (it uses its own default, 7)
    at.checkbox(key="rep_full").check().run()
    assert any("Press **Run**" in i.value for i in at.info)
    at.button[0].click().run()
    assert_clean(at)
    assert CALLS[-1] == (7, 5)


def test_a_failing_reproduction_gives_a_message(open_page, fake):
    at = open_page(PAGE, rep="aab-failing")
    at.button[0].click().run()
    assert not at.exception
    assert any("runs must be at least 2" in e.value for e in at.error)
    assert not plotly_figs(at)


def test_a_registered_reproduction_small_run(open_page):
    real = [k for k in sorted(REPRODUCTIONS) if not k.startswith("aa")]
    if not real:
        pytest.skip("no reproduction registered")
    key = "vbekf" if "vbekf" in real else real[0]
    R._CACHE.clear()
    at = open_page(PAGE, rep=key, rep_runs="2")
    at.button[0].click().run()
    assert_clean(at)
    table, _ = R.cached_run(key, 2, 1)
    assert list(table.columns[:8]) == [
        "experiment",
        "filter",
        "metric",
        "value",
        "paper",
        "rel_diff",
        "unit",
        "note",
    ]
    if table["paper"].notna().any():
        assert len(plotly_figs(at)) >= 2
    R._CACHE.clear()


def test_pure_helpers():
    df = fake_run(runs=2)
    d = R.differences(df)
    assert list(d["verdict"]) == ["far", "close"]
    assert R.paper_groups(df) == [("exp", "rmse_pos")]
    fig = R.bar_figure(df, "exp", "rmse_pos")
    assert fig.data[0].name == "paper" and list(fig.data[1].x) == ["kf", "chi2-kf"]
    long = pd.DataFrame(
        {
            "epoch": [0, 1, 0, 1],
            "filter": ["kf", "kf", "ekf", "ekf"],
            "rmse": [1.0, 2.0, 3.0, 4.0],
            "bias": [0.0, 0, 0, 0],
        }
    )
    assert R.is_long(long) and R.curve_measures(long) == ["rmse", "bias"]
    assert [t.name for t in R.curve_figure(long, "c", "rmse").data] == ["KF", "EKF"]
    wide = pd.DataFrame(
        {
            c: [0.0, 1.0]
            for c in ("t", "ekf_rmse_pos", "ekf_rmse_vel", "vb-ekf_rmse_pos", "vb-ekf_tauP3_rmse_pos")
        }
    )
    assert R.wide_groups(wide) == {
        "rmse_pos": ["ekf_rmse_pos", "vb-ekf_rmse_pos", "vb-ekf_tauP3_rmse_pos"],
        "rmse_vel": ["ekf_rmse_vel"],
    }
    assert R.wide_groups(pd.DataFrame({"epoch": [0], "kf": [1.0], "ekf": [2.0]})) == {}
    assert R.accepts(fake_run, "on_progress") and not R.accepts(failing_run, "on_progress")

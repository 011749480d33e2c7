"""The Leaderboard page: the last bench's overall standing, its heat map with links to Compare,
a problem's ranked table; without a bench, what to run.
"""

from __future__ import annotations

from apphelpers import assert_clean

from navlab import bench as BN
from navlab.experiment import ExperimentSpec
from navlab.store import Store

PAGE = "pages/8_Leaderboard.py"


def _tiny_bench(folder) -> None:
    probs = (BN.Problem("cv2d tiny", ExperimentSpec(scenario="cv2d", filters=("kf",), seed=60, epochs=30)),)
    suite = BN.Suite("tiny", probs, budget=2, train_runs=4, test_runs=10)
    b = BN.run(suite, filters=["kf", "huber-kf", "oracle-kf"], store=Store(folder / "store"))
    BN.save(b, folder / "bench")


def test_leaderboard_shows_the_last_bench_with_links_to_compare(open_page, tmp_path, monkeypatch):
    _tiny_bench(tmp_path)
    monkeypatch.setenv(BN.ENV_DIR, str(tmp_path / "bench"))
    at = open_page(PAGE)
    assert_clean(at)
    overall, problem = at.table
    assert list(overall.value["filter"]) and "verdict" in overall.value.columns
    assert set(problem.value["filter"]) == {"KF (tuned)", "HKF (Huber) (tuned)", "Oracle KF"}
    heat = next(m.value for m in at.markdown if "<table" in m.value)
    assert heat.count('href="Compare?') == 3 and "go=1" in heat and "flt=huber-kf" in heat


def test_leaderboard_without_a_bench_says_what_to_run(open_page, tmp_path, monkeypatch):
    monkeypatch.setenv(BN.ENV_DIR, str(tmp_path / "none"))
    at = open_page(PAGE)
    assert_clean(at)
    assert any("navlab bench --suite small" in i.value for i in at.info)

"""Compare shows the floor (posterior Cramér–Rao bound) beside the oracle: a paragraph under the
table and a dashed line on the error chart.
"""

from apphelpers import SMALL, assert_clean, plotly_figs

PAGE = "pages/1_Compare.py"


def test_compare_shows_the_floor_beside_the_oracle(open_page):
    at = open_page(PAGE, seed="3", out="mixture", **SMALL)
    at.button(key="run_compare").click().run()
    assert_clean(at)
    floor = [m.value for m in at.markdown if "Floor (posterior Cramér–Rao bound" in m.value]
    assert len(floor) == 1 and "the oracle" in floor[0] and "Gap (RMSE / floor)" in floor[0]
    err = next(f for f in plotly_figs(at) if "error over time" in f["layout"]["title"]["text"])
    assert "floor (PCRB)" in [t.get("name") for t in err["data"]]

"""Publication export (navlab.ui.export): what the pages' figures carry survives the redraw."""

from __future__ import annotations

import numpy as np
import pandas as pd
import plotly.graph_objects as go
import pytest
from matplotlib.collections import LineCollection

from navlab.experiment import ExperimentSpec, run_experiment
from navlab.ui import export, single
from navlab.ui import figures as F


def _errorbar_segments(ax) -> list[np.ndarray]:
    return [seg for c in ax.collections if isinstance(c, LineCollection) for seg in c.get_segments()]


def test_sweep_error_bars_are_drawn():
    df = pd.DataFrame(
        {
            "value": [1.0, 2.0, 4.0],
            "filter": ["kf"] * 3,
            "label": ["KF"] * 3,
            "metric_value": [1.0, 2.0, 3.0],
            "ci_lo": [0.5, 1.5, 2.0],
            "ci_hi": [1.2, 2.6, 3.1],
        }
    )
    fig = F.sweep_lines(df, "σ", "RMSE")
    with export._LOCK:
        ax = export.publication(fig).axes[0]
    segs = _errorbar_segments(ax)
    assert len(segs) == 3
    ends = np.array(sorted((s[:, 1].min(), s[:, 1].max()) for s in segs))
    np.testing.assert_allclose(ends, [(0.5, 1.2), (1.5, 2.6), (2.0, 3.1)], rtol=1e-6)
    bare = go.Figure(fig)
    bare.update_traces(error_y=None)
    assert export.to_svg(fig).count(b"<path") > export.to_svg(bare).count(b"<path")  # the bars


def test_claims_intervals_and_tolerance_band_are_drawn():
    from navlab.ui.reproduce import TOLERANCE

    fig = go.Figure(
        go.Scatter(
            x=[5.0, -10.0],
            y=["claim a", "claim b"],
            mode="markers",
            error_x={"type": "data", "symmetric": False, "array": [3.0, 4.0], "arrayminus": [2.0, 1.0]},
        )
    )
    fig.add_vrect(x0=-100 * TOLERANCE, x1=100 * TOLERANCE, fillcolor="rgba(44,160,44,0.08)", line_width=0)
    with export._LOCK:
        ax = export.publication(fig).axes[0]
    segs = _errorbar_segments(ax)
    ends = np.array(sorted((s[:, 0].min(), s[:, 0].max()) for s in segs))
    np.testing.assert_allclose(ends, [(-11.0, -6.0), (3.0, 8.0)])
    (band,) = ax.patches
    assert band.get_x() == pytest.approx(-100 * TOLERANCE)
    assert band.get_width() == pytest.approx(200 * TOLERANCE)


def test_the_players_cursor_and_veil_are_not_exported():
    res = run_experiment(ExperimentSpec(runs=2, epochs=30, seed=4, filters=("kf",)))
    fig = single.single_run_figure(res, 0, ["kf"], 0, 0)
    assert fig.frames and fig.layout.shapes
    with export._LOCK:
        mfig = export.publication(fig)
    assert all(not ax.patches for ax in mfig.axes)
    assert not [ln for ax in mfig.axes for ln in ax.lines if np.ptp(ln.get_xdata()) == 0]  # no cursor

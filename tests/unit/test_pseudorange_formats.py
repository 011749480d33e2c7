"""The generic pseudorange CSV, the smartLoc reader's variants and system codes, and the
pseudorange scenario on them (one clock per system, no odometry, no truth). Short slices of the
Berlin recording (written by examples/convert_smartloc.py); skips without ../shared/data."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from navlab.data import data_root
from navlab.data.loaders import SMARTLOC_DIR, load_pseudoranges, read_smartloc
from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, run_experiment

ROOT = Path(__file__).resolve().parents[2]
BERLIN = data_root() / SMARTLOC_DIR
pytestmark = pytest.mark.skipif(not BERLIN.is_dir(), reason=f"real data not found: {BERLIN}")
SECONDS = 40


def _convert(out: Path, *args: str) -> Path:
    sys.path.insert(0, str(ROOT / "examples"))
    try:
        import convert_smartloc
    finally:
        sys.path.pop(0)
    assert convert_smartloc.main(["--out", str(out), "--seconds", str(SECONDS), *args]) == 0
    return out


def _slice(tmp_path: Path, name="Frankfurt_Test", edit=None, gt=True) -> Path:
    """The first SECONDS of the Berlin files under another sequence name, lines edited by ``edit``."""
    d = tmp_path / name
    d.mkdir()
    keep = []
    for ln in (BERLIN / "Berlin_Potsdamer_Platz_Input.txt").read_text().splitlines():
        parts = ln.split()
        if parts and float(parts[1]) <= SECONDS:
            keep.append(edit(parts) if edit and parts[0] == "pseudorange3" else " ".join(parts))
    (d / f"{name}_Input.txt").write_text("\n".join(keep) + "\n")
    if gt:
        g = [
            ln
            for ln in (BERLIN / "Berlin_Potsdamer_Platz_GT.txt").read_text().splitlines()
            if float(ln.split()[1]) <= SECONDS
        ]
        (d / f"{name}_GT.txt").write_text("\n".join(g) + "\n")
    return d


def _run(folder, filters=("wls", "huber-kf"), **params):
    spec = ExperimentSpec(
        scenario="own-pseudoranges",
        filters=filters,
        runs=1,
        scenario_params={"data_dir": str(folder), **params},
    )
    return run_experiment(spec)


def _metric(res, key, metric):
    df = res.metrics()
    return float(df[(df["filter"] == key) & (df.metric == metric)].value.iloc[0])


def test_generic_csv_reads_like_the_smartloc_files(tmp_path):
    d = _convert(tmp_path / "csv")
    a = load_pseudoranges(d)
    b = read_smartloc(
        _slice(tmp_path) / "Frankfurt_Test_Input.txt", tmp_path / "Frankfurt_Test" / "Frankfurt_Test_GT.txt"
    )
    assert len(a.pr) == len(b.pr) and set(a.pr.system) == {1, 4}  # RINEX letters G/R -> 1/4
    np.testing.assert_allclose(a.pr.pseudorange_m, b.pr.pseudorange_m, rtol=1e-9)
    np.testing.assert_allclose(a.truth[["x_m", "y_m", "z_m"]], b.truth[["x_m", "y_m", "z_m"]], atol=1e-3)
    ra, rb = _run(d), _run(tmp_path / "Frankfurt_Test")
    assert _metric(ra, "huber-kf", "rmse_hpos") == pytest.approx(
        _metric(rb, "huber-kf", "rmse_hpos"), rel=1e-3
    )
    assert _metric(ra, "huber-kf", "rmse_hpos") < _metric(ra, "wls", "rmse_hpos")


@pytest.mark.parametrize(
    ("edit", "clocks"),
    [
        (lambda p: " ".join(["range3", *p[1:]]), ("GPS", "GLO")),  # the RTKLIB-postprocessed export
        (lambda p: " ".join(["range3", *p[1:8], *p[9:]]), ("GPS", "GLO")),  # no system column
        (lambda p: " ".join([*p[:8], "8" if p[8] == "4" else p[8], *p[9:]]), ("GPS", "GAL")),  # Galileo
        (lambda p: " ".join([*p[:8], "32" if p[8] == "4" else "16", *p[9:]]), ("QZS", "BDS")),
    ],
)
def test_smartloc_variants_and_every_system_code(tmp_path, edit, clocks):
    d = _slice(tmp_path, edit=edit)
    res = _run(d, filters=("huber-kf",), epochs=30)
    names = res.data.state_names
    assert tuple(n.removeprefix("cb_") for n in names if n.startswith("cb_")) == clocks
    assert np.isfinite(_metric(res, "huber-kf", "rmse_hpos"))


def test_unknown_codes_and_unassignable_ids_are_refused(tmp_path):
    d = _slice(tmp_path, "Bad_Code", edit=lambda p: " ".join([*p[:8], "3", *p[9:]]))
    with pytest.raises(NavlabError, match=r"system code 3, not one of 1 GPS, 2 SBAS, 4 GLONASS"):
        load_pseudoranges(d)
    d = _slice(tmp_path, "No_System", edit=lambda p: " ".join(["range3", *p[1:7], "150", *p[9:]]))
    with pytest.raises(NavlabError, match=r"satellite id 150 .* cannot be assigned"):
        load_pseudoranges(d)
    d = _convert(tmp_path / "csv")  # an unknown RINEX letter was "'X', not a number"
    f = d / "pseudoranges.csv"
    f.write_text(f.read_text().replace(",G,", ",X,", 1))
    with pytest.raises(NavlabError, match=r"\(system\) is 'X'; give a RINEX letter \(G, R, E, C, J, S\)"):
        load_pseudoranges(d)


def test_no_odometry_no_truth_and_missing_optional_columns(tmp_path):
    d = _convert(tmp_path / "bare", "--no-odometry", "--no-truth")
    import pandas as pd

    pr = pd.read_csv(d / "pseudoranges.csv")
    pr.drop(columns=["var_m2", "elevation_deg", "cn0_dbhz"]).to_csv(d / "pseudoranges.csv", index=False)
    res = _run(d, filters=("wls", "ekf"))
    notes = " ".join(res.data.extras["notes"])
    assert "constant velocity" in notes and "elevations computed" in notes and "'elevation' used" in notes
    assert not res.data.has_truth and "|d|" not in res.data.channel_names
    assert np.isfinite(res.runs["ekf"].x[0, -1, :3]).all()


def test_the_berlin_map_height_is_not_used_for_other_data(tmp_path):
    d = _slice(tmp_path)
    spec = ExperimentSpec(
        scenario="smartloc-berlin", filters=("wls",), runs=1, scenario_params={"data_dir": str(d)}
    )
    with pytest.raises(NavlabError, match="map height of Berlin's Potsdamer Platz"):
        run_experiment(spec)
    with pytest.raises(NavlabError, match="needs a folder"):
        run_experiment(ExperimentSpec(scenario="own-pseudoranges", filters=("wls",), runs=1))

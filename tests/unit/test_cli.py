"""The command line: listing, running, formats and one-line errors."""

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from navlab.cli import main


def run_cli(capsys, *argv):
    rc = main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def test_list_filters_and_scenarios(capsys):
    rc, out, _ = run_cli(capsys, "list", "filters")
    assert rc == 0
    for key in ("kf", "oracle-kf", "chi2-kf"):
        assert key in out
    rc, out, _ = run_cli(capsys, "list", "scenarios", "--format", "json")
    assert rc == 0
    assert "cv2d" in {row["key"] for row in json.loads(out)}


def test_run_json_has_tidy_rows(capsys):
    rc, out, _ = run_cli(
        capsys,
        "run",
        "--scenario",
        "cv2d",
        "--filters",
        "kf,oracle-kf,chi2-kf",
        "--runs",
        "20",
        "--seed",
        "1",
        "--epochs",
        "50",
        "--format",
        "json",
    )
    assert rc == 0
    rows = json.loads(out)
    assert all({"filter", "metric", "value"} <= set(r) for r in rows)
    got = {(r["filter"], r["metric"]): r["value"] for r in rows}
    for f in ("kf", "oracle-kf", "chi2-kf"):
        assert got[(f, "rmse_pos")] > 0
        assert got[(f, "rmse_vel")] > 0
    assert got[("oracle-kf", "rmse_pos")] <= got[("kf", "rmse_pos")]
    # every headline row carries its interval; rows without one carry empty (null) bounds
    by = {(r["filter"], r["metric"]): r for r in rows}
    r = by[("kf", "rmse_pos")]
    assert r["ci_lo"] < r["value"] < r["ci_hi"] and r["ci_method"] == "bootstrap"
    assert by[("kf", "diverged")]["ci_lo"] is None and by[("kf", "runs")]["ci_hi"] is None


def test_compare_to_adds_paired_rows_and_a_verdict_column(capsys):
    argv = ["run", "--filters", "kf,oracle-kf,chi2-kf", "--runs", "30", "--epochs", "40"]
    rc, out, _ = run_cli(capsys, *argv, "--compare-to", "kf", "--format", "json")
    assert rc == 0
    diff = [r for r in json.loads(out) if r["metric"] == "rmse_pos_diff"]
    assert {r["filter"] for r in diff} == {"oracle-kf", "chi2-kf"}
    assert all(r["vs"] == "kf" and 0 <= r["p_value"] <= 1 and r["ci_lo"] <= r["ci_hi"] for r in diff)
    oracle = next(r for r in diff if r["filter"] == "oracle-kf")
    assert oracle["verdict"] == "better" and oracle["value"] < 0
    rc, out, _ = run_cli(capsys, *argv, "--compare-to", "kf")
    assert rc == 0
    assert "vs KF" in out and "better (Δ -" in out and "reference" in out
    assert "nan" not in out.lower() and "None" not in out  # empty cells, reasons in footnotes
    assert "Analysis window: epochs 1–40" in out and "Divergence:" in out
    rc, _, err = run_cli(capsys, *argv, "--compare-to", "hakf")
    assert rc == 2 and "--compare-to hakf" in err


def test_config_file_and_overrides(tmp_path, capsys):
    spec = tmp_path / "spec.json"
    rc, _, _ = run_cli(
        capsys,
        "run",
        "--filters",
        "kf",
        "--runs",
        "5",
        "--epochs",
        "20",
        "--contamination",
        "0.2",
        "--save-spec",
        str(spec),
        "--format",
        "csv",
    )
    assert rc == 0
    saved = json.loads(spec.read_text())
    assert saved["contamination"] == 0.2
    rc, out1, _ = run_cli(capsys, "run", "--config", str(spec), "--format", "csv")
    rc2, out2, _ = run_cli(capsys, "run", "--config", str(spec), "--runs", "6", "--format", "csv")
    assert rc == rc2 == 0
    runs = lambda text: pd.read_csv(io.StringIO(text)).query("metric == 'runs'").value.iloc[0]  # noqa: E731
    assert runs(out1) == 5
    assert runs(out2) == 6


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["run", "--runs", "abc"], "--runs"),
        (["run", "--runs", "0"], "runs"),
        (["run", "--filters", "kf,nope"], "unknown filter"),
        (["run", "--scenario", "moon"], "unknown scenario"),
        (["run", "--contamination", "7"], "contamination"),
        (["run", "--config", "/nonexistent/spec.json"], "cannot read"),
        (["run", "--set", "oops"], "GROUP.NAME=VALUE"),
        (["list", "bananas"], "invalid choice"),
        (["reproduce", "nobody"], "unknown reproduction"),
        (["frobnicate"], "invalid choice"),
    ],
)
def test_bad_arguments_give_one_line(capsys, argv, words):
    rc, _out, err = run_cli(capsys, *argv)
    assert rc == 2
    assert words in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_broken_config_file(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"runs": 5, "filters": ["kf"')
    rc, _, err = run_cli(capsys, "run", "--config", str(bad))
    assert rc == 2
    assert "JSON" in err or "json" in err


@pytest.mark.parametrize(("env", "want"), [(None, False), ("1", True)])
def test_module_entry_point_turns_numpy_huge_pages_off_unless_asked(env, want):
    """python -m navlab sets NUMPY_MADVISE_HUGEPAGE=0 before numpy is imported (see
    navlab/__main__.py); an explicit setting wins."""
    code = (
        "import runpy, sys\n"
        "sys.argv = ['navlab', 'list', 'outliers']\n"
        "try:\n    runpy.run_module('navlab', run_name='__main__')\nexcept SystemExit:\n    pass\n"
        "from numpy._core import multiarray as m\n"
        "print('HUGEPAGE', m._get_madvise_hugepage())\n"
    )
    environ = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if env is not None:
        environ["NUMPY_MADVISE_HUGEPAGE"] = env
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=environ)
    assert p.returncode == 0, p.stderr
    assert f"HUGEPAGE {want}" in p.stdout


def test_module_entry_point():
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "navlab",
            "run",
            "--runs",
            "3",
            "--epochs",
            "10",
            "--filters",
            "kf",
            "--format",
            "csv",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("filter,label,metric,value,unit")


def test_app_runs_in_the_apps_folder_so_streamlit_reads_navlabs_config(tmp_path, monkeypatch):
    import os

    from navlab import cli

    seen = {}
    monkeypatch.setattr(cli.os, "execv", lambda exe, cmd: seen.update(cwd=os.getcwd(), cmd=cmd))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("NAVLAB_DATA", "data")
    cli._app([])
    root = Path(cli.__file__).resolve().parent.parent
    assert Path(seen["cwd"]) == root and (root / ".streamlit" / "config.toml").is_file()
    assert os.environ["NAVLAB_DATA"] == str(tmp_path / "data")  # still the folder the user meant


def test_app_passes_streamlit_flags_and_stopping_it_stops_the_server(tmp_path):
    import os
    import signal
    import socket
    import time
    import urllib.error
    import urllib.request

    from navlab.cli import app_command

    assert app_command(["--server.port", "8611"])[-2:] == ["--server.port", "8611"]
    assert app_command(["--", "--server.port", "8611"])[-2:] == ["--server.port", "8611"]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    args = ["--server.port", str(port), "--server.address", "127.0.0.1", "--server.headless", "true"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "navlab", "app", *args, "--browser.gatherUsageStats", "false"],
        cwd=tmp_path,  # started from elsewhere
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "PYTHONPATH": str(__import__("pathlib").Path(__file__).resolve().parents[2])},
    )
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            try:
                if opener.open(f"http://127.0.0.1:{port}/_stcore/health", timeout=2).read() == b"ok":
                    break
            except OSError:
                time.sleep(0.3)
        else:
            pytest.fail("navlab app did not serve on the port it was given")
        proc.send_signal(signal.SIGTERM)  # the navlab process IS the server (exec)
        proc.wait(timeout=30)
        with pytest.raises(urllib.error.URLError, match="refused"):
            opener.open(f"http://127.0.0.1:{port}/_stcore/health", timeout=2)
    finally:
        if proc.poll() is None:
            proc.kill()


@pytest.mark.parametrize(
    ("argv", "runs"),
    [
        (["run", "--scenario", "smartloc-berlin"], 1),  # its runs are all alike: one is enough
        (["run", "--scenario", "cv2d"], 100),
        (["run"], 100),
        (["run", "--scenario", "smartloc-berlin", "--runs", "3"], 3),
        (["tune", "--scenario", "smartloc-berlin", "--filters", "skew-t-kf"], 1),
    ],
)
def test_runs_default_to_the_scenarios_own(argv, runs):
    from navlab.cli import _spec_from_args, build_parser

    assert _spec_from_args(build_parser().parse_args(argv)).runs == runs


def test_tuning_a_recording_whose_runs_are_alike_uses_one_training_run():
    from navlab import tune as TU
    from navlab.experiment import ExperimentSpec

    spec = ExperimentSpec(scenario="smartloc-berlin", filters=("skew-t-kf",), runs=1)
    assert TU.setup(spec).schedule.runs == (1,)
    assert TU.setup(spec.replace(scenario="cv2d", runs=100)).schedule.runs[-1] == TU.DEFAULT_TRAIN_RUNS


def test_nlpd_is_offered_as_an_objective_only_where_a_filter_states_its_predictive_density():
    from navlab import tune as TU
    from navlab.experiment import ExperimentSpec

    assert TU.truth_free_objectives(ExperimentSpec(filters=("kf", "huber-kf"))) == []
    assert TU.truth_free_objectives(ExperimentSpec(filters=("kf", "skew-t-kf"))) == ["nlpd"]


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_is_taken_before_or_after_the_subcommand(capsys, monkeypatch, where):
    """Issue 22 item 7: the message says 'rerun with --debug', but `navlab run … --debug` was refused."""
    import navlab.experiment

    def boom(*a, **k):
        raise RuntimeError("boom")

    monkeypatch.setattr(navlab.experiment, "run_experiment", boom)
    argv = ["run", "--filters", "kf", "--runs", "2", "--epochs", "5"]
    rc, _, err = run_cli(capsys, *argv)
    assert rc == 1 and "internal error: RuntimeError: boom (rerun with --debug)" in err
    with pytest.raises(RuntimeError, match="boom"):
        main(["--debug", *argv] if where == "before" else [*argv, "--debug"])


def test_a_run_off_a_terminal_prints_progress_lines_from_within_its_one_chunk(capsys, monkeypatch):
    """#22 item 6: a long `navlab run` in a log or a pipe shows it is alive (a line every
    EVERY_S seconds, also inside its single chunk), not only when it ends."""
    from navlab import cli

    monkeypatch.setattr(cli._Progress, "EVERY_S", 0.0)  # a line at every epoch
    rc, _, err = run_cli(capsys, "run", "--filters", "kf", "--runs", "4", "--epochs", "20")
    assert rc == 0
    lines = [ln for ln in err.splitlines() if ln.startswith("navlab: ") and " runs after " in ln]
    assert len(lines) >= 10  # one chunk of 20 epochs
    assert lines[0].startswith("navlab: 5 % of 4 runs after")  # 1/20 of the epochs ("0.2/4 runs" read oddly)
    assert lines[-1].startswith("navlab: 4/4 runs after")


@pytest.fixture
def no_compute(monkeypatch):
    """Computing is a failure of the test: the bad input must be refused before it."""

    def refuse(*_a, **_k):
        raise AssertionError("computed before refusing the bad input")

    for name in ("run_experiment", "run_summary"):
        monkeypatch.setattr(f"navlab.experiment.{name}", refuse)
    monkeypatch.setattr("navlab.reproduce.engine.Reproduction.evaluate", refuse)
    monkeypatch.setattr("navlab.tune.tune", refuse)


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["run", "--out", "{tmp}/missing/out.txt"], "missing does not exist; create it"),
        (["run", "--out", "{tmp}/afile/out.txt"], "is a file, not a folder"),
        (["run", "--out", "{tmp}"], "that is a folder; give a file name"),
        (["run", "--save-results", "{tmp}/missing/r.nc"], "--save-results"),
        (["run", "--save-spec", "{tmp}/missing/s.json"], "--save-spec"),
        (["run", "--summary", "--save-results", "{tmp}/r.nc"], "which --summary drops"),
        (["run", "--compare-to", "nope"], "not one of the filters run"),
        (["run", "--out", "{tmp}/r.nc", "--save-results", "{tmp}/r.nc"], "name the same file"),
        (["reproduce", "hakf", "--seeds", "1", "--runs", "2", "--outdir", "{tmp}/afile/x"], "not a folder"),
        (["tune", "--outdir", "{tmp}/afile"], "that is a file; give a folder"),
        (["sweep", "--param", "outliers.contamination", "--values", "0,0.1", "--out", "{tmp}/no/x"], "--out"),
    ],
)
def test_an_output_that_cannot_be_written_is_refused_before_computing(
    tmp_path, capsys, no_compute, argv, words
):
    (tmp_path / "afile").write_text("x")
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    rc, _out, err = run_cli(capsys, *argv, "-q")
    assert rc == 2, err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--set", "outliers.contamination=0.1", "--contamination", "0.3"], "give it once"),
        (["--set", "scenario.epochs=20", "--epochs", "10"], "give it once"),
        (["--set", ".=3"], "name the group and the parameter"),
        (["--set", "kf.=3"], "name the group and the parameter"),
    ],
)
def test_contradictory_or_empty_settings_are_refused(capsys, argv, words):
    rc, _out, err = run_cli(capsys, "run", "--runs", "2", *argv)
    assert rc == 2 and words in err and err.count("\n") == 1


def test_a_flag_overrides_the_configurations_value_of_the_same_parameter(tmp_path, capsys):
    cfg = tmp_path / "spec.json"
    cfg.write_text(json.dumps({"runs": 2.0, "epochs": 10, "outlier_params": {"contamination": 0.1}}))
    saved = tmp_path / "saved.json"
    rc, _out, err = run_cli(
        capsys, "run", "--config", str(cfg), "--contamination", "0.3", "--save-spec", str(saved), "-q"
    )
    assert rc == 0, err  # runs 2.0 is 2 runs
    spec = json.loads(saved.read_text())
    assert (
        spec["contamination"] == 0.3 and "contamination" not in spec["outlier_params"] and spec["runs"] == 2
    )


def test_reproduce_names_seeds_times_runs_when_too_many(capsys):
    rc, _out, err = run_cli(capsys, "reproduce", "hakf", "--seeds", "1000000000", "-q")
    assert rc == 2 and "--seeds 1000000000 × --runs" in err and "use fewer seeds or runs" in err


def test_a_sweep_range_of_a_billion_values_is_refused_before_it_is_made(capsys):
    """0:0.3:1000000000 made the billion values first (23 GB, killed)."""
    rc, _out, err = run_cli(
        capsys, "sweep", "--param", "outliers.contamination", "--values", "0:0.3:1000000000"
    )
    assert rc == 2 and "1000000000 values; a sweep takes at most 15" in err
    rc, _out, err = run_cli(capsys, "sweep", "--param", "noise.factor", "--values", "0:1:3:log")
    assert rc == 2 and "positive lower end" in err  # was swallowed by the generic message


def test_tune_seeds_beyond_the_seed_range_are_named(capsys):
    rc, _out, err = run_cli(capsys, "tune", "--train-seeds", "99999999999999999999", "-q")
    assert rc == 2 and "--train-seeds takes comma-separated whole numbers in [0, " in err


def test_check_filter_that_checked_nothing_does_not_say_passed(capsys, monkeypatch, tmp_path):
    """With the recording missing, 'kf: passed — 0 passed, 0 failed, 11 skipped' exited 0."""
    from navlab import contracts

    monkeypatch.setenv("NAVLAB_DATA", str(tmp_path / "nowhere"))
    # the contract batches are cached per process: another test may have loaded the recording
    for cached in (contracts.scenario_data, contracts.cached_run):
        cached.cache_clear()
    rc, out, err = run_cli(capsys, "check-filter", "kf", "--scenario", "drive0708")
    for cached in (contracts.scenario_data, contracts.cached_run):
        cached.cache_clear()  # the next test sees the recording again
    assert rc == 2 and "passed" not in out and "kf: nothing checked — all" in err and "not found under" in out


def test_an_unwritable_bench_folder_is_refused_before_the_bench(capsys, monkeypatch, tmp_path):
    from navlab import bench as BN

    monkeypatch.setattr(BN, "run", lambda *a, **k: (_ for _ in ()).throw(AssertionError("ran the bench")))
    (tmp_path / "afile").write_text("x")
    monkeypatch.setenv("NAVLAB_BENCH_DIR", str(tmp_path / "afile"))
    rc, _out, err = run_cli(
        capsys, "bench", "--suite", "tiny", "--filters", "kf", "--scheduler", "serial", "-q"
    )
    assert rc == 2 and "the bench folder" in err and "that is a file; give a folder" in err


def test_sweep_ranges_are_the_values_a_user_types():
    """0:0.3:7 gave linspace's 0.049999999999999996 and 0.09999999999999999 in every table."""
    from navlab.cli import _floats

    assert _floats("0:0.3:7", "--values") == [0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3]
    assert _floats("0.1:1000:5:log", "--values") == [0.1, 1.0, 10.0, 100.0, 1000.0]


def test_compare_to_with_one_other_filter_says_p_not_holm_across_one(capsys):
    rc, out, _err = run_cli(capsys, "run", "--filters", "kf,huber-kf", "--compare-to", "kf", "--runs", "12")
    assert rc == 0 and "better/worse when p < 0.05, else" in out and "across the 1 other" not in out

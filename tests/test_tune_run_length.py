"""tune's run length: the model's [simulation] duration, else one from the plant; runs
too short for a verdict refused; runs shorter than the model's logs warned about.

The first-time user's room (1 s samples, 60-sample window, no duration) was tuned on the
old default 10 s runs: 10 samples, the RMS window never filled, and R1 came out at
0.0653 K, which 4 of 6 healthy 3600 s logs exceeded.
"""

from pathlib import Path

import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.model.model_file import load_model
from fdigen.tune import TuneSettings, tune
from fdigen.sim.run_length import default_duration
from fdigen.tune.run_length import check_run_duration

DATA = Path(__file__).parent / "data" / "newuser"


def test_default_run_length_comes_from_the_model_file_or_the_plant():
    room = load_model(str(DATA / "room.toml"))
    seconds, why = default_duration(room)
    # tau = C/G = 5e4/50 = 1000 s; five of them (360 s of six windows is shorter)
    assert seconds == pytest.approx(5000.0)
    assert "slowest time constant 1e+03 s" in why
    tanks = load_model(str(DATA / "twotank_cm.toml"))
    assert default_duration(tanks) == (600.0, "the model's [simulation] duration")


def test_a_run_without_a_full_rms_window_is_refused_and_a_short_one_warned(tmp_path):
    res = CliRunner().invoke(main, ["tune", "--model", str(DATA / "room.toml"),
                                    "--duration", "110", "--runs", "2"])
    assert res.exit_code == 2
    assert "at least 120 s" in res.output and "no verdict" in res.output
    tanks = load_model(str(DATA / "twotank_cm.toml"))
    assert check_run_duration(tanks, 600.0, 0.1, 50) == []
    [note] = check_run_duration(tanks, 10.0, 0.1, 50)
    assert "shorter than the model's [simulation] duration 600 s" in note


def test_tune_runs_last_the_default_length():
    rep = tune(str(DATA / "room.toml"), TuneSettings(runs=2, validation_runs=0, faults=()),
               scheduler="synchronous", progress=False)
    assert rep["settings"]["duration"] == pytest.approx(5000.0)
    assert rep["false_alarm"]["run_duration"] == pytest.approx(5000.0)
    assert {r["samples"] for r in rep["runs"]["healthy"]} == {5000}
    # the uncertain G (+-10 %) shifts the steady state by up to about 1 K over 5000 s:
    # far above the 0.05 K sensor noise the 10-sample runs saw
    assert max(r["max_rms"]["R1"] for r in rep["runs"]["healthy"]) > 0.2

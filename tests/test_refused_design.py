"""A design ``fdigen commission`` refused is marked in its file, and every command that
runs it says so first.

A user's pump rig (2026-11-28): commission refused the design (thresholds 14 times the
current sensor's span, no fault detected in its campaign) but wrote the commissioned
file without a mark; ``detect`` ran it on the logs of both faults and said "diagnosis:
none (no flag raised)", in silence.
"""

import json
import shutil

from click.testing import CliRunner

from fdigen.cli import main
from fdigen.commission.model_text import mark_refusal
from fdigen.model.model_file import load_model


def test_a_refused_design_is_said_to_be_refused_by_detect_build_and_inspect(tmp_path,
                                                                            monkeypatch):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "dc_motor_commissioned.toml"
    shutil.copy(load_model("dc_motor").source, path)
    failures = ["threshold R1 = 110 is 13.8 times the span of sensor i_meas",
                "fault load detected in 0 of 20 runs at its test size"]
    mark_refusal(path, {"usable": False, "failures": failures})
    model = load_model(str(path))
    assert "13.8 times the span" in model.fdi["refused"]
    runner = CliRunner()
    log = tmp_path / "healthy.csv"
    res = runner.invoke(main, ["simulate", "--model", str(path), "--duration", "2",
                               "-o", str(log)])
    assert res.exit_code == 0, res.output
    res = runner.invoke(main, ["detect", str(log), "--model", str(path)])
    assert res.exit_code == 0, res.output
    assert "REFUSED by `fdigen commission`" in res.stderr
    assert "13.8 times the span" in res.stderr
    res = runner.invoke(main, ["detect", str(log), "--model", str(path), "--json"])
    assert "13.8 times the span" in json.loads(res.stdout)["design_refused"]
    for cmd in (["inspect", "--model", str(path)], ["build", "--model", str(path)]):
        res = runner.invoke(main, cmd)
        assert res.exit_code == 0, res.output
        assert "REFUSED by `fdigen commission`" in res.stderr, cmd
    # a later commission that finds the design usable takes the mark out
    mark_refusal(path, {"usable": True, "failures": []})
    assert "refused" not in load_model(str(path)).fdi
    res = runner.invoke(main, ["detect", str(log), "--model", str(path), "--json"])
    assert json.loads(res.stdout)["design_refused"] is None


def test_the_mark_is_text_never_code(tmp_path):
    """The failures name residuals and sensors from the user's file: the mark is a TOML
    string (quotes and newlines escaped), read back as text."""
    path = tmp_path / "m.toml"
    shutil.copy(load_model("dc_motor").source, path)
    nasty = 'threshold "R1" = 1\n[fdi.thresholds]\nR1 = 0 # injected'
    mark_refusal(path, {"usable": False, "failures": [nasty]})
    model = load_model(str(path))
    assert model.fdi["refused"].startswith('threshold "R1" = 1')
    assert "\n" not in model.fdi["refused"]
    assert model.fdi["thresholds"] == load_model("dc_motor").fdi["thresholds"]


def test_tune_write_marks_thresholds_that_failed_their_validation(tmp_path, monkeypatch):
    """tune --write wrote thresholds that raised flags on 2 of 3 of its own validation runs
    (a user's furnace) with a "FAILED" comment in a header only; detect used them in
    silence. Now the file carries ``[fdi] refused`` and build says so first (a target of
    50 % false alarms per run makes the validation fail on purpose)."""
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "motor.toml"
    # and a load torque of 1e-9 N m, below any threshold: a design blind to a declared
    # fault at its test size is refused too (a user's conveyor, its shunt offset "never
    # detected", was written unrefused, where `fdigen commission` refuses the same)
    text = open(load_model("dc_motor").source).read()
    assert "test_size = 0.01\n" in text
    path.write_text(text.replace("test_size = 0.01\n", "test_size = 1e-9\n"))
    res = CliRunner().invoke(main, [
        "tune", "--model", str(path), "--runs", "4", "--duration", "1",
        "--validation-runs", "6", "--fault-sizes", "1", "--fault-starts", "1",
        "--horizon-runs", "0", "--false-alarm-rate", "0.5", "--margin", "1",
        "--tolerance", "0", "--write", "--report", str(tmp_path / "tune.json")])
    assert res.exit_code == 0, res.output
    rep = json.loads((tmp_path / "tune.json").read_text())
    # what was written is said as written (the refusal's warning had taken the place of
    # the `else` of --write: "--write would change" printed after the write)
    assert "wrote the tuned thresholds to" in res.stdout
    assert "--write would change" not in res.output
    assert "these thresholds FAILED their checks, and --write marked" in res.stderr
    fa = rep["false_alarm"]
    assert fa["validation_false_alarms"] > 0
    mark = load_model(str(path)).fdi["refused"]
    assert mark == rep["refused"]
    assert mark.startswith("fdigen tune: ")
    assert f"{fa['validation_false_alarms']} of 6 fresh healthy validation runs" in mark
    load = rep["faults"]["load"]
    assert load["detected"] == 0 and load["runs"] > 0
    assert f"load (0 of {load['runs']})" in mark
    seen = [n for n, f in rep["faults"].items() if f["detected"]]
    assert seen and not any(f"{n} (0 of" in mark for n in seen)   # only the blind one
    res = CliRunner().invoke(main, ["build", "--model", str(path)])
    assert res.exit_code == 0, res.output
    assert "REFUSED by `fdigen tune`" in res.stderr


def test_a_passing_tune_lifts_its_own_mark_and_never_a_commissions():
    from fdigen.tune.refusal import KEEP, refusal_value
    from fdigen.tune.model_update import updated_model_text

    good = {"false_alarm": {"validation_false_alarms": 0, "validation_runs": 10},
            "faults": {"leak": {"runs": 4, "false_alarms_before_onset": 0}}}
    assert refusal_value(good, "fdigen tune: 3 of 10 fresh healthy ...") is None
    assert refusal_value(good, "threshold R1 = 110 is 13.8 times the span") is KEEP
    assert refusal_value(good, "") is KEEP
    bad = {**good, "thresholds_beyond_span": {
        "R1": {"threshold": 2.0, "span": 1.5, "output": "h1"}}}
    assert "R1 = 2 against h1's 1.5" in refusal_value(bad, "")
    from pathlib import Path

    text = Path(load_model("dc_motor").source).read_text()
    marked = updated_model_text(text, {}, fdi_values={"refused": "fdigen tune: x."})
    assert 'refused = "fdigen tune: x."' in marked
    assert updated_model_text(marked, {}, fdi_values={"refused": None}) == text


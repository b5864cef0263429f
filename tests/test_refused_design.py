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

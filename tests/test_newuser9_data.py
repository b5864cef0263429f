"""A user's measured data (tests/data/newuser9): two tanks in cm through 4-20 mA
transmitters, sampled at 1 s, simulated by the user's own code (``rig1.py``, not fdigen's)
with a leak out of tank 2 the model lacks, a pump gain 5 % and an outlet 4 % off the
datasheet, quantised readings and a slow pump-flow disturbance.

Two findings of that user, each on the CLI's default path:

* ``discover`` wrote and built the augmented model, then ended with exit 2 because the
  model *as given* lacked a threshold for a derived residual (a model not tuned yet);
* the commissioned design (``realign_noise_scale = 0.1``) isolated a transmitter offset
  at 304 s and then escalated it to ``unexplained`` / ``safety_stop`` at 351 s: commission
  wrote no validity horizons, so a frozen parallel model drifting after the first flag
  contradicted the isolated sensor fault.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser9"


def test_discover_on_a_model_not_tuned_yet(tmp_path):
    res = CliRunner().invoke(main, ["discover", str(DATA / "tanks_healthy.csv"), "--model",
                                    str(DATA / "tanks_noR3.toml"), "--out",
                                    str(tmp_path / "d"), "--json"])
    assert res.exit_code == 0, (res.output[-2000:], res.stderr[-2000:])
    out = json.loads(res.stdout)
    assert any(w.startswith("the model file has no threshold for R3") for w in out["warnings"])
    # the before/after comparison is there, for the residual the file lacked too
    assert "R3" in out["fdi_before"] and "R3" in out["fdi_after"]
    assert out["effects"] and out["effects"][0].startswith("leak")


def test_commissioned_tanks_keep_an_isolated_transmitter_offset(tmp_path):
    out = tmp_path / "c"
    res = CliRunner().invoke(main, ["commission", str(DATA / "tanks_healthy.csv"), "--model",
                                    str(DATA / "tanks_rn.toml"), "--out", str(out)])
    # the design is refused for other faults (a tank-1 leak the plant hides): exit 1
    assert res.exit_code in (0, 1), (res.output[-2000:], res.stderr[-2000:])
    commissioned = out / "lab_tanks_commissioned.toml"
    doc = tomllib.loads(commissioned.read_text())
    horizons = doc["fdi"]["frozen_horizon"]
    assert horizons and all(v > 0 for v in horizons.values())
    # each uncertain parameter carries the spread the commissioning used, so that a later
    # `fdigen tune` on this file does not spread them +-10 % again (the user's finding),
    # and tune's advice no longer sends the commissioned model back to commission
    report = json.loads((out / "commission.json").read_text())
    own = report["campaign"]["tolerances"]
    for name, spec in doc["parameters"].items():
        if spec.get("uncertain"):
            expected = own.get(name, report["campaign"]["tolerance"])
            assert expected <= spec["tolerance"] <= expected * 1.01, name  # 3 digits, up
    from fdigen.model.model_file import load_model
    from fdigen.tune.parameter_masking import calibrated_spread, masking_text

    assert calibrated_spread(load_model(commissioned))
    entry = {"masked": False, "remainder": 11.0, "effect": 20.0, "parameters": {}}
    assert "fdigen commission" not in masking_text("leak1", "step", "2", entry, True)
    assert "fdigen commission" in masking_text("leak1", "step", "2", entry, False)
    det = CliRunner().invoke(main, ["detect", "--model", str(commissioned),
                                    str(DATA / "tanks_lt2_offset.csv"), "--json"])
    assert det.exit_code == 0, det.output
    diag = json.loads(det.stdout)["diagnosis"]
    # the offset starts at 300 s (the user's truth file)
    assert diag["fault"] == "transmitter2" and diag["action"] == "none", diag
    assert 300.0 <= diag["t_isolated"] <= 330.0


def test_a_single_blind_parameter_is_not_called_a_hidden_states_scale(tmp_path):
    """The user's heatsink (die temperature hidden, 300 samples at 0.5 s) on a log with a
    thermistor offset from 75 s: an overflow of the die temperature was taken, its
    coefficient at its bound 0, and the warning read "scaling them as cof_Td^+1 ... the
    scale of the hidden state Td". An effect its search bound decides is now refused
    (fit_checks.effect_at_bound), and one parameter alone is said as what it is."""
    from types import SimpleNamespace

    from fdigen.discover.output_loop import identifiability
    from fdigen.model.model_file import load_model

    res = CliRunner().invoke(main, ["discover", str(DATA / "heat_ts_offset.csv"), "--model",
                                    str(DATA / "thermal.toml"), "--out", str(tmp_path / "d"),
                                    "--no-build", "--no-fdi", "--json"])
    assert res.exit_code == 0, res.output[-2000:]
    out = json.loads(res.stdout)
    assert "overflow_Td" not in out["effects"]
    refused = [c for c in out["candidates"] if c["effect"] == "overflow_Td"]
    assert refused and all("search bound" in c.get("refused", "") for c in refused)
    for w in out["warnings"]:
        assert "+1 (times a common factor)" not in w, w
    # the wording of a single blind parameter, on the fit the user had
    model = load_model(str(DATA / "thermal.toml"))
    fit = SimpleNamespace(null_directions=[{"cof_Td": 1.0}], held={}, J=None, free=[],
                          params={"cof_Td": 8.8e-9}, std={})
    _, warnings = identifiability(model, fit, {})
    assert warnings[0].startswith("cof_Td = ") and "does not move any output" in warnings[0]
    assert "hidden state" not in warnings[0]

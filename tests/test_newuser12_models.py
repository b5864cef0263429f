"""Plants a user wrote from the README alone (tests/data/newuser12): a Li-ion cell whose
resistance fault is written inside a definition the terminal voltage reads, and the same
cell with the fault written as terms; and the commission verdict on what that user's
campaigns showed (wrong isolations, a step missed where its ramp was seen)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fdigen.backends.reference import ReferenceFdi
from fdigen.design.fdi_design import fdi_design
from fdigen.model.model_file import load_model
from fdigen.sim.plant import FaultEvent, simulate
from fdigen.tune.model_update import fill_missing_thresholds

DATA = Path(__file__).parent / "data" / "newuser12"


@pytest.fixture(scope="module")
def cells():
    out = []
    for name in ("battery_orig.toml", "bat_terms.toml"):
        model, _ = fill_missing_thresholds(load_model(str(DATA / name)), 1e3)
        out.append((model, fdi_design(model)))
    return out


def test_a_fault_in_a_definition_an_output_reads_has_the_terms_spelling_s_design(cells):
    """R0e = R0*(1 + r_incr) in the terminal voltage: the definition spelling derived a
    Kalman residual on the voltage whose r_incr entry was 0 (inspect itself called it a
    defect), and tune isolated the resistance rise as the voltage sensor. Same physics,
    same table, same residuals."""
    (m0, d0), (m1, d1) = cells
    assert d0.residual_names == d1.residual_names
    assert {f: sorted(r) for f, r in d0.signature_table.items()} == \
        {f: sorted(r) for f, r in d1.signature_table.items()}
    # the resistance fault's row is read by the voltage's residuals
    assert "RV" in d0.signature_table["r_incr"]
    for extra in d0.extra_residuals:          # none may be blind to it and see the sensor
        name = extra["residual"]
        if "v_offset" in d0.signature_table and name in d0.signature_table["v_offset"]:
            assert name in d0.signature_table["r_incr"], name


def test_both_spellings_simulate_and_compute_the_same(cells):
    (m0, d0), (m1, d1) = cells
    logs = [simulate(m, 600.0, faults=(FaultEvent("r_incr", 200.0, 0.5),), noise=False)
            for m in (m0, m1)]
    assert np.allclose(logs[0].y, logs[1].y, rtol=1e-10, atol=1e-12)
    outs = [ReferenceFdi(d).run(logs[0].u, logs[0].y) for d in (d0, d1)]
    scale = np.maximum(np.max(np.abs(outs[0]["r"]), axis=0), 1e-12)
    assert np.max(np.abs(outs[0]["r"] - outs[1]["r"]) / scale) < 1e-9


def test_commission_verdict_refuses_wrong_isolations_and_names_a_missed_step():
    from fdigen.commission.verdict import design_verdict

    model = load_model(str(DATA / "battery_orig.toml"))
    y = np.zeros((10, 2))
    wrong = {"r_incr": {"runs": 3, "false_isolations": 3,
                        "by_size": [{"factor": 1.0, "detected": 1, "runs": 1,
                                     "isolated_correct": 0}]}}
    v = design_verdict(model, {}, wrong, y, 0.1)
    assert not v["usable"]
    assert "r_incr isolated as another class in 3 of 3 runs" in v["failures"][0]
    # with the campaign's classes and sizes (round 52: "which class?")
    named = {"r_incr": {**wrong["r_incr"], "isolated_as": ["voltage_sensor"],
                        "by_size": [{"factor": 1.0, "detected": 1, "runs": 1,
                                     "isolated_correct": 0, "false_isolations": 1},
                                    {"factor": 2.0, "kind": "ramp", "detected": 1, "runs": 1,
                                     "isolated_correct": 0, "false_isolations": 1}]}}
    assert ("r_incr isolated as voltage_sensor in 3 of 3 runs (at 1 x, 2 x (ramp) its test "
            "size)") in design_verdict(model, {}, named, y, 0.1)["failures"][0]
    step_missed = {"enc": {"runs": 2, "by_size": [
        {"factor": 1.0, "kind": "step", "detected": 0, "runs": 1, "isolated_correct": 0},
        {"factor": 1.0, "kind": "ramp", "detected": 1, "runs": 1, "isolated_correct": 0}]}}
    lims = design_verdict(model, {}, step_missed, y, 0.1)["limits"]
    assert any("its step at the test size was missed in every run (step 0 of 1, ramp 1 of 1)"
               in lim for lim in lims), lims


def test_simulate_warns_when_a_healthy_run_leaves_the_declared_ranges(tmp_path):
    """The CSTR's temperature reference written in K for a sensor in degC: the loop runs
    the reactor to its 450 K limit and simulate said only "wrote 1800 samples". The same
    reactor with its reference in degC stays inside its ranges and gets no warning."""
    from click.testing import CliRunner

    from fdigen.cli import main

    runner = CliRunner()
    bad = runner.invoke(main, ["simulate", "--model", str(DATA / "cstr_ref_in_K.toml"),
                               "-o", str(tmp_path / "k.csv")])
    assert bad.exit_code == 0, bad.output
    text = " ".join(bad.output.split())
    assert "leaves the declared ranges" in text and "T " in text and "against [312, 336]" in text
    good = runner.invoke(main, ["simulate", "--model", str(DATA / "cstr.toml"),
                                "-o", str(tmp_path / "c.csv")])
    assert good.exit_code == 0 and "leaves the declared ranges" not in good.output


def test_a_caret_is_refused_naming_the_power_operator():
    from fdigen.errors import ModelFileError
    from fdigen.model.model_file import parse_model_text

    text = (DATA / "battery_orig.toml").read_text(encoding="utf-8").replace(
        "a2*soc**2", "a2*soc^2")
    with pytest.raises(ModelFileError, match=r"'\^' is not a power here: write a\*\*2"):
        parse_model_text(text, "bat_pow.toml")


def test_a_calibration_of_the_other_sign_is_not_called_a_calibration():
    """A user's flexible arm: the output-error calibration gave the motor damping
    Bm = -0.115 (datasheet 0.002) with an absurd interval, and nothing was said."""
    from types import SimpleNamespace

    from fdigen.discover.output_loop import identifiability

    model = load_model(str(DATA / "flexjoint.toml"))
    fit = SimpleNamespace(null_directions=[], held={}, J=None, free=["Bm"],
                          params={"Bm": -0.115}, std={"Bm": 1.7e-19})
    info, warnings = identifiability(model, fit, {"Bm": 0.002})
    assert info["far_from_datasheet"][0]["parameter"] == "Bm"
    assert "opposite sign of its datasheet value 0.002" in warnings[0]

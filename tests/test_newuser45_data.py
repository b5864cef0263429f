"""Round 45: a user's motor-and-propeller thrust stand (its own simulator; logs at 50 Hz
with jitter, dropouts and dropped rows; tests/data/newuser45).

* The load cell reads ``kT w^2``: kT is held by no state equation, so the equation test
  never calibrated it ("the log cannot determine kT", held 7 % off, then spread +-31.6 %);
  ``auto`` now takes the output-error loop for such a parameter, as for a power meter.
* The derived residuals invert the load cell, ``w = sqrt(lc/kT)``: one reading of -0.51 g
  at spin-up (2 g of noise) was NaN, latched two flags for the whole log and stopped the
  rig at 0.1 s; a later tachometer fault read "unexplained".
"""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from fdigen.cli import main
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser45"


def test_a_parameter_only_a_sensor_map_holds_sends_auto_to_the_output_error_loop():
    from fdigen.discover.pipeline import static_parameter_outputs

    why = static_parameter_outputs(load_model(DATA / "thrust_stand.toml"))
    assert why == ["output lc depends on the uncertain kT, which no state equation holds: "
                   "the equation test would not calibrate it"]
    # the shipped models keep the equation test
    for name in ("pneumatic_cylinder", "three_tank", "dc_motor", "heat_exchanger"):
        assert static_parameter_outputs(load_model(name)) == []


def test_an_even_roots_reading_below_its_range_is_clipped_not_nan():
    from fdigen.model.sensor_maps import sensor_maps

    (lc,) = [m for m in sensor_maps(load_model(DATA / "thrust_stand.toml"))["w"]
             if m.output == "lc"]
    assert "Max(0, lc/kT)" in str(lc.inverse)
    res = CliRunner().invoke(main, ["detect", str(DATA / "short_neg_thrust.csv"), "--model",
                                    str(DATA / "thrust_stand_commissioned.toml"), "--json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["flags"] == [] and summary["diagnosis"]["action"] == "none"


def test_the_tachometer_fault_after_a_negative_reading_is_isolated():
    truth = json.loads((DATA / "fault_rpm.json").read_text())
    res = CliRunner().invoke(main, ["detect", str(DATA / "fault_rpm.csv"), "--model",
                                    str(DATA / "thrust_stand_commissioned.toml"), "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads(res.stdout)["diagnosis"]
    assert d["fault"] == "rpm_sensor" and d["candidates"] == ["tachfail"]
    onset = float(truth["fault"]["t0"])
    assert onset <= d["t_isolated"] <= onset + 1.0


def test_the_verdict_says_what_the_ambiguity_policy_does_for_an_unisolated_fault():
    """Under ambiguity = "wait" a damaged propeller (safety_stop) that shares its flags
    with a load-cell drift gets no action: the verdict said only "acts on it by the
    ambiguity policy"."""
    import dataclasses

    import numpy as np

    from fdigen.commission.verdict import design_verdict

    model = load_model("three_tank")
    leak = model.fault("leak1")
    own = dict(model.fdi["actions"])[leak.fault_class]
    delays = {"leak1": {"runs": 2, "false_isolations": 0, "by_size": [
        {"factor": 1.0, "kind": "step", "size": leak.test_size, "runs": 2, "detected": 2,
         "isolated_correct": 0}]}}
    y = np.zeros((10, len(model.outputs)))
    thresholds = dict(model.fdi["thresholds"])
    texts = {}
    for policy in ("wait", "most_severe"):
        m = dataclasses.replace(model, fdi={**model.fdi, "ambiguity": policy})
        v = design_verdict(m, thresholds, delays, y, 0.1)
        texts[policy] = next(t for t in v["limits"] if t.startswith("fault leak1 is detected"))
    assert 'ambiguity = "wait"' in texts["wait"]
    assert own == "safety_stop"
    assert "while they differ, none, though its own class calls for safety_stop" in \
        texts["wait"]
    assert "the most severe action of the classes its flags fit" in texts["most_severe"]


def test_an_inf_reading_is_refused_saying_a_nan_would_be_a_missing_sample(tmp_path):
    rows = (DATA / "short_neg_thrust.csv").read_text().splitlines()
    head = rows[0].split(",")
    j = head.index("rpm")
    cells = rows[40].split(",")
    cells[j] = "inf"
    rows[40] = ",".join(cells)
    log = tmp_path / "inf.csv"
    log.write_text("\n".join(rows) + "\n")
    res = CliRunner().invoke(main, ["detect", str(log), "--model",
                                    str(DATA / "thrust_stand_commissioned.toml")])
    assert res.exit_code == 2
    assert "column 'rpm': value is inf (Inf is not accepted; a NaN or an empty field is " \
           "read as a missing sample)" in res.output

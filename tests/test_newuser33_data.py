"""A user's pump rig, simulated by their own numpy code (round 33, 2026-11-28): a DC motor
with Coulomb friction and a drifting supply, a pump whose head droops, a lagged flow
meter. Discover's equation-error search chose ``sensor_offset_n_enc = -859 rpm`` (at its
search bound) and ``external_load``: the equations' error fell, the current's free-run
error rose from 0.45 to 2.06 V on the log and from 0.48 to 2.07 V on a validation log.
Commission committed both, and its campaign spread the pump head +-90 %.
"""

from pathlib import Path

from fdigen.commission.withhold import not_committed
from fdigen.discover.fit_report import unconfirmed_effects
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser33"

# discover's result on the rig's healthy log (discover.json, the keys these rules read;
# the whole-log errors keyed by log column, the validation's by output name)
FOUND = {
    "effects": ["sensor_offset_n_enc", "external_load"],
    "parameters": {"off_n_enc": -859.437, "Tload": -0.182, "Ra": 3.51, "c1": 0.5},
    "calibrated": {"Ra": 1.54, "c1": 1.08},
    "noise": {"i_sh": 0.00665, "n": 0.545, "p_lvl": 0.000484, "q_out": 0.182},
    "error_before": {"i_sh": 0.4514, "n": 26.95, "p_lvl": 0.004141, "q_out": 0.4456},
    "error_after": {"i_sh": 2.062, "n": 24.95, "p_lvl": 0.003065, "q_out": 0.3406},
    "validation": {"log": "healthy2.csv",
                   "error_before": {"i_sh": 0.4761, "n_enc": 20.58, "p_lvl": 0.002612,
                                    "q_out": 0.4609},
                   "error_after": {"i_sh": 2.073, "n_enc": 22.84, "p_lvl": 0.003404,
                                   "q_out": 0.5872}},
    "ties": [], "declared_faults": [],
}


def test_effects_that_make_the_free_run_worse_are_not_committed():
    model = load_model(str(DATA / "pump_tank.toml"))
    why = unconfirmed_effects(FOUND, model)
    assert len(why) == 2
    assert "on the log is larger" in why[0] and "i_sh 0.4514 -> 2.062" in why[0]
    assert "validation log healthy2.csv" in why[1] and "n_enc 20.58 -> 22.84" in why[1]
    withheld, faulty, notes = not_committed(FOUND, True, model)
    assert [w["chosen"] for w in withheld] == FOUND["effects"] and not faulty
    assert notes[0].startswith("not committed: sensor_offset_n_enc, external_load: ")
    assert "calibrated one without effects" in notes[0]


def test_effects_that_improve_the_outputs_are_committed():
    model = load_model(str(DATA / "pump_tank.toml"))
    better = {**FOUND, "error_after": {"i_sh": 0.30, "n": 20.0, "p_lvl": 0.003,
                                       "q_out": 0.34},
              "validation": {**FOUND["validation"], "error_after": {
                  "i_sh": 0.31, "n_enc": 19.0, "p_lvl": 0.0026, "q_out": 0.45}}}
    assert unconfirmed_effects(better) == []
    assert not_committed(better, True, model) == ([], [], [])
    # a worse output beside better ones: the sum in units of each sensor's noise decides
    # (the current's 0.005 V noise weighs more than the speed's 0.5 rpm)
    mixed = {**better, "error_after": {**better["error_after"], "i_sh": 0.60}}
    assert unconfirmed_effects(mixed, model)


def test_an_effect_the_log_does_not_determine_is_not_committed():
    """The output-error loop on the same rig wrote ``off_n_enc = 6.03 +- 49`` rpm, which it
    called hardly determined (820 %): its interval holds zero."""
    found = {"effects": ["sensor_offset_n_enc"],
             "parameters": {"off_n_enc": 6.03, "Ra": 1.096},
             "uncertainty": {"off_n_enc": 49.0, "Ra": 0.02}, "calibrated": {"Ra": 1.1}}
    why = unconfirmed_effects(found)
    assert why == ["the log does not determine off_n_enc = 6.03 +- 49 (its interval holds "
                   "zero)"]
    assert unconfirmed_effects({**found, "uncertainty": {"off_n_enc": 2.0}}) == []
    assert unconfirmed_effects({**found, "uncertainty": {"off_n_enc": None}}) == []


def test_the_commission_report_gives_each_kinds_detection_delay():
    """"level_tx 2/2 detected, detection 146" read as slow for an offset the user's own log
    showed flagged 0.3 s after onset: 146 s was the median of a step's and a ramp's."""
    from fdigen.commission.report import delays_by_kind

    d = {"by_size": [{"kind": "step", "detection_delay": 0.3},
                     {"kind": "ramp", "detection_delay": 290.0},
                     {"kind": "ramp", "detection_delay": 150.0},
                     {"kind": "step", "detection_delay": None}]}
    assert delays_by_kind(d) == " (steps 0.3, ramps 220)"
    assert delays_by_kind({"by_size": [{"kind": "step", "detection_delay": 1.0}]}) == ""

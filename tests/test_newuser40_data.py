"""Round 40: a hot-water storage tank a user simulated themselves
(tests/data/newuser40/rig_sim.py, kept out of fdigen's tuning): three stratified layers,
an on/off element, PT100s logged in Ohm, 5 s samples with rows the logger wrote twice.

What it found: a row written twice stopped discover and detect ("duplicated sample");
multiplicative fault sizes read "0.01x", as if a factor of the test size.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.errors import LogError


def test_a_row_written_twice_is_dropped_and_counted(tmp_path):
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.sim.log import read_log

    log = tmp_path / "log.csv"
    r = CliRunner()
    assert r.invoke(main, ["simulate", "--model", "dc_motor", "--duration", "1", "-o",
                           str(log)]).exit_code == 0
    lines = log.read_text().splitlines()
    twice = lines[:40] + [lines[39]] + lines[40:300] + [lines[299], lines[299]] + lines[300:]
    log.write_text("\n".join(twice) + "\n")
    model = load_model(resolve_model_path("dc_motor"))
    with pytest.raises(LogError, match="duplicated sample"):
        read_log(log, model)                                  # the strict reader
    lg = read_log(log, model, missing="keep")
    assert lg.missing == {"duplicates": 3} and len(lg.t) == len(lines) - 1
    assert "3 duplicated rows" in lg.missing_note()
    res = r.invoke(main, ["detect", str(log), "--model", "dc_motor"])
    assert res.exit_code == 0, res.output[-2000:]
    assert "3 duplicated rows (written twice, stamp and values) dropped" in res.output
    # a repeated stamp with other values is still refused: which row is the sample?
    other = lines[:40] + [lines[39].split(",", 1)[0] + "," + lines[41].split(",", 1)[1]] \
        + lines[40:]
    log.write_text("\n".join(other) + "\n")
    with pytest.raises(LogError, match="time does not increase"):
        read_log(log, model, missing="keep")


def test_a_multiplicative_fault_size_reads_as_a_percentage():
    from fdigen.tune.fault_sensitivity import sensitivity_text

    entry = {"unit": "x", "offset": False, "ramp": False, "basis": "campaign",
             "detected_from": 0.01, "isolated_from": 0.02, "isolation_delay_max": 30.0}
    text = sensitivity_text("top_gain", entry)
    assert text.startswith("top_gain: faults from 1 % detected, from 2 % isolated"), text
    assert "0.01x" not in text


def test_the_users_tank_models_load():
    from fdigen.model.model_file import load_model

    data = Path(__file__).parent / "data" / "newuser40"
    for name in ("dhw_tank.toml", "dhw2.toml"):
        assert load_model(data / name).outputs


def test_a_calibration_that_did_not_converge_refuses_the_design():
    """The tank's two-layer model was commissioned on the last iterate of an output-error
    fit IPOPT had stopped, the campaign's spread set by that iterate's interval."""
    import numpy as np

    from fdigen.commission.verdict import design_verdict
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    model = load_model(resolve_model_path("three_tank"))
    thresholds = dict(cached_design(model).config.thresholds)
    y = np.zeros((10, len(model.outputs)))
    assert design_verdict(model, thresholds, {}, y, 0.1)["usable"]
    v = design_verdict(model, thresholds, {}, y, 0.1, converged=False)
    assert not v["usable"] and v["failures"][0].startswith("the calibration did not converge")


def test_a_residual_at_its_noise_is_no_effect_to_scale():
    """round 41's greenhouse: the soil filter at 0.0056 V of noise against 0.00986 V gave
    an air-sensor offset "isolated from ~3.49 degF", never isolated at 8 degF."""
    from fdigen.tune.fault_sensitivity import fault_share

    assert fault_share(0.0056, 0.0055, 0.00986) is None          # at its noise
    share = fault_share(0.02, 0.005, 0.01)
    assert abs(share - (0.02 ** 2 - 0.005 ** 2) ** 0.5 / (0.01 ** 2 - 0.005 ** 2) ** 0.5) \
        < 1e-12
    assert fault_share(float("inf"), 0.005, 0.01) == float("inf")  # a dead sensor
    assert fault_share(0.02, 0.012, 0.01) is None                 # no room under the noise


def test_an_operating_input_outside_its_range_is_said():
    """round 41's pump needed 24.23 V from a 24 V supply: the healthy loop saturated in
    51 % of its samples and the thresholds were designed on it, said nowhere."""
    data = Path(__file__).parent / "data" / "newuser41"
    from fdigen.design.design_warnings import inputs_outside
    from fdigen.model.model_file import load_model

    (note,) = inputs_outside(load_model(data / "pump_v1_saturated.toml"))
    assert "input V = 24.2253 lies outside its declared range [0, 24]" in note
    assert inputs_outside(load_model(data / "pump.toml")) == []


def test_residual_names_never_take_a_name_of_the_model(tmp_path):
    """round 41's pump named a residual Rp beside its pipe-loss parameter Rp (refused
    now, naming both); a derived residual skips a name the model gives a quantity (a
    battery's polarisation resistance R1)."""
    from fdigen.design.cache import cached_design
    from fdigen.errors import ModelFileError
    from fdigen.model.model_file import load_model

    data = Path(__file__).parent / "data"
    text = (data / "newuser39" / "cruise.toml").read_text()
    extra = text.replace("[states]", 'R1 = { value = 1.0, unit = "1", description = '
                                     '"an unused resistance" }\n\n[states]', 1)
    path = tmp_path / "cruise_r1.toml"
    path.write_text(extra)
    from fdigen.tune.model_update import fill_missing_thresholds

    def derived(p):
        return [e["residual"] for e in cached_design(
            fill_missing_thresholds(load_model(p), 1e30)[0]).extra_residuals]

    names, plain = derived(path), derived(data / "newuser39" / "cruise.toml")
    assert plain == ["R1"] and names == ["R2"]
    clash = tmp_path / "clash.toml"
    clash.write_text(extra.replace('[fdi.parity]\n', '[fdi.parity]\nR1 = "f_wheel"\n', 1))
    with pytest.raises(ModelFileError, match="a residual named like the model's parameter R1"):
        derived(clash)


def test_the_tune_comment_gives_the_campaign_it_ran():
    """round 41: the comment read `--runs 6 --duration 10 --seed 0 --write`, without the
    `--validation-runs 4 --horizon-runs 2` that made the campaign."""
    from fdigen.tune.model_update import threshold_note

    base = {"runs": 6, "duration": 10.0, "seed": 0, "tolerance": 0.1,
            "false_alarm_rate": 0.01, "margin": 1.25}
    plain = threshold_note({**base, "validation_runs": 10, "fault_starts": 2,
                            "horizon_runs": 10, "fault_factors": (0.25, 0.5, 1, 2)})
    assert "`fdigen tune --runs 6 --duration 10 --seed 0 --write`" in plain
    note = threshold_note({**base, "validation_runs": 4, "fault_starts": 2,
                           "horizon_runs": 2, "fault_factors": (1.0,)})
    assert ("`fdigen tune --runs 6 --duration 10 --seed 0 --validation-runs 4 "
            "--horizon-runs 2 --fault-sizes 1 --write`") in note


def test_fault_sizes_past_a_total_loss_are_said_not_run():
    from fdigen.model.model_file import load_model
    from fdigen.tune.cases import clipped_sizes

    pump = load_model(Path(__file__).parent / "data" / "newuser41" / "pump.toml")
    notes = clipped_sizes(pump, (0.25, 0.5, 1.0, 2.0))
    assert any(n.startswith("bearing: sizes 2x its test size") for n in notes), notes
    assert clipped_sizes(pump, (0.5, 1.0)) == []

"""A user's water heater (tests/data/newuser13, written from the README; logs from the
user's own simulator with a heat loss, a heater efficiency and a thermocouple lag the
model lacks): discover on a model whose declared residuals have no thresholds yet, and the
equation test's refusal of a log too short or too slowly sampled for it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser13"


def _copy(tmp_path, *names):
    for n in names:
        shutil.copy(DATA / n, tmp_path / n)


def test_discover_default_path_on_a_model_never_tuned(tmp_path, monkeypatch):
    """The model declares R1 and K1 and no [fdi.thresholds]: discover ended in exit 2
    ("missing thresholds for residuals R1, K1") after writing the augmented model, with or
    without --no-fdi. Now both designs read their thresholds from the log and the
    before/after residual comparison is reported."""
    _copy(tmp_path, "water_heater.toml", "heater_healthy.csv")
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, ["discover", "heater_healthy.csv", "--model",
                                    "water_heater.toml", "--out", "d", "--no-build",
                                    "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert info["effects"], info
    before, after = info["fdi_before"], info["fdi_after"]
    assert set(before) >= {"R1", "K1"} and set(after) >= {"R1", "K1"}
    # the augmented model explains more of the log: its parity residual shrinks
    assert after["R1"] < 0.5 * before["R1"]
    text = " ".join(info["warnings"])
    assert "no threshold for R1" in text and "without a threshold in the file" in text


def test_too_short_names_a_length_that_would_do(tmp_path, monkeypatch):
    """A 10-s log of 1190 s with 30-s windows (3 samples each): the message said it
    needed 'at least about 1155 s (this one is 1190 s)'. The length it names now follows
    from the windows this log could use, and it names the output-error loop."""
    _copy(tmp_path, "water_heater.toml", "heater_slow.csv")
    monkeypatch.chdir(tmp_path)
    for extra in (["--window", "30"], []):
        res = CliRunner().invoke(main, ["discover", "heater_slow.csv", "--model",
                                        "water_heater.toml", "--out", "d", *extra])
        assert res.exit_code == 2, res.output
        msg = " ".join(res.output.split())
        need = float(msg.split("at least about ")[1].split(" s")[0])
        have = float(msg.split("(this one is ")[1].split(" s")[0])
        assert need > 2 * have, msg
        assert "--method output-error" in msg
    assert "windows of at least 10 samples (`fdigen discover --window 100`)" in " ".join(
        CliRunner().invoke(main, ["discover", "heater_slow.csv", "--model",
                                  "water_heater.toml", "--out", "d", "--window", "30"]
                           ).output.split())


def test_a_quantised_sensor_has_no_rail():
    """A motor held at 3000 rpm by a PI loop, read by an encoder quantised to 14.6 rpm:
    its top reading repeats as often as the one below it, and got a 'saturation' at the
    setpoint. A sensor clipped at a rail piles its samples on the rail."""
    from fdigen.discover.effects_real import rails

    rng = np.random.default_rng(0)
    q = 60.0 / 4096 / 1e-3                       # one count per ms, in rpm
    w = 3000.0 + 6.0 * rng.standard_normal(4000)
    assert rails(np.round(w / q) * q) == {}
    clipped = np.minimum(3000.0 + 30.0 * rng.standard_normal(4000), 3020.0)
    assert rails(clipped) == {"high": 3020.0}


def _heater_effects():
    from fdigen.discover.effects_real import real_plant_effects
    from fdigen.model.model_file import load_model
    from fdigen.sim.log import read_log

    model = load_model(str(DATA / "water_heater.toml"))
    log = read_log(DATA / "heater_healthy.csv", model)
    return model, log, {e.name: e for e in real_plant_effects(model, log.t, log.u, log.y)}


def test_an_overflow_above_the_log_is_refused():
    """The user's heater never passes 45.9 degC; an overflow at 55.4 degC acted through
    its rounded tail as a heat loss and was chosen. A level the log reaches is kept."""
    from fdigen.discover.fit_checks import switch_refusal
    from fdigen.discover.output_loop import noise_of

    model, log, effects = _heater_effects()
    over = effects["overflow_T"]
    noise = noise_of(model, log.y)
    top = float(np.max(log.y[:, 0]))
    why = switch_refusal(over, {"xof_T": 55.4}, model, log.u, log.y, noise)
    assert why is not None and "0 of" in why and "rounded tail" in why
    assert switch_refusal(over, {"xof_T": top - 0.5}, model, log.u, log.y, noise) is None
    sat = effects["actuator_saturation_P"]
    p_top = float(np.max(log.u[:, 0]))
    assert switch_refusal(sat, {"umax_P": 1.01 * p_top}, model, log.u, log.y, noise)
    assert switch_refusal(sat, {"umax_P": 0.9 * p_top}, model, log.u, log.y, noise) is None


def test_an_effect_a_calibrated_parameter_absorbs_is_named(tmp_path, monkeypatch):
    """The user's motor with Coulomb friction (8 mN m) and a viscous b declared uncertain:
    Tc is estimated to 7.84e-3 +- 2e-4 but not added (dBIC -1.3) while b calibrates to
    1.77 times its datasheet. The report said the two facts apart; it now links them."""
    _copy(tmp_path, "my_motor_tuned.toml", "motor_fric_only.csv")
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, ["discover", "motor_fric_only.csv", "--model",
                                    "my_motor_tuned.toml", "--out", "d", "--no-build",
                                    "--no-fdi", "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    (hit,) = [a for a in info["absorbed"] if a["effect"] == "coulomb_friction"]
    assert hit["z"] > 10 and -10 < hit["delta_bic"] < 0
    tc = next(c for c in info["candidates"] if c["effect"] == "coulomb_friction")
    assert abs(tc["parameters"]["Tc"] - 8e-3) < 0.05 * 8e-3      # the rig's truth
    assert any("may be absorbing it" in w and "b (1.77x" in w for w in info["warnings"])


def test_commission_does_not_commit_an_effect_the_log_cannot_decide(tmp_path, monkeypatch):
    """The heater's healthy log: discover chose a -3.66 degC offset of the (healthy)
    thermocouple, tied with the heat loss the rig really has (dBIC -111.7 against -110.4),
    and commission wrote the offset into the commissioned model. It now commits neither,
    says why, and the verdict follows from the calibrated model alone."""
    _copy(tmp_path, "water_heater_tuned.toml", "heater_healthy.csv")
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, ["commission", "heater_healthy.csv", "--model",
                                    "water_heater_tuned.toml", "--out", "c", "--runs", "8",
                                    "--validation-runs", "3", "--json"])
    assert res.exit_code in (0, 1), res.output[-2000:]
    out = json.loads(res.stdout)
    assert out["effects"] == []
    assert any(w.startswith("not committed: sensor_offset_T_meas") and "heat_loss_T" in w
               for w in out["warnings"]), out["warnings"]
    text = (tmp_path / "c" / "water_heater_commissioned.toml").read_text()
    assert "off_T_meas" not in text

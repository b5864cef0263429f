"""Round 54: a user's electric boiler, simulated by the user's own code and logged as a
rig would (``tests/data/newuser54/README.md``).

- A command logged in V for a model's ``%`` is another quantity: refused, where it was read
  as a duty and a healthy boiler was shut down as "heater" (safety_stop at 50 s).
- A validation log that lies within the design's start-up validates nothing, and says so
  (it was "no flag"); the largest RMS over the threshold is taken after the start-up.
- A residual that reads no state of the core (a static relation) raised by the log's start
  is not blamed on the hidden states, and gets no advice to re-align a parallel model it
  does not have.
- A heat loss whose ambient was assumed (the state's lower limit) says so; an output the
  fit follows worse than the datasheet model is named; a commissioning log shorter than
  the campaign's runs is warned of.
"""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from fdigen.cli import main
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser54"
COMMISSIONED = DATA / "eboiler_commissioned.toml"


def test_a_command_logged_in_volts_for_a_percentage_is_refused():
    res = CliRunner().invoke(main, ["detect", "--model", str(COMMISSIONED),
                                    str(DATA / "healthyB_u_in_V.csv"), "--json"])
    assert res.exit_code == 2, res.output
    err = json.loads(res.stdout)["error"]
    assert "column 'u' in 'V', another quantity than the model's '%'" in err["message"]
    # the same log labelled as the model's unit runs (and a healthy boiler stays quiet)
    res = CliRunner().invoke(main, ["detect", "--model", str(COMMISSIONED),
                                    str(DATA / "healthy_B.csv"), "--json"])
    assert res.exit_code == 0, res.output


def test_a_validation_log_inside_the_start_up_validates_nothing():
    from fdigen.commission.validation_logs import check_validation_logs, validation_text

    model = load_model(COMMISSIONED)
    said = []
    short, long = check_validation_logs(
        model, [DATA / "healthy_C_short.csv", DATA / "healthy_B.csv"], said.append)
    assert not short["validates"] and short["peak_over_threshold"] == {}
    assert "VALIDATES NOTHING" in said[1] and "start-up of 400 s" in said[1]
    assert long["validates"] and long["quiet"]
    assert "no flag (after the start-up of 400 s)" in validation_text(long)
    # after the start-up the log stays under every threshold (its start reached R3 at
    # 118 % of it, which the core never compares)
    assert max(long["peak_over_threshold"].values()) < 1.0


def test_a_static_residual_is_not_blamed_on_hidden_states():
    from fdigen.commission.healthy_check import early_start_warning, stateless_residuals
    from fdigen.design.cache import cached_design

    static = stateless_residuals(cached_design(load_model(COMMISSIONED)))
    # R3 (declared) and R5 compare the transducer with kI*Pmax*u/(100*Vm): no state
    assert {"R3", "R5"} <= static and not {"R1", "R2", "K1"} & static
    peaks = {"R5": {"t_max": 0.0, "ratio": 4.0}, "R1": {"t_max": 60.0, "ratio": 3.5}}
    text = early_start_warning(peaks, ["R5", "R1"], ["Te started at 39.49"], static)
    first, second = text.split("; threshold ")
    assert first.startswith("threshold R5") and "no state of the core" in first
    assert "Te started" not in first and "R1" in second and "Te started" in second


def test_an_assumed_ambient_is_said():
    from fdigen.discover.effects_physics import _balance_effects as physics_effects
    from fdigen.discover.effects_physics import assumed_ambient_notes
    from fdigen.discover.roles_physics import balances

    model = load_model(DATA / "boiler.toml")
    thermal = {b.state: b for b in balances(model) if b.kind == "thermal"}
    assert thermal and all(b.assumed for b in thermal.values())
    notes = assumed_ambient_notes(physics_effects(model))
    assert any(n.startswith("heat_loss_Tw: extra heat loss of Tw to ambient") and
               "declare the ambient" in n for n in notes)
    # an ambient declared: used, nothing said
    text = (DATA / "boiler.toml").read_text().replace(
        "[parameters]\n", '[parameters]\nTa = { value = 18.0, unit = "degC", '
        'description = "ambient temperature of the room" }\n', 1)
    from fdigen.model.model_file import parse_model_text

    declared = parse_model_text(text, str(DATA / "boiler.toml"))
    assert not any(b.assumed for b in balances(declared) if b.kind == "thermal")
    assert not assumed_ambient_notes(physics_effects(declared))


def test_an_output_the_fit_follows_worse_is_named():
    from fdigen.discover.fit_checks import worse_after_fit

    # the user's healthy_A: the current transducer 0.305 -> 0.496 V, the others better
    nominal = {"y_out": 0.6319, "y_tank": 1.312, "y_I": 0.3049}
    after = {"y_out": 0.5907, "y_tank": 0.2879, "y_I": 0.4962}
    noise = {"y_out": 0.0605, "y_tank": 0.0303, "y_I": 0.01}
    warned = worse_after_fit(nominal, after, noise)
    assert len(warned) == 1 and warned[0].startswith("y_I: the fitted model follows it "
                                                     "worse")
    # within its noise: nothing
    assert not worse_after_fit({"a": 0.01}, {"a": 0.019}, {"a": 0.05})


def test_a_commissioning_log_shorter_than_a_run_is_warned_of():
    from fdigen.commission.healthy_check import short_log_warning

    assert short_log_warning(3600.0, 3600.0) is None
    text = short_log_warning(360.0, 3600.0)
    assert "holds 360 s of the rig" in text and "10 % of a run" in text


def test_no_realignment_advice_for_a_residual_without_a_parallel_model(tmp_path):
    """The user's first commission advised re-aligning R3 (the current transducer against
    kI*Pmax*u/(100*Vm): no dynamics); only R1 and R2 have parallel models."""
    import numpy as np

    from fdigen.commission.verdict import _spread_levers
    from fdigen.sim.log import read_log

    text = COMMISSIONED.read_text().replace("realign_noise_scale = 0.1",
                                            "realign_noise_scale = 0.0")
    path = tmp_path / "eboiler_open_loop.toml"
    path.write_text(text)
    model = load_model(path)
    y = read_log(DATA / "healthy_B.csv", model, missing="fill").y
    spans = np.nanmax(y, axis=0) - np.nanmin(y, axis=0)
    thresholds = dict(model.fdi["thresholds"])
    for res, out in model.fdi["parity"].items():       # every parity threshold wide
        thresholds[res] = float(spans[model.output_index(out)])
    (loop,) = [f for f in _spread_levers(model, thresholds, y, None)
               if "parallel model runs open loop" in f]
    named = loop.split(":")[0].split(", ")
    assert "R3" not in named and {"R1", "R2"} <= set(named)

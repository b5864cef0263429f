"""Plants a first-time user wrote from the README (2026-11-27): a cart-pole under LQR
state feedback, a quarter-car active suspension in mm with an accelerometer, and an
electric oven read through thermocouples in mV with a hidden wall.

The cart-pole's motor gain fault (a term on the force ``F``) and its friction fault
(inside ``Ff = (bc + fric) v``) reach the plant only through ``F - Ff``; the quarter car's
actuator loss and damper leak only through ``F - Fd``. inspect called both pairs
achievable (structure assumes generic gains), printed "a residual blind to it exists but
was not chosen" and advised a sensor on the unmeasured velocities, which would not help.
"""

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.design.analytic_isolability import (achievable_isolability,
                                                analytic_isolability, parallel_pairs)
from fdigen.design.structure import isolability, model_structure
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser18"


@pytest.mark.parametrize("name, pair", [("cartpole", ("motor", "fric")),
                                        ("qcar_mm", ("act_loss", "damper_leak")),
                                        ("qcar_si", ("act_loss", "damper_leak")),
                                        ("oven", ("door", "element"))])
def test_faults_acting_in_one_direction_are_not_called_isolable(name, pair):
    model = load_model(str(DATA / f"{name}.toml"))
    structural = isolability(model_structure(model))
    isol, removed = achievable_isolability(model, structural)
    a, b = pair
    assert frozenset(pair) in parallel_pairs(model)
    assert not isol[(a, b)] and not isol[(b, a)]
    # the test only removes pairs; the rest of the structural answer stands
    assert all(isol[p] == ok for p, ok in structural.items() if p not in removed)
    assert not any(isol[p] and not ok for p, ok in structural.items())


@pytest.mark.parametrize("name", ["pneumatic_cylinder", "three_tank", "dc_motor",
                                  "heat_exchanger"])
def test_the_shipped_models_keep_their_structural_isolability(name):
    """Every pair structure allows, the shipped models' equations allow too (their designs
    are unchanged); a fault without effect at the operating point (the cylinder's
    blockages: no flow) never makes a structurally inseparable pair separable."""
    model = load_model(name)
    structural = isolability(model_structure(model))
    isol, removed = achievable_isolability(model, structural)
    assert removed == [] and isol == structural
    assert analytic_isolability(model) is not None


def test_inspect_says_no_sensor_separates_a_pair_acting_in_one_direction(tmp_path,
                                                                        monkeypatch):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "cartpole.toml")])
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    # no sensor on a state; one on the force the motor delivers (F_eff) or on the
    # friction force Ff (the definition fric is written in)
    assert "motor from fric: a sensor on F as the actuator delivers it (F_eff), Ff " in text
    assert "a residual blind to it exists but was not chosen" not in text
    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "qcar_mm.toml"),
                                    "--json"])
    assert res.exit_code == 0, res.output
    iso = json.loads(res.output)["isolability"]
    assert {tuple(e["pair"]) for e in iso["not_isolable_by_direction"]} == {
        ("act_loss", "damper_leak"), ("damper_leak", "act_loss")}
    assert all(e["same_direction"] for e in iso["not_isolable_by_direction"])
    # no sensor on a state helps; one on the force the actuator delivers (F_eff), or on
    # the damper force Fd (a load cell), in which the leak is written, does
    for entry in iso["sensor_placement"]:
        if set(entry["pair"]) == {"act_loss", "damper_leak"}:
            assert entry["sensors"] == ["F_eff", "Fd"]


def test_a_sensor_on_a_definition_is_advised_where_it_separates(tmp_path, monkeypatch):
    """The oven's element loss is written in the heater power P = (1 - element) Pmax
    sat(u); it and the open door both act only in the wall's heat balance. No sensor on a
    state separates them; a wattmeter on P does (it sees the element, not the door)."""
    from fdigen.design.structure import isolability_report

    model = load_model(str(DATA / "oven.toml"))
    iso = isolability_report(model)
    placed = {tuple(e["pair"]): e["sensors"] for e in iso["sensor_placement"]}
    assert placed[("door", "element")] == ["P"] == placed[("element", "door")]
    assert iso["definition_sensors"] == ["P"]
    # the same fault as a term on the heater's input: the actuator's delivered value
    other = isolability_report(load_model(str(DATA / "oven_b.toml")))
    assert any("d_eff" in e["sensors"] for e in other["sensor_placement"])


def test_no_sensor_is_advised_on_a_definition_the_parser_made():
    """A fault written in an equation makes the equation a definition (d<state>_dt) for
    the parser: a user's mixing tank was advised "a sensor on dh_dt", which sees every
    term of the level's balance."""
    from fdigen.design.definition_sensors import definition_structures
    from fdigen.model.model_file import builtin_model_path, parse_model_text

    text = builtin_model_path("dc_motor").read_text()
    inline = text.replace('w = "(Kt*i - b*w)/J"', 'w = "(Kt*i - b*w - load)/J"', 1)
    inline = inline.replace('target = "w"\nterm = "-load/J"\n', "", 1)
    model = parse_model_text(inline, "inline.toml")
    assert "dw_dt" in dict(model.definitions)
    assert "dw_dt" not in definition_structures(model)

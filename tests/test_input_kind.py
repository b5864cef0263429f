"""An input's ``kind``: a command (the default) or a measured disturbance.

A user's air tunnel declared its inlet temperature and fan flow as plain inputs (they are
read from the log): discover offered ``actuator_deadband_Tin`` and ``gain_loss_Tin``
("heater ageing" of an air temperature), and the output-error loop chose the dead band.
``kind = "measured"`` says what the input is; without it, an actuator effect on an input
no controller commands is named with the key.
"""

from pathlib import Path

import pytest

from fdigen.discover.effects import library
from fdigen.discover.effects_real import actuator_saturation
from fdigen.discover.input_kind import measured_input_warnings, uncommanded_inputs
from fdigen.errors import ModelFileError
from fdigen.model.model_file import canonical_description, load_model, parse_model_text

DATA = Path(__file__).parent / "data" / "newuser31"


def _tunnel(kinds: str = ""):
    text = (DATA / "air_tunnel.toml").read_text()
    if kinds:
        text = text.replace('column = "mdot" }', f'column = "mdot"{kinds} }}').replace(
            'column = "T0" }', f'column = "T0"{kinds} }}')
    return parse_model_text(text, source="air_tunnel.toml")


def _on_inputs(effects, names):
    return sorted(e.name for e in effects if e.family in ("deadband", "gain",
                                                          "actuator_saturation")
                  and any(n in e.name for n in names))


def test_a_measured_input_gets_no_actuator_effect():
    import numpy as np

    plain, measured = _tunnel(), _tunnel(', kind = "measured"')
    assert [u.kind for u in measured.inputs] == ["actuator", "measured", "measured"]
    u = np.tile([1000.0, 0.05, 20.0], (50, 1)) + np.linspace(0, 1, 50)[:, None]
    before = _on_inputs([*library(plain), *actuator_saturation(plain, u)], ("Tin", "mdot"))
    after = _on_inputs([*library(measured), *actuator_saturation(measured, u)],
                       ("Tin", "mdot"))
    assert "gain_loss_Tin" in before and "actuator_saturation_Tin" in before
    assert after == []
    # the heater, a command, keeps its own
    assert "gain_loss_P" in [e.name for e in library(measured)]
    assert "actuator_saturation_P" in [e.name for e in actuator_saturation(measured, u)]


def test_an_actuator_effect_on_an_input_no_controller_commands_names_the_key():
    plain = _tunnel()
    assert uncommanded_inputs(plain) == {"Tin", "mdot"}
    effects = {e.name: e for e in library(plain)}
    warns = measured_input_warnings(plain, [effects["gain_loss_Tin"], effects["gain_loss_P"]])
    assert len(warns) == 1 and 'declare it `kind = "measured"`' in warns[0]
    assert "input Tin" in warns[0]
    assert measured_input_warnings(_tunnel(', kind = "measured"'), list(effects.values())) \
        == []


def test_the_key_is_checked_and_the_default_changes_nothing():
    with pytest.raises(ModelFileError, match=r"inputs\.mdot\.kind.*'actuator', 'measured'"):
        _tunnel(', kind = "sensor"')
    with pytest.raises(ModelFileError, match=r"kind"):
        parse_model_text((DATA / "air_tunnel.toml").read_text().replace(
            'range = [30.0, 60.0]', 'range = [30.0, 60.0], kind = "measured"'))
    spelled = _tunnel(', kind = "actuator"')
    assert canonical_description(spelled) == canonical_description(_tunnel())
    assert canonical_description(_tunnel(', kind = "measured"')) != \
        canonical_description(_tunnel())
    # the shipped models' descriptions (and so their stamps) are what they were
    for name in ("pneumatic_cylinder", "three_tank"):
        assert all(len(i) == 4 for i in canonical_description(load_model(name))["inputs"])

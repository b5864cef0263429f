"""Round 39: plants a user wrote from the README alone (tests/data/newuser39): a car
with cruise control (speed in km/h, engine torque lag, road grade measured, wheel-speed
pulses in Hz, an accelerometer), a quadrotor's altitude loop, a compressed-air receiver.

What the car found: the check every vehicle makes, wheel speed against the accelerometer
(``dv/dt = 3.6 (a - g sin(theta))``, in which the engine torque and the mass cancel), was
"achievable, not achieved": the accelerometer's map reads the unmeasured torque with the
measured speed *and the road grade*, an input, which the compound sensor maps did not
allow. Once built, the table claimed the trailer (mass) moved it: the mass enters the
speed equation and the accelerometer's specific force, whose effects cancel, and the
driver's term had the wrong sign. A trailer would then have been isolated as the
powertrain.
"""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser39"


def test_wheel_speed_and_accelerometer_check_each_other():
    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "cruise.toml"),
                                    "--json"])
    assert res.exit_code == 0, res.output[-2000:]
    rep = json.loads(res.stdout)
    acc = rep["sensor_maps"]["measures"]["a_meas"]
    assert acc["state"] == "Te" and acc["with"] == ["v"] and "grade" in acc["inverse"]
    (r1,) = [e for e in rep["extra_residuals"] if e["drivers"] == {"Te": "a_meas"}]
    sig = {f: v for f, v in rep["signature_table"][r1["residual"]].items()}
    # the sensors' faults move it; the engine's and the mass's cannot
    assert sig == {"acc_offset": 1, "tyre": 1, "throttle": 0, "trailer": 0}
    iso = rep["isolability"]
    assert not iso["achieved_not_achievable"]
    assert not iso["achievable_not_achieved"]


def test_the_trailer_does_not_move_the_residual_the_table_says_it_cannot():
    """By simulation: a 50 % heavier car raises the speed and torque residuals, not the
    wheel-speed/accelerometer one; a tyre's 3 % raises it."""
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.verify.sensitivity import numeric_signatures

    design = cached_design(load_model(DATA / "cruise_tuned.toml"))
    check = next(e["residual"] for e in design.extra_residuals
                 if e["drivers"] == {"Te": "a_meas"})
    num = numeric_signatures(design, duration=60.0, t_fault=20.0, horizon=30.0,
                             stop_at_isolation=False, faults=("trailer", "tyre"))
    assert num["healthy"] == []
    assert num["faults"]["trailer"] and check not in num["faults"]["trailer"]
    assert check in num["faults"]["tyre"]


def test_two_classes_to_accommodate_that_share_their_first_flags_are_named(tmp_path):
    """The core then reports `accommodate` with no class: which sensor is the controller
    to stop using? inspect says so (the quadrotor with its barometer set to accommodate,
    like its range finder)."""
    text = (DATA / "quad_alt.toml").read_text()
    assert 'barometer = "none"' in text
    model = tmp_path / "quad.toml"
    model.write_text(text.replace('barometer = "none"', 'barometer = "accommodate"'))
    for path, named in ((DATA / "quad_alt.toml", False), (model, True)):
        res = CliRunner().invoke(main, ["inspect", "--model", str(path), "--json"])
        assert res.exit_code == 0, res.output[-2000:]
        warnings = " ".join(json.loads(res.stdout)["warnings"])
        assert ("accommodate without a class: barometer and range_finder" in warnings) \
            is named


def test_the_barometric_formula_is_inverted():
    """`p0*(1 - 2.25577e-5*z)**5.25588` had "no closed-form inverse": sympy inverts no
    power with a decimal exponent. It is inverted with the exponent as its fraction."""
    import numpy as np
    import sympy as sp

    from fdigen.model.model_file import load_model
    from fdigen.model.sensor_maps import sensor_maps

    m = load_model(DATA / "quad_alt.toml")
    (baro,) = [sm for sm in sensor_maps(m)["z"] if sm.output == "p_baro"]
    values = m.parameter_values
    state = m.states[m.state_index("z")]
    z = state.symbol
    y = sp.Symbol("p_baro", real=True)
    for height in np.linspace(*state.range, 7):
        reading = baro.forward.xreplace({z: sp.Float(height)}).xreplace(values)
        back = float(baro.inverse.xreplace({y: reading}).xreplace(values))
        assert abs(back - height) <= 1e-9 * max(1.0, abs(height))


def test_a_refusal_advises_what_fits_its_failure():
    """A drone refused for a rotor fault never detected was told to add healthy runs."""
    from fdigen.design.refusal_marks import TUNE_REFUSAL, refused_text

    blind = refused_text(TUNE_REFUSAL + " faults detected in none of their runs at their "
                                        "test size: rotor1 (0 of 2).")
    assert "more healthy runs" not in blind and "a sensor that reads it" in blind
    alarms = refused_text(TUNE_REFUSAL + " 1 of 10 healthy validation runs raised a flag "
                                         "with the tuned thresholds.")
    assert "more healthy runs (--runs)" in alarms and "a sensor that reads it" not in alarms
    wrong = refused_text(TUNE_REFUSAL + " fault runs isolated as another class: an_drift "
                                       "in 1 of 16.")
    assert "[fdi] confirm" in wrong

"""A first-time user's water heater (2026-11-27, round 21): one well-mixed node, a 3 kW
heater on a PI loop, a draw-off flow meter, a top thermistor and a heater power meter
``yP = Pel = (1 - heater) Pmax u/100``, with the capacity ``C`` and the rated power
``Pmax`` uncertain.

discover's default path (the equation test) calibrated from the tank's state equation
alone and ignored the power meter, a static relation that pins ``Pmax``: 2539 +- 190 on
a log without any hidden effect (truth 3000); the output-error loop gave 3023.8. A model
whose static output depends on an uncertain parameter is now calibrated by output error
by default, saying why; commission takes ``--method`` too.
"""

from pathlib import Path

from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser21"


def test_a_static_sensor_of_an_uncertain_parameter_sends_discover_to_output_error():
    from fdigen.discover.pipeline import static_parameter_outputs

    model = load_model(str(DATA / "water_heater.toml"))
    why = static_parameter_outputs(model)
    assert why == ["output yP reads no state and depends on the uncertain Pmax: the "
                   "equation test would not use it"]
    # the shipped models (every output reads a state) keep the equation test
    for name in ("pneumatic_cylinder", "three_tank", "dc_motor", "heat_exchanger"):
        assert static_parameter_outputs(load_model(name)) == []


def test_commission_takes_the_discover_method():
    from click.testing import CliRunner

    from fdigen.cli import main

    res = CliRunner().invoke(main, ["commission", "--help"])
    assert res.exit_code == 0 and "--method [auto|output-error]" in res.output
    res = CliRunner().invoke(main, ["commission", "x.csv", "--method", "bogus"])
    assert res.exit_code == 2


def test_a_static_outputs_noise_is_read_around_its_relation():
    """The power meter follows every 1 % step of the heater command: its second
    differences read 29.7 W for a 10 W meter, and the fit weighed it 9x too little."""
    import numpy as np

    from fdigen.discover.noise import noise_level, noise_of

    model = load_model(str(DATA / "water_heater.toml"))
    rng = np.random.default_rng(4)
    K = 3000
    u = np.column_stack([np.clip(np.cumsum(rng.integers(-3, 4, K)), 0, 100).astype(float),
                         np.full(K, 0.35)])
    p = 3000.0 * u[:, 0] / 100 + rng.normal(0.0, 10.0, K)
    T = 60.0 + rng.normal(0.0, 0.05, K)
    y = np.column_stack([T, p])
    assert noise_level(y)[1] > 25.0                      # the command's steps read as noise
    est = noise_of(model, y, u)
    assert abs(est[1] - 10.0) < 1.0 and abs(est[0] - 0.05) < 0.01
    assert np.array_equal(noise_of(model, y), noise_level(y))   # without u: as before


def test_the_output_error_bic_sums_errors_in_units_of_noise():
    """A heat loss that cut the thermistor's free-run error from 0.418 to 0.116 K beside a
    power meter's unchanged 9.95 W scored dBIC -1.1 on unscaled squares."""
    import numpy as np

    from fdigen.discover.output_loop import _scaled

    class Fit:
        def __init__(self, rms):
            self.rms = np.array(rms)

    noise = np.array([0.0545, 9.68])
    before, after = Fit([0.4182, 9.947]), Fit([0.116, 9.947])
    N, k = 6000, 1
    scaled = N * np.log(_scaled(after, noise) / _scaled(before, noise)) + k * np.log(N)
    unscaled = N * np.log(np.sum(after.rms ** 2) / np.sum(before.rms ** 2)) + k * np.log(N)
    assert scaled < -5000 and unscaled > -10

"""The parameter-spread masking of a fault (``fdigen.tune.parameter_masking``).

A clogging of the three tanks' first pipe is, by the model's own equations, a loss of
the outflow coefficient ``az12``: ``q12 (1 - clog12) = (az12 (1 - clog12)) Sn ...``.
Switched on from the start, a clogging inside the tolerance must therefore be explained
by the spread (masked, with ``az12`` at ``-clog12``) and one beyond it must not; a
sensor step has a shape no parameter produces.
"""

import pytest

from fdigen.model.model_file import builtin_model_path, load_model
from fdigen.tune.parameter_masking import masking_of_fault_cases, masking_text

DURATION = 300.0


def _effect(model, fault, size, t0=DURATION / 2):
    """Largest moving RMS (eq 22, window 100) over the noise of the fault's effect on the
    outputs after its onset, from two noise-free simulations."""
    import numpy as np

    from fdigen.design.evaluation import moving_rms
    from fdigen.sim.plant import FaultEvent, simulate

    y0 = simulate(model, DURATION, noise=False).y
    yf = simulate(model, DURATION, noise=False, faults=(FaultEvent(fault, t0, size),)).y
    k0 = int(round(t0 / model.fdi["sample_time"]))
    sigma = np.array([o.noise_std for o in model.outputs])
    return float(moving_rms((yf - y0)[k0:] / sigma, 100).max())


@pytest.fixture(scope="module")
def tanks():
    return load_model(builtin_model_path("three_tank"))


def test_a_fault_that_is_a_parameter_error_inside_the_tolerance_is_masked(tanks):
    res = masking_of_fault_cases(tanks, [("clog12", 0.05, False), ("clog12", 0.3, False)],
                                 tolerance=0.1, duration=DURATION, window=100, t_fault=0.0)
    inside, beyond = res[("clog12", 0.05, False)], res[("clog12", 0.3, False)]
    assert inside["masked"] and inside["remainder"] < 0.1 * inside["effect"]
    assert inside["effect"] > 5.0                 # a visible effect, explained by az12
    assert inside["parameters"]["az12"] == pytest.approx(-0.05, rel=0.1)
    assert abs(inside["parameters"]["az23"]) < 0.01 and abs(inside["parameters"]["az30"]) < 0.01
    assert not beyond["masked"] and beyond["remainder"] > 1.0
    assert beyond["parameters"]["az12"] == pytest.approx(-0.1)     # held at its bound
    assert "masked by the parameter spread" in masking_text("clog12", "step", "0.05x", inside)
    assert "the miss is the design's" in masking_text("clog12", "step", "0.3x", beyond)


def test_a_sensor_step_is_not_masked_and_a_narrower_tolerance_explains_less(tanks):
    cases = [("s1", 0.02, False), ("s1", 3.9e-5, True)]
    wide = masking_of_fault_cases(tanks, cases, tolerance=0.1, duration=DURATION,
                                  window=100)
    narrow = masking_of_fault_cases(tanks, cases, tolerance=0.01, duration=DURATION,
                                    window=100)
    step = wide[("s1", 0.02, False)]
    # 2 cm on a sensor of 0.5 mm noise, which the level loop then partly follows: the
    # largest window RMS of the effect, computed here from two plain simulations
    assert step["effect"] == pytest.approx(_effect(tanks, "s1", 0.02), rel=1e-9)
    assert 20.0 < step["effect"] <= 0.02 / 5e-4
    assert not step["masked"] and step["remainder"] > 0.5 * step["effect"]
    for case in cases:
        # the best explanation can only get worse when the spread narrows
        assert narrow[case]["remainder_rms"] >= wide[case]["remainder_rms"] * (1 - 1e-9)
        assert all(abs(v) <= 0.01 + 1e-12 for v in narrow[case]["parameters"].values())


def test_a_fault_under_the_noise_is_said_to_be_so(tanks):
    """A 0.2 mm level offset on 0.5 mm of noise: at most 0.4 sigma in any window; the
    text says the size is the problem, not the parameters."""
    res = masking_of_fault_cases(tanks, [("s1", 2e-4, False)], tolerance=0.1,
                                 duration=DURATION, window=100)
    entry = res[("s1", 2e-4, False)]
    assert entry["effect"] == pytest.approx(_effect(tanks, "s1", 2e-4), rel=1e-9)
    assert entry["effect"] <= 0.4
    assert entry["below_noise"] and entry["masked"]
    text = masking_text("s1", "step", "0.0002 m", entry)
    assert "under the sensor noise" in text and "spread" not in text

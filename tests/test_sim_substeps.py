"""The simulator's RK4 sub-steps: chosen stable by default, an unstable explicit count refused.

The plant is the first-time user's DC servo (encoder only, 50 ms samples, armature mode
-Ra/La = -2000 1/s) written as they wrote it, without ``simulation.substeps``: 10 sub-steps
(the old default) moved the motor 14.3 rad in one 50 ms sample of 0.5 V and clamped it
at its 20 rad limit.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from fdigen.design.config import read_fdi_config
from fdigen.design.parallel_model import check_parallel_model_step
from fdigen.errors import DesignError, ModelFileError
from fdigen.model.model_file import load_model
from fdigen.sim.plant import simulate
from fdigen.sim.substeps import simulation_substeps

SERVO = Path(__file__).parent / "data" / "newuser" / "dc_servo_50ms.toml"


def _servo(tmp_path, extra=""):
    path = tmp_path / "servo.toml"
    path.write_text(SERVO.read_text().replace("fdi.substeps = 40", "fdi.substeps = 40" + extra))
    return load_model(str(path))


def _exact_first_sample(model, volts, dt):
    """th after one sample of ``volts`` held: the ZOH solution of the linear motor."""
    v = {q.name: q.value for q in model.parameters}
    A = np.array([[0, 1, 0], [0, -v["b"] / v["J"], v["Kt"] / v["J"]],
                  [0, -v["Kt"] / v["La"], -v["Ra"] / v["La"]]])
    B = np.array([0, 0, 1 / v["La"]])
    M = expm(np.block([[A, B[:, None]], [np.zeros((1, 4))]]) * dt)
    return (M[:3, 3] * volts)[0]


def test_default_substeps_are_the_least_stable_count_and_the_motion_is_physical(tmp_path):
    model = _servo(tmp_path)
    dt = 0.05
    # the same count the FDI design asks for with fdi.substeps = 10
    assert simulation_substeps(model, dt) == 36
    with pytest.raises(DesignError, match=r"use substeps >= 36"):
        check_parallel_model_step(model, replace(read_fdi_config(model), substeps=10))
    sim = simulate(model, 0.5, noise=False)
    assert sim.u[0, 0] == pytest.approx(0.5)
    exact = _exact_first_sample(model, 0.5, dt)
    assert 0.02 < exact < 0.04
    assert sim.y[1, 0] == pytest.approx(exact, rel=1e-3)      # was 14.3 rad
    assert np.abs(sim.y[:, 0]).max() < 2.0                    # never near the 20 rad limit


def test_an_explicit_unstable_count_is_refused_and_a_stable_one_kept(tmp_path):
    with pytest.raises(ModelFileError, match=r"simulation\.substeps.*-1997.*use substeps >= 36"):
        simulate(_servo(tmp_path, "\nsimulation.substeps = 20"), 0.5, noise=False)
    model = _servo(tmp_path, "\nsimulation.substeps = 40")
    assert simulation_substeps(model, 0.05) == 40
    sim = simulate(model, 0.5, noise=False)
    assert sim.y[1, 0] == pytest.approx(_exact_first_sample(model, 0.5, 0.05), rel=1e-3)


@pytest.mark.parametrize("name, count", [("dc_motor", 10), ("three_tank", 4),
                                         ("heat_exchanger", 2)])
def test_shipped_models_keep_their_counts(name, count):
    model = load_model(name)
    assert simulation_substeps(model, float(model.fdi["sample_time"])) == count

"""A derivative term for the simulation's PI controllers (`kd`, `td`): a user's magnetic
levitation rig is unstable open loop and no static or PI law on its position stabilises
it; the user had to add an analog differentiator to the plant as a hidden state (which
then sent discover to its slow output-error loop).

The plant here: ``x'' = a x + u`` (a point pushed from the origin), the position
measured, a step reference of 0.1 m.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fdigen.errors import ModelFileError
from fdigen.model.model_file import load_model, parse_model_text
from fdigen.sim.plant import simulate

PLANT = Path(__file__).parent / "data" / "controllers" / "unstable_point_pid.toml"


def test_the_derivative_damps_what_the_pi_alone_cannot():
    with_d = load_model(PLANT)
    text = PLANT.read_text()
    assert "kd = 6.0" in text
    without = parse_model_text(text.replace("kd = 6.0", "kd = 0.0"), source="pi.toml")
    a = simulate(with_d, noise=False)
    b = simulate(without, noise=False)
    err_a = np.abs(a.y[-300:, 0] - 0.1)
    err_b = np.abs(b.y[-300:, 0] - 0.1)
    assert err_a.max() < 0.01 < 0.1 < err_b.max()
    # no kick at the first sample: the command is kp * e alone (the filter holds nothing)
    assert a.u[0, 0] == pytest.approx(20.0 * 0.1, rel=1e-12)
    # at the second, the backward difference of the measurement over td (td > dt)
    m0, m1 = a.y[0, 0], a.y[1, 0]
    i1 = 0.01 * (0.1 - m0)
    expected = 20.0 * (0.1 - m1) + 0.5 * i1 - 6.0 * (m1 - m0) / 0.02
    assert a.u[1, 0] == pytest.approx(expected, rel=1e-9)


def test_a_negative_filter_time_is_refused():
    with pytest.raises(ModelFileError, match="td"):
        parse_model_text(PLANT.read_text().replace("td = 0.02", "td = -1.0"), source="x.toml")

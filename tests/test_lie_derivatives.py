"""The output derivatives along the dynamics, two ways: sympy's symbolic series
(:mod:`fdigen.derive.lie_derivatives`) and CasADi's algorithmic differentiation
(:mod:`fdigen.derive.lie_numeric`, what the derivations use; 0.1 s where sympy took 2-4 s
on the cylinder and a cart-pole). They must agree at seeded points of every kind of plant
the tests hold, and for a linear model be the Markov parameters."""

from pathlib import Path

import numpy as np
import pytest
import sympy as sp

from fdigen.derive.lie_derivatives import lie_series
from fdigen.derive.lie_numeric import lie_values
from fdigen.derive.linearisation import linearise, numeric, operating_point_substitution
from fdigen.design.analytic_isolability import _points
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data"
PLANTS = ["pneumatic_cylinder", "three_tank", "dc_motor", "heat_exchanger",
          str(DATA / "newuser18" / "cartpole.toml"), str(DATA / "newuser12" / "battery_orig.toml"),
          str(DATA / "newuser23" / "mixing_tank_mass.toml"),
          str(DATA / "newuser25" / "batt.toml"), str(DATA / "newuser" / "hvac_zone.toml")]


def _close(a, b, floor: float = 0.0) -> bool:
    """Equal to 1e-9 of the larger's magnitude, or to 1e-12 of ``floor`` (the largest
    entry of the whole series at that point: a symbolic residue of -3e-21 where the
    numeric series has an exact 0)."""
    scale = max(float(np.max(np.abs(a), initial=0.0)), float(np.max(np.abs(b), initial=0.0)))
    return a.shape == b.shape and float(np.max(np.abs(a - b), initial=0.0)) <= max(
        1e-9 * scale, 1e-12 * floor)


@pytest.mark.parametrize("plant", PLANTS)
def test_the_numeric_series_is_the_symbolic_one(plant):
    model = load_model(plant)
    n = len(model.states)
    points = _points(model, 3)
    fast = lie_values(model, points, n)
    assert fast is not None
    series = lie_series(model, order=n)
    assert series.complete
    checked = 0
    for point, values in zip(points, fast):
        if values is None:
            continue
        subs = operating_point_substitution(model, point)
        floor = max(float(np.max(np.abs(v), initial=0.0))
                    for v in [*values[0], *(b for row in values[1] for b in row)])
        for g, v in zip(series.gradients, values[0]):
            assert _close(numeric(g, subs), v, floor)
        for row, vrow in zip(series.fault_blocks, values[1]):
            for b, v in zip(row, vrow):
                assert _close(numeric(b, subs), v, floor)
        checked += 1
    assert checked >= 2


def test_for_a_linear_model_the_series_is_the_markov_parameters():
    """The DC motor is linear: dPhi_k/dx = C A^k and B_km = C A^(k-1-m) E (F for m = k)."""
    model = load_model("dc_motor")
    n = len(model.states)
    (values,) = lie_values(model, [dict(model.operating_point)], n)
    lin = linearise(model)
    A, C, E, F = lin.A, lin.C, lin.E, lin.F
    for k in range(n + 1):
        assert _close(values[0][k], C @ np.linalg.matrix_power(A, k))
        for m in range(k + 1):
            want = F if m == k else C @ np.linalg.matrix_power(A, k - 1 - m) @ E
            assert _close(values[1][k][m], want)


def test_a_measured_expression_is_differentiated_through_the_outputs():
    model = load_model("three_tank")
    y1, y3 = (o.symbol for o in model.outputs if o.name in ("y1", "y3"))
    m = sp.Matrix([y1 - 2 * y3])
    point = dict(model.operating_point)
    (values,) = lie_values(model, [point], 2, faults=[], measurement=m)
    (full,) = lie_values(model, [point], 2, faults=[])
    rows = {o.name: i for i, o in enumerate(model.outputs)}
    for k in range(3):
        want = full[0][k][rows["y1"]] - 2 * full[0][k][rows["y3"]]
        assert _close(values[0][k], want[None, :])


def test_the_rank_test_is_the_same_on_the_symbolic_path(monkeypatch):
    """Where CasADi cannot take the equations (a function it is not given), the symbolic
    series answers the rank test: the same answer."""
    import fdigen.derive.lie_numeric as lie_numeric
    from fdigen.design.analytic_isolability import analytic_isolability

    model = load_model(str(DATA / "newuser23" / "mixing_tank_mass.toml"))
    fast = analytic_isolability(model)
    monkeypatch.setattr(lie_numeric, "lie_values", lambda *a, **k: None)
    assert analytic_isolability(model) == fast

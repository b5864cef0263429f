"""A user's data loop on two rigs emulated by their own simulators (tests/data/newuser16):
two tanks in cm whose model was never tuned (a 3 s lag on level 2, 1 mm quantisation,
gaps interpolated), and a DC servo with a gearbox, its encoder quantised to 4096 counts."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.discover.locate import prepare
from fdigen.discover.noise import noise_level, quantisation_step
from fdigen.discover.output_loop import hidden_states
from fdigen.model.model_file import load_model
from fdigen.sim.plant import simulate

DATA = Path(__file__).parent / "data" / "newuser16"


@pytest.mark.parametrize("q, sigma", [(2 * np.pi / 4096, 0.0), (0.1, 0.042), (0.01, 0.042),
                                      (0.0, 0.042)])
def test_the_noise_of_a_quantised_sensor_is_its_quantisation_noise(q, sigma):
    """A quantised encoder read 6e-10 rad of noise (its second differences are mostly 0,
    and the repeated values were left out as if saturated): the verdict then said 7.3e5x
    the noise and the error bars were 1e-9 relative. Now the estimate is the noise plus
    the quantisation's q^2/12, to 5 %."""
    rng = np.random.default_rng(0)
    t = np.arange(20000) * 1e-3
    y = np.sin(2 * np.pi * 0.5 * t) + sigma * rng.standard_normal(t.size)
    if q:
        y = np.round(y / q) * q
        assert quantisation_step(y) == pytest.approx(q, rel=1e-9)
    else:
        assert quantisation_step(y) == 0.0
    truth = np.sqrt(sigma ** 2 + q ** 2 / 12)
    assert noise_level(y)[0] == pytest.approx(truth, rel=0.05)


def test_a_gearbox_speed_is_the_derivative_of_the_measured_angle():
    """``th' = w/N``: w was called hidden and discover fell back to the output-error loop;
    it is ``N dth/dt`` (the equation error's second-order equation)."""
    model = load_model(str(DATA / "servo.toml"))
    assert hidden_states(model) == []
    sim = simulate(model, 2.0, noise=False, seed=1)
    data = prepare(model, sim.t, sim.u, sim.y, window=0.05, smooth=0.01)
    assert data.kind["w"] == "second" and data.source["w"] == "th"
    w = model.state_index("w")
    inner = slice(50, -50)
    span = np.ptp(sim.x[:, w])
    assert np.max(np.abs(data.xs[inner, w] - sim.x[inner, w])) < 0.02 * span


def test_discover_and_commission_a_model_never_tuned(tmp_path):
    """discover filled the file's R1 and R2 from the log, then ended in exit 2 on the
    derived R3; commission ended in exit 2 on the commissioned file's missing R1, R2."""
    runner = CliRunner()
    log, model = DATA / "tanks_lagged_l2.csv", DATA / "two_tank_untuned.toml"
    res = runner.invoke(main, ["discover", str(log), "--model", str(model), "--out",
                               str(tmp_path / "d"), "--no-build", "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    note = next(w for w in info["warnings"] if "no threshold for" in w)
    assert all(f"{r} (set to" in note for r in ("R1", "R2", "R3")), note
    res = runner.invoke(main, ["commission", str(log), "--model", str(model), "--out",
                               str(tmp_path / "c"), "--runs", "4", "--validation-runs", "2",
                               "--no-build", "--json"])
    assert res.exit_code in (0, 1), res.output
    info = json.loads(res.output)
    assert set(info["thresholds"]) >= {"R1", "R2", "R3"}
    assert all(v > 0 for v in info["thresholds"].values())
    assert info["thresholds_before"] == {}
    assert not any(w.startswith("the augmented design has residual") for w in info["warnings"])
    written = load_model(info["model_file"]).fdi["thresholds"]
    assert {k: pytest.approx(v) for k, v in written.items()} == info["thresholds"]
    # the fit's verdict is part of commission's summary (a user's servo: "found: no
    # effect" and "usable" while discover had said 12.4x the noise)
    from fdigen.commission.report import text_report

    assert isinstance(info["explains"], bool) and set(info["noise_ratio"]) == {"L1", "L2"}
    poor = {**info, "explains": False, "noise_ratio": {"L1": 1.1, "L2": 7.25}}
    assert "does not explain the log (L2 at 7.25x its sensor noise)" in text_report(poor)
    assert "does not explain" not in text_report({**info, "explains": True})
    # no warning of discover on the worst output: the library does not hold what is
    # missing (a user's thermocouple lag: "discover's warnings name what may be missing",
    # and none concerned it)
    silent = " ".join(text_report({**poor, "warnings": []}).split())
    assert "no warning of discover concerns L2" in silent and "a sensor's lag" in silent
    named = {**poor, "warnings": ["L2 reads 3 % high"]}
    assert "discover's warnings name what may be missing" in text_report(named)


def test_a_correlation_between_fitted_parameters_does_not_depend_on_their_units():
    """A user's fit printed correlations of -16.5 and -20.1: the pseudo-inverse of J^T J
    with one column 1e-14 of the others. The same fit with that parameter in other units
    (its column scaled) must give the same correlation, inside [-1, 1]."""
    from types import SimpleNamespace

    from fdigen.discover.fit_checks import identifiability

    rng = np.random.default_rng(3)
    v = rng.standard_normal((400, 4))
    base = np.column_stack([v[:, 0], 0.99 * v[:, 0] + 0.1 * v[:, 1], v[:, 2], v[:, 3]])
    cov = np.linalg.inv(base.T @ base)[:3, :3]
    truth = cov[0, 1] / np.sqrt(cov[0, 0] * cov[1, 1])
    assert abs(truth) > 0.95
    model = load_model(str(DATA / "servo.toml"))
    for scale in (1.0, 1e-14, 1e9):
        J = base * np.array([1.0, scale, 1.0, 1.0])
        fit = SimpleNamespace(null_directions=(), held={}, J=J, free=["R", "b", "Km"],
                              params={"R": 2.0, "b": 1e-5, "Km": 0.05},
                              std={"R": 0.1, "b": 1e-6, "Km": 0.001})
        info, _ = identifiability(model, fit, {"R": 2.0, "b": 1e-5, "Km": 0.05})
        (pair,) = info["correlated"]
        assert pair["parameters"] == ["R", "b"]
        assert pair["correlation"] == pytest.approx(truth, abs=1e-6), scale


def test_an_effect_that_is_a_declared_fault_is_named_with_its_size():
    """The library's effects on the user's two tanks, against the model's own faults:
    a leak through the tank-1 orifice shape is ``leak1``, a sensor offset is ``s1``/``s2``,
    a gain loss of the pump voltage is ``pump``; the linear leak, the dead band and the
    inter-tank flow loss are none. The size is the fault's: the effect at its value and
    the fault at that size change the equations by the same amount."""
    import sympy as sp

    from fdigen.discover.declared_faults import declared_fault_of
    from fdigen.discover.effects import _model_symbols, library
    from fdigen.model.expression import parse_expression

    model = load_model(str(DATA / "two_tank_kp_known.toml"))
    found = {e.name: declared_fault_of(model, e, 0.7) for e in library(model)}
    assert {k: v["fault"] for k, v in found.items() if v} == {
        "sensor_offset_y1": "s1", "sensor_offset_y2": "s2", "leak_sqrt_h1": "leak1",
        "gain_loss_u": "pump"}
    effect = next(e for e in library(model) if e.name == "leak_sqrt_h1")
    size = found["leak_sqrt_h1"]["size"]
    theta = sp.Symbol(effect.parameters[0].name, real=True)
    term = parse_expression(effect.text("h1"), {**_model_symbols(model), theta.name: theta})
    point = {s.symbol: 12.0 + k for k, s in enumerate(model.states)}
    point.update({u.symbol: 5.0 for u in model.inputs})
    point.update({f.symbol: 0.0 for f in model.faults})
    f0 = model.f(with_faults=True).xreplace(point).xreplace(model.parameter_values)
    leak = model.fault("leak1").symbol
    f1 = model.f(with_faults=True).xreplace({**point, leak: size}).xreplace(
        model.parameter_values)
    change = float(f1[model.state_index("h1")] - f0[model.state_index("h1")])
    added = float(model.expand(term).xreplace({**point, theta: 0.7}).xreplace(
        model.parameter_values))
    assert added == pytest.approx(change, rel=1e-12)
    assert f1[model.state_index("h2")] == f0[model.state_index("h2")]


def test_commission_does_not_commit_a_declared_fault_found_on_its_log(tmp_path):
    """A log of the tanks with leak1 open from the start (2x its test size): discover
    finds leak_sqrt_h1 at the leak's size; commission had written it into the healthy
    model (the design then reads the leak as normal). Now it is not committed, and the
    verdict refuses the design naming the fault."""
    import sympy as sp

    from fdigen.sim.plant import FaultEvent

    model_path = DATA / "two_tank_kp_known.toml"
    model = load_model(str(model_path))
    from fdigen.sim.log import write_log

    sim = simulate(model, 1200.0, faults=(FaultEvent("leak1", 0.0, 0.06),), seed=2)
    log = tmp_path / "leaky.csv"
    write_log(log, sim.columns())
    res = CliRunner().invoke(main, ["commission", str(log), "--model", str(model_path),
                                    "--out", str(tmp_path / "c"), "--runs", "4",
                                    "--validation-runs", "2", "--no-build", "--json"])
    info = json.loads(res.output)
    (found,) = info["declared_faults_found"]
    assert found["fault"] == "leak1" and found["size"] == pytest.approx(0.06, rel=0.1)
    assert info["effects"] == []
    committed = load_model(info["model_file"])
    assert [q.name for q in committed.parameters] == [q.name for q in model.parameters]
    assert committed.f() == model.f().xreplace({  # the calibrated values, no leak term
        q.symbol: sp.Symbol(q.name, real=True) for q in model.parameters})
    assert not info["verdict"]["usable"] and res.exit_code != 0
    assert any("declared fault leak1" in f for f in info["verdict"]["failures"])

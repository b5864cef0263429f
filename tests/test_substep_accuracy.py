"""The plant simulator's RK4 sub-steps are checked for accuracy on the run asked for.

A clean room's door opened wide (round 50) took the pressures together through
``sqrt(|p1 - p2|) sign(p1 - p2)``; at the 10 sub-steps stable at the operating point the
simulated room stayed 19 Pa above the anteroom, and nothing said so.
``tests/data/substep_accuracy/two_rooms.toml`` is that plant open loop, whose truth
SciPy's Radau integrates to 1e-10.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main

MODEL = Path(__file__).parent / "data" / "substep_accuracy" / "two_rooms.toml"


def _truth(door: float, t_fault: float, t_end: float) -> np.ndarray:
    """The two pressures at ``t_end`` with the door opened by ``door`` at ``t_fault``."""
    from scipy.integrate import solve_ivp

    from fdigen.model.model_file import load_model

    m = load_model(MODEL)
    v = {q.name: q.value for q in m.parameters}
    q_in = float(m.operating_point["q"])

    def orifice(area, dp):
        return v["Cd"] * area * np.sqrt(2 * abs(dp) / v["rho"]) * np.sign(dp)

    def rhs(_, p, opened):
        q12 = orifice(v["A12"] + opened, p[0] - p[1])
        return [v["Pa0"] / v["V1"] * (q_in - q12 - orifice(v["A1"], p[0])),
                v["Pa0"] / v["V2"] * (q12 - orifice(v["A2"], p[1]))]

    p0 = [m.operating_point["p1"], m.operating_point["p2"]]
    before = solve_ivp(rhs, (0, t_fault), p0, args=(0.0,), method="Radau", rtol=1e-10,
                       atol=1e-10)
    after = solve_ivp(rhs, (t_fault, t_end), before.y[:, -1], args=(door,),
                      method="Radau", rtol=1e-10, atol=1e-10)
    return after.y[:, -1]


def _simulate(tmp_path, *args):
    log = tmp_path / "run.csv"
    res = CliRunner().invoke(main, ["simulate", "--model", str(MODEL), "-o", str(log), *args])
    assert res.exit_code == 0, res.output
    data = np.genfromtxt(log, delimiter=",", names=True, comments="#")
    truth = json.loads(log.with_suffix(".json").read_text())
    return res, data, truth


def test_a_door_opened_wide_is_simulated_as_the_plant(tmp_path):
    """At the stable count the room 2 pressure ends 1.6 Pa (16 noise std) below the
    truth; the log is now the run whose doubling agrees within the noise, and it is
    within the noise (0.1 Pa) of Radau."""
    from fdigen.model.model_file import load_model
    from fdigen.sim.plant import FaultEvent, simulate

    res, data, truth = _simulate(tmp_path, "--fault", "door@20=0.5")
    sub = truth["substeps"]
    assert sub["converged"] and sub["used"] > sub["stable"]
    assert f"raised from {sub['stable']} to {sub['used']}" in res.output
    expect = _truth(0.5, 20.0, 60.0)
    tail = slice(-500, None)                       # the last 10 s, settled
    got = np.array([data["y1"][tail].mean(), data["y2"][tail].mean()])
    assert np.all(np.abs(got - expect) < 0.1), (got, expect)
    # what the stable count alone simulates: the bias the check removed
    m = load_model(MODEL)
    stable = simulate(m, faults=(FaultEvent("door", 20.0, 0.5),), substeps=sub["stable"],
                      noise=False)
    assert np.max(np.abs(stable.y[-1] - expect)) > 0.5


def test_a_healthy_run_keeps_the_stable_count(tmp_path):
    res, _, truth = _simulate(tmp_path)
    assert truth["substeps"]["used"] == truth["substeps"]["stable"]
    assert truth["substeps"]["converged"]
    assert "sub-steps" not in res.output


def test_a_run_that_does_not_converge_says_so(tmp_path):
    """The door at 1.8 m^2: the flows' slope is without bound where the pressures meet,
    and 16 times the stable count still changes the log by more than its noise."""
    res, _, truth = _simulate(tmp_path, "--fault", "door@20=1.8")
    assert not truth["substeps"]["converged"]
    assert "does not converge in its RK4 sub-steps" in res.output
    assert f"the log is the run at {truth['substeps']['used']}" in res.output


def _result(t, y):
    return SimpleNamespace(t=np.asarray(t, float), y=np.asarray(y, float))


def test_disagreement_is_over_the_noise_and_ignores_a_few_switched_samples():
    from fdigen.sim.substep_accuracy import ACCURATE_FRACTION, output_disagreement

    t = np.arange(1000) * 0.1
    base = np.sin(t)[:, None]
    shifted = base + 0.5 * ACCURATE_FRACTION       # half the tolerance of noise 1
    assert output_disagreement(_result(t, base), _result(t, shifted), [1.0])[0] == \
        pytest.approx(0.5)
    switched = base.copy()
    switched[500:510] += 10.0                      # 1 % of the samples switched apart
    assert output_disagreement(_result(t, base), _result(t, switched), [1.0])[0] == 0.0
    lost = base.copy()
    lost[700] = np.nan                             # finite in one run, not in the other
    ratio, k, when = output_disagreement(_result(t, base), _result(t, lost), [1.0])
    assert ratio == np.inf and k == 0 and when == pytest.approx(70.0)


def test_the_campaign_simulates_its_runs_at_the_accurate_count(tmp_path):
    """A door whose test size opens it wide: every run of the campaign is raised to the
    count the single simulation converges at, and says so."""
    from fdigen.model.model_file import load_model
    from fdigen.sim.plant import FaultEvent, simulate
    from fdigen.sim.substep_accuracy import converged_simulation
    from fdigen.sim.substeps import simulation_substeps
    from fdigen.tune.cases import make_cases
    from fdigen.tune.settings import TuneSettings
    from fdigen.tune.substep_probe import accurate_campaign

    wide = tmp_path / "two_rooms.toml"
    wide.write_text(MODEL.read_text().replace("test_size = 0.05", "test_size = 0.5"))
    m = load_model(wide)
    cases = make_cases(m, TuneSettings(runs=2, validation_runs=1, duration=60.0,
                                       fault_factors=(1.0,), fault_starts=1))
    raised, info = accurate_campaign(m, cases)
    stable = simulation_substeps(m, 0.02)
    alone = converged_simulation(
        m, lambda n: simulate(m, 60.0, faults=(FaultEvent("door", 30.0, 0.5),), substeps=n),
        stable)
    assert info is not None and info["converged"] and info["start"] == stable
    assert info["used"] == alone.used > stable
    assert "door at 0.5 from 30 s" in info["text"]
    assert {c.substeps for runs in raised.values() for c in runs} == {info["used"]}
    # tune's searches run the same campaign on a file whose [fdi] differs: probed once
    calls = []

    def counting(fn, items):
        calls.append(len(items))
        return [fn(*a) for a in items]

    other = dataclasses.replace(m, fdi={**m.fdi, "realign_noise_scale": 0.05})
    again, info2 = accurate_campaign(other, cases, counting)
    assert calls == [] and info2 == info
    # the same draws otherwise: only the count changed
    assert [dataclasses.replace(c, substeps=None) for c in raised["fault"]] == \
        [dataclasses.replace(c, substeps=None) for c in cases["fault"]]


def test_a_state_on_its_limit_ends_the_comparison(cylinder):
    """A clamp (a piston on its end stop) is first order at any sub-step count: the
    runs are compared up to the first arrival on a limit, not after (the cylinder's dead
    position sensor raised every cylinder campaign to twice its sub-steps for it)."""
    import sympy as sp

    from fdigen.sim.substep_accuracy import first_limit_contact, output_disagreement

    m = cylinder
    i = [s.name for s in m.states].index("x")
    stroke = float(sp.sympify(m.states[i].limits[1]).xreplace(m.parameter_values))
    t = np.arange(100) * 0.01
    x = np.tile([float(v) for v in (3e5, 3e5, 0.5 * stroke, 0.0)], (100, 1))
    y = np.zeros((100, len(m.outputs)))
    a = SimpleNamespace(t=t, y=y, x=x, model=m)
    assert first_limit_contact(a) == 100
    x2 = x.copy()
    x2[60:, i] = stroke                            # on the end stop from sample 60
    b = SimpleNamespace(t=t, y=y.copy(), x=x2, model=m)
    assert first_limit_contact(b) == 60
    sig = [1.0] * len(m.outputs)
    b.y[70:, 0] = 100.0                            # after the contact: not compared
    assert output_disagreement(a, b, sig)[0] == 0.0
    b.y[30:, 0] = 100.0                            # before it: compared
    assert output_disagreement(a, b, sig)[0] > 1.0
    start = SimpleNamespace(t=t, y=y, x=np.tile(x2[60:61], (100, 1)), model=m)
    assert first_limit_contact(start) == 100       # starting on it is no arrival

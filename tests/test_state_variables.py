"""The same plant written in other state variables derives the same diagnosis.

A first-time user (2026-11-28) wrote a brine mixing tank twice: with the salt
concentration ``c`` as a state, and with the salt mass ``M`` (``c = M/(A h)`` in
``[definitions]``). Another wrote a fed-batch bioreactor with concentrations ``X, S`` and
with masses ``mX = X V, mS = S V``. The physics is the same; fdigen derived different
tables, diagnosed the same scenario differently and called pairs "achievable" in one
spelling only:

- signatures read the linearisation's Markov parameters ``C A^k E`` at points away from
  equilibrium, which depend on the coordinates (the mass spelling lost the leak from the
  conductivity residual): they are now the Lie derivatives' gradients
  (:mod:`fdigen.derive.lie_derivatives`), and so is the rank test of achievable
  isolability;
- a sensor reading a mass over a measured volume (``OD = kod mX/V``) measured nothing:
  with the volume measured it now measures the mass (``compound_sensor_maps``), and
  sub-models are driven by it;
- a fault entering two states in a state-dependent ratio (a valve in the level and the
  concentration) or three states (a feed diluting biomass and substrate) was never
  cancelled: a balance the fault cannot move is found as a first integral of its
  direction (:mod:`fdigen.design.first_integral`), and any two measured states it enters
  are tried.
"""

import json
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.design.first_integral import first_integral
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser23"


def _inspect(path, monkeypatch, tmp_path) -> dict:
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    res = CliRunner().invoke(main, ["inspect", "--json", "--model", str(path)])
    assert res.exit_code == 0, res.output
    return json.loads(res.output)


def _columns(info) -> list:
    """The signature table as a sorted list of columns (the faults each residual responds
    to): the same table whatever the residuals are called."""
    faults = sorted(info["signature_table"][next(iter(info["signature_table"]))])
    return sorted(tuple(info["signature_table"][r][f] for f in faults)
                  for r in info["signature_table"])


@pytest.mark.parametrize("pair", [("mixing_tank", "mixing_tank_mass"),
                                  ("bioreactor_conc", "bioreactor_mass")])
def test_two_spellings_of_the_states_derive_the_same_isolation(pair, monkeypatch,
                                                               tmp_path):
    a, b = (_inspect(DATA / f"{name}.toml", monkeypatch, tmp_path) for name in pair)
    for key in ("achieved", "achievable"):
        assert a["isolability"][key] == b["isolability"][key], key
    assert a["isolability"]["achievable_not_achieved"] == []
    assert b["isolability"]["achievable_not_achieved"] == []
    # the residuals comparing one sensor with the whole model: the same signatures
    for r in a["paper_residuals"]:
        assert a["signature_table"][r] == b["signature_table"][r], r
    if pair[0] == "bioreactor_conc":
        # every fault isolated from every other, in both spellings, by the same table
        assert all(all(row) for row in a["isolability"]["achieved"])
        assert _columns(a) == _columns(b)


def test_the_mass_spelling_keeps_the_leak_in_the_conductivity_residual(monkeypatch,
                                                                       tmp_path):
    """``C A E`` of the mass spelling is 0 at every point (the leak removes water and
    salt in the tank's proportion); the leak reaches the probe through the level's
    effect on the dilution, which the second Lie derivative sees."""
    info = _inspect(DATA / "mixing_tank_mass.toml", monkeypatch, tmp_path)
    assert info["signature_table"]["Rk"]["leak"] == 1
    assert info["signature_table"]["Rk"]["clog"] == 1


def test_a_probe_of_a_mass_over_a_measured_volume_measures_the_mass():
    from fdigen.design.submodel import measured_states, state_from_sensor
    from fdigen.model.sensor_maps import compound_sensor_maps

    model = load_model(str(DATA / "bioreactor_mass.toml"))
    maps = compound_sensor_maps(model)
    assert {s: [m.output for m in ms] for s, ms in maps.items()} == {"mX": ["OD"],
                                                                     "mS": ["yS"]}
    assert measured_states(model) == {"V": "W", "mX": "OD", "mS": "yS"}
    # the inverse reads the probe and the load cell, and returns the mass
    inv = state_from_sensor(model, "mX", "OD")
    values = model.parameter_values
    W, OD = sp.Symbol("W", real=True), sp.Symbol("OD", real=True)
    V, mX = 6.3, 17.0
    p = {k.name: float(v) for k, v in values.items()}
    w = p["m0"] + p["rho"] * V
    od = p["kod"] * mX / V
    assert float(inv.xreplace({W: w, OD: od}).xreplace(values)) == pytest.approx(mX,
                                                                               rel=1e-12)


def test_a_balance_with_state_dependent_weights_cancels_the_fault(monkeypatch, tmp_path):
    """The hydrophore's pump enters the water level and the air pressure in the ratio
    (p + patm)/(H - h): the air mass (p + patm)(H - h) does not move with it, and is the
    residual blind to pump wear (an air leak moves it)."""
    info = _inspect(DATA / "hydrophore.toml", monkeypatch, tmp_path)
    blind = [r for r in info["extra_residuals"] if r["blind_to"] == "pump_wear"]
    assert blind, [r["description"] for r in info["extra_residuals"]]
    assert set(blind[0]["drivers"]) == {"h", "p"}
    name = blind[0]["residual"]
    assert info["signature_table"][name]["pump_wear"] == 0
    assert info["signature_table"][name]["air_leak"] == 1


@pytest.mark.parametrize("slope, expect", [
    ("(c1 - c)/h", "h*(c - c1)"),                  # brine valve: level and concentration
    ("(p + patm)/(H - h)", "(H - h)*(p + patm)"),  # pump: water level and air pressure
    ("-c/h", "c*h"),                               # dilution: concentration times volume
])
def test_first_integrals_of_fault_directions(slope, expect):
    h, c, p = (sp.Symbol(n, real=True) for n in ("h", "c", "p"))
    syms = {s.name: s for s in (h, c, p)}
    slope = sp.sympify(slope, locals=syms)
    xa, xb = (h, p) if "p" in str(slope) else (h, c)
    m = first_integral(slope, xa, xb)
    assert m is not None
    # constant along the direction, and the plain form (up to a constant factor)
    assert sp.simplify(sp.diff(m, xa) + sp.diff(m, xb) * slope) == 0
    ratio = sp.simplify(m / sp.sympify(expect, locals=syms))
    assert not ratio.free_symbols & {h, c, p}


def test_both_spellings_simulate_the_same_plant(tmp_path, monkeypatch):
    """The same fault scenario through the default `simulate` path: the logs of the two
    spellings agree to the integrator's accuracy (the states differ, the sensors not)."""
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    logs = {}
    for name in ("mixing_tank", "mixing_tank_mass"):
        out = tmp_path / f"{name}.csv"
        res = CliRunner().invoke(main, ["simulate", "--model", str(DATA / f"{name}.toml"),
                                        "--duration", "600", "--fault", "leak@200=0.3",
                                        "-o", str(out)])
        assert res.exit_code == 0, res.output
        logs[name] = np.genfromtxt(out, delimiter=",", names=True)
    a, b = logs["mixing_tank"], logs["mixing_tank_mass"]
    for col in ("level_mA", "cond"):
        assert np.max(np.abs(a[col] - b[col])) < 1e-6 * np.max(np.abs(a[col])), col
    # the leak did move the level loop: the scenario is not trivially equal
    assert np.ptp(a["u2"][a["t"] > 200]) > 1.0


DATA25 = Path(__file__).parent / "data" / "newuser25"


def test_a_separator_written_with_moles_derives_what_level_and_pressure_do(monkeypatch,
                                                                           tmp_path):
    """A user's gas-liquid separator, states (L, P) or (VL, ng) with P = ng R T/(A H -
    VL) in [definitions]: the pressure transmitter measures the moles once the level
    transmitter gives the liquid volume. The mole spelling had lost its residual on the
    liquid balance (8 pairs unseparated, 2 in the other) and blamed "the unmeasured ng"."""
    a, b = (_inspect(DATA25 / f"{name}.toml", monkeypatch, tmp_path)
            for name in ("sep_a", "sep_b"))
    for key in ("achieved", "achievable"):
        assert a["isolability"][key] == b["isolability"][key], key
    assert b["isolability"]["achievable_not_achieved"] == []
    assert b["sensor_maps"]["measures"]["yp"]["state"] == "ng"
    assert b["sensor_maps"]["measures"]["yp"]["with"] == ["VL"]
    # the liquid balance driven by the moles read from the pressure and the simulated VL
    assert any(r["drivers"] == {"ng": "yp"} and r["equations"] == ["VL"]
               for r in b["extra_residuals"])


def test_a_differential_pressure_over_a_measured_level_drives_sub_models(monkeypatch,
                                                                         tmp_path):
    """Two tanks, the first read by a differential-pressure cell across both (h1 - h2),
    the second by a level sensor: every fault pair is isolated (the pump was not
    isolable from four others)."""
    info = _inspect(DATA25 / "tanks.toml", monkeypatch, tmp_path)
    assert all(all(row) for row in info["isolability"]["achieved"])
    assert info["sensor_maps"]["measures"]["ydp"]["with"] == ["h2"]


def test_an_ntc_read_through_a_divider_is_inverted_without_exhausting_memory():
    """sympy's solve of ``y = V Rf/(Rf + R25 exp(B (1/(T + 273.15) - 1/298.15)))`` ran a
    user's inspect past 16 GB: the inverse of the composed functions is found first, and
    solve runs under a CPU budget."""
    from fdigen.model.sensor_maps import sensor_maps

    model = load_model(str(DATA25 / "batt.toml"))
    (ntc,) = sensor_maps(model)["Tc"]
    values = model.parameter_values
    y = sp.Symbol("yT", real=True)
    for T in (15.0, 25.0, 50.0):
        reading = ntc.forward.xreplace({model.states[1].symbol: sp.Float(T)}).xreplace(values)
        back = float(ntc.inverse.xreplace({y: reading}).xreplace(values))
        assert back == pytest.approx(T, abs=1e-9)


def test_a_sensor_fault_on_a_measured_input_says_how_to_write_it(tmp_path):
    """A battery's current sensor is logged as the plant's input ``I``; a user wrote its
    offset as a sensor fault and was told only which outputs a sensor fault may target."""
    from fdigen.errors import ModelFileError

    text = (DATA25 / "batt.toml").read_text()
    text = text.replace('[faults.cs_offset]\nlocation = "actuator"',
                        '[faults.cs_offset]\nlocation = "sensor"')
    path = tmp_path / "batt.toml"
    path.write_text(text)
    with pytest.raises(ModelFileError) as exc:
        load_model(str(path))
    assert 'location = "actuator"' in str(exc.value) and '"-cs_offset"' in str(exc.value)

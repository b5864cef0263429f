"""Round 46: plants written from the README alone (tests/data/newuser46).

A vehicle's lateral dynamics (gyro in deg/s, accelerometer in g reading the states and
the steering input, speed a measured input in km/h), a wind-turbine drivetrain, and a
solar collector loop whose collector temperature is a PT100 read in ohms.
"""

from __future__ import annotations

import json
from pathlib import Path

import sympy as sp
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.design.residual_identity import same_key
from fdigen.model.expression import expression_text, parse_expression
DATA = Path(__file__).parent / "data" / "newuser46"


def _inspect(path):
    res = CliRunner().invoke(main, ["inspect", "--model", str(path), "--json"])
    assert res.exit_code == 0, res.output[-2000:]
    return json.loads(res.stdout)


def test_a_derived_residual_reading_an_input_is_inspected_and_built(tmp_path):
    """The accelerometer's balance reads the steering angle and the speed: inspect and
    build stopped at "field 'fdi', symbol 'dsw': undefined symbol" (exit 2), after tune
    had written a threshold for that residual."""
    info = _inspect(DATA / "vehicle_orig.toml")
    scales = info["residual_scales"]
    derived = [k for k in scales if k.startswith("R") and k[1:].isdigit()]
    assert derived, sorted(scales)
    compares = " ".join(scales[k]["compares"] for k in derived)
    assert "dsw" in compares and "v_kmh" in compares
    # its unit is that of an expression that names the inputs' units too
    assert any("dsw: deg" in scales[k]["unit"] for k in derived)
    res = CliRunner().invoke(main, ["build", "--model", str(DATA / "vehicle.toml"),
                                    "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output[-2000:]


def test_an_inverted_nonlinear_sensor_map_reads_back(tmp_path):
    """A PT100 in ohms, ``R0 (1 + A Tc + B Tc^2)``: its inverse is clipped at the even root
    (``sqrt(max(0, ...))``) and sympy printed ``Max``, which the model language does not
    know: inspect stopped at "symbol 'Max': unknown function" (exit 2), and the same plant
    in degC built."""
    info = _inspect(DATA / "solar.toml")
    texts = [v["compares"] for v in info["residual_scales"].values()]
    assert any("sqrt(max(0, " in t for t in texts)
    assert not any("Max(" in t for t in texts)
    _inspect(DATA / "solar_degc.toml")


def test_fdigens_texts_are_model_language_and_old_keys_still_match():
    x, y = sp.symbols("x y", real=True)
    expr = sp.Max(0, x - 1) + sp.Min(x, y) * sp.Abs(y)
    text = expression_text(expr)
    assert "Max" not in text and "Min" not in text and "Abs" not in text
    back = parse_expression(text, {"x": x, "y": y}, source="test", field="f")
    assert sp.simplify(back - expr) == 0
    # a key written by an earlier fdigen (sympy's names) is the same residual
    old = "Kalman filter: equations [T] driven by [], checked on Max(0, x - 1.50)"
    assert same_key(old, "Kalman filter: equations [T] driven by [], checked on "
                         "max(0, x - 1.5)")
    assert not same_key(old, "Kalman filter: equations [T] driven by [], checked on "
                             "min(0, x - 1.5)")


def test_a_division_by_an_input_whose_range_reaches_zero_is_warned_of():
    """The collector's efficiency divides by the irradiance G (range [0, 1000] W/m^2):
    inspect said nothing, and simulate stopped at t = 0 (night)."""
    import types

    from fdigen.design.design_warnings import domain_warnings
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    warns = _inspect(DATA / "solar_degc.toml")["warnings"]
    (hit,) = [w for w in warns if "not a finite real number" in w]
    assert hit.startswith("dTc/dt") and "G = 0" in hit
    # the same plant with G multiplied out, and the shipped models: nothing to say
    for m in [DATA / "solar_q.toml", *(resolve_model_path(n) for n in (
            "pneumatic_cylinder", "three_tank", "dc_motor", "heat_exchanger"))]:
        assert domain_warnings(types.SimpleNamespace(model=load_model(m))) == (), m


def test_why_a_pair_is_not_separated_names_the_fault_to_see():
    """R2 is blind to pump wear (and to the flow meter); inspect said "no residual blind
    to pump_wear", which R2's own line contradicted."""
    reasons = _inspect(DATA / "solar_q.toml")["isolability"]["not_achieved_reasons"]
    assert reasons == {"pump_wear": "a residual blind to pump_wear that sees flow_gain is "
                                    "allowed by the structure, but none of fdigen's "
                                    "constructions realises one here"}


def test_report_on_a_refused_design_says_so_first(tmp_path):
    """detect, build and inspect say a refused design first; report drew the figure and
    said nothing (round 49)."""
    import subprocess
    import sys

    model = DATA / "vehicle.toml"
    log = tmp_path / "veh.csv"
    run = [sys.executable, "-m", "fdigen.cli"]
    sim = subprocess.run([*run, "simulate", "--model", str(model), "-o", str(log),
                          "--duration", "2"], capture_output=True, text=True, timeout=600)
    assert sim.returncode == 0, sim.stderr[-2000:]
    rep = subprocess.run([*run, "report", str(log), "--model", str(model), "-o",
                          str(tmp_path / "r.png")], capture_output=True, text=True,
                         timeout=600)
    assert rep.returncode == 0, rep.stderr[-2000:]
    first = rep.stderr.strip().splitlines()[0]
    assert first.startswith("warning: this design was REFUSED"), rep.stderr[:500]

"""A measured input's sensor offset in discover's library, and ties the free run decides.

A buffer tank's inflow is read by a flow meter 0.4 L/min low (the plant gets 0.4 L/min
more than the log says). The equation error cannot tell that offset from a linear leak or
a level-sensor offset (dBIC -32.4, -32.6, -31.9: within 2 of each other); one free run of
the validation part can (1.47x the sensor noise against 6.09x and 3.73x). Before, the
library had no input offset and discover chose the leak: 6.31x the noise over one free
run, "does not explain".
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fdigen.discover.effects import library
from fdigen.model.expression import parse_expression
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data"
TANK = DATA / "input_offset" / "tank_flowmeter.toml"



def _rig():
    import importlib.util

    spec = importlib.util.spec_from_file_location("input_offset_rig",
                                                  DATA / "input_offset" / "rig.py")
    rig = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rig)
    return rig


def _offset_effect(model):
    return {e.name: e for e in library(model) if e.family == "input_offset"}


def test_a_measured_inputs_offset_acts_wherever_the_input_does():
    """Affine equations get ``gain * off``; a current squared in a heat balance gets the
    exact difference; the output reading the input too. Commanded inputs get none."""
    bat = load_model(DATA / "newuser43" / "battery_v1.toml")
    eff = _offset_effect(bat)["input_offset_I"]
    syms = {s.name: s.symbol for s in [*bat.parameters, *bat.states, *bat.inputs]}
    off = eff.parameters[0]
    assert off.name == "off_I" and off.unit == "A" and off.bounds == (-75.0, 75.0)
    terms = eff.terms(bat)
    I, o = syms["I"], terms["soc"].free_symbols - set(syms.values())
    (o,) = o
    f, h = bat.f(), bat.h()
    zero = {q.symbol: 0 for q in bat.faults}
    for k, s in enumerate(bat.states):      # f(I + off) - f(I), exactly
        want = (f[k].xreplace({I: I + o}) - f[k]).xreplace(zero)
        assert (terms[s.name] - want).expand() == 0, s.name
    want = (h[0].xreplace({I: I + o}) - h[0]).xreplace(zero)
    assert (terms["v_meas"] - want).expand() == 0
    assert "T_th" not in terms                # the thermistor does not read I
    # an input used in [definitions] only (a radiator: UA*v*(Tsup - Ta))
    zone = load_model(DATA / "newuser47" / "zone_naive.toml")
    effs = _offset_effect(zone)
    assert set(effs) == {"input_offset_Tsup", "input_offset_To"}
    assert "Ta" in effs["input_offset_Tsup"].states
    from fdigen.pipeline import resolve_model_path

    # the built-in tanks' pumps are commanded: no input offset
    assert not _offset_effect(load_model(resolve_model_path("three_tank")))
    # every term reads back through the model language's parser
    for model, e in [(bat, eff), *((zone, z) for z in effs.values())]:
        names = _symbols(model, e)
        for target in [*e.states, *e.outputs]:
            parse_expression(e.text(target), names, source="test", field=target)


def _symbols(model, e):
    import sympy as sp

    syms = {s.name: s.symbol for s in [*model.parameters, *model.states, *model.inputs]}
    syms.update({p.name: sp.Symbol(p.name, real=True) for p in e.parameters})
    return syms


@pytest.fixture(scope="module")
def discovered(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("io")
    log = tmp / "tank.csv"
    rig = _rig()
    rig.write_log(log)
    proc = subprocess.run([sys.executable, "-m", "fdigen.cli", "discover", str(log),
                           "--model", str(TANK), "--out", str(tmp / "d"), "--no-build",
                           "--no-fdi", "--json"], capture_output=True, text=True,
                          env={**os.environ, "FDIGEN_CACHE": str(tmp / "cache")},
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout)


def test_discover_finds_the_meters_offset_where_the_free_run_decides_the_tie(discovered):
    info = discovered
    assert info["effects"] == ["input_offset_qin"]
    off, sd = info["parameters"]["off_qin"], info["uncertainty"]["off_qin"]
    rig = _rig()
    assert abs(off - rig.OFFSET) < 3 * sd and abs(off - rig.OFFSET) < 0.1
    assert info["parameters"]["Kv"] == pytest.approx(rig.KV, abs=0.02)
    assert info["explains"] is True
    assert max(info["noise_ratio_free_run"].values()) < 3.0
    (tie,) = info["ties"]
    runs = tie["free_run"]
    assert set(runs) == {"input_offset_qin", *tie["tied_with"]}
    assert "leak_linear_h" in runs
    # the choice is the one whose free run is decisively better
    assert all(runs["input_offset_qin"] < 0.5 * v for k, v in runs.items()
               if k != "input_offset_qin")
    assert any("one free run of the validation part decided" in w
               for w in info["warnings"])

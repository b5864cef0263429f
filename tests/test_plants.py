"""Plants users write: a new model written from scratch goes through the whole CLI, and the
shipped plants (three tanks, heat exchanger) build, verify and detect every declared fault.

The scratch model is a two-mass spring system that none of the shipped models resembles:
a spring fault written with several terms (it enters both force balances, and is one
fault), a PI position loop on one input, a second input nobody controls (held at its
operating value, not at 0), positions measured.
"""

from __future__ import annotations

import json
import re
import subprocess

import numpy as np
import sympy as sp
import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.errors import ModelFileError
from fdigen.model.model_file import load_model, parse_model_text

SCRATCH = """
[model]
name = "two_mass"
description = "Two masses joined by a spring, force on mass 1, positions measured"

[parameters]
m1 = { value = 1.0, unit = "kg", bounds = [0.1, 10.0] }
m2 = { value = 0.5, unit = "kg", bounds = [0.1, 10.0] }
k  = { value = 50.0, unit = "N/m", bounds = [1.0, 1e4] }
c1 = { value = 4.0, unit = "N s/m", bounds = [0.0, 100.0], uncertain = true }
c2 = { value = 2.0, unit = "N s/m", bounds = [0.0, 100.0], uncertain = true }
D0 = { value = 1.0, unit = "N", bounds = [-10.0, 10.0] }

[states]
x1 = { unit = "m", range = [-0.2, 0.3] }
v1 = { unit = "m/s", range = [-1.0, 1.0] }
x2 = { unit = "m", range = [-0.2, 0.3] }
v2 = { unit = "m/s", range = [-1.0, 1.0] }

[inputs]
F = { unit = "N", range = [-20.0, 20.0], column = "F" }
D = { unit = "N", range = [0.0, 2.0], column = "D" }

[definitions]
Fs = "k*(x1 - x2)"

[dynamics]
x1 = "v1"
v1 = "(F - Fs - c1*v1)/m1"
x2 = "v2"
v2 = "(Fs + D - c2*v2)/m2"

[outputs]
y1 = { expr = "x1", unit = "m", noise_std = 1e-4, column = "x1" }
y2 = { expr = "x2", unit = "m", noise_std = 1e-4, column = "x2" }

[faults.spring]
class = "spring"
mode = "multiplicative"
terms = [{ target = "v1", term = "spring*Fs/m1" }, { target = "v2", term = "-spring*Fs/m2" }]
test_size = 0.5

[faults.drive]
location = "actuator"
mode = "multiplicative"
target = "F"
term = "-drive*F"
class = "drive"
test_size = 0.5

[faults.pos2]
location = "sensor"
mode = "additive"
target = "y2"
term = "pos2"
class = "sensor2"
test_size = 0.01

[operating_point]
x1 = "D0/k"
x2 = 0.0
v1 = 0.0
v2 = 0.0
F = 0.0
D = "D0"

[fdi]
sample_time = 0.01
window = 50
confirm = 5
realign_noise_scale = 0.05
extra_residuals = false

[fdi.parity]
R1 = "y1"
R2 = "y2"

[fdi.process_noise]
x1 = 1e-4
v1 = 1e-2
x2 = 1e-4
v2 = 1e-2

[fdi.thresholds]
R1 = 2e-3
R2 = 2e-3

[fdi.actions]
spring = "safety_stop"
drive = "safety_stop"
sensor2 = "none"

[simulation]
duration = 8.0
substeps = 4

[simulation.controllers.position]
type = "pi"
input = "F"
measurement = "y2"
reference = "0.05 + 0.04*sin(2*pi*0.3*t) + 0.02*sin(2*pi*0.7*t + 1.0)"
reference_column = "x2_ref"
kp = 40.0
ki = 20.0
limits = [-20.0, 20.0]
"""


def _invoke(*args):
    res = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return res.output


def test_new_model_written_from_scratch_goes_through_the_whole_cli(tmp_path):
    path = tmp_path / "two_mass.toml"
    path.write_text(SCRATCH)
    model = load_model(path)
    spring = model.fault("spring")
    assert [t for t, _ in spring.terms] == ["v1", "v2"]
    _invoke("build", "--model", path, "--out", tmp_path / "gen")
    assert (tmp_path / "gen" / "two_mass" / "c" / "two_mass_fdi.c").is_file()
    design = json.loads(_invoke("inspect", "--model", path, "--json"))
    # the spring fault is one column of E, entering both force balances
    E = np.array(design["linearisation"]["E"], dtype=float)
    assert E.shape == (4, 3)
    assert E[1, 0] != 0 and E[3, 0] != 0 and E[0, 0] == 0 and E[2, 0] == 0
    assert design["faults"]["spring"]["targets"] == ["v1", "v2"]
    rep = json.loads(_invoke("verify", "--model", path, "--backend", "c", "--points", "30",
                             "--duration", "2", "--json"))
    assert rep["backends"]["c"]["summary"]["ok"]
    healthy, faulty = tmp_path / "healthy.csv", tmp_path / "spring.csv"
    _invoke("simulate", "--model", path, "-o", healthy)
    _invoke("simulate", "--model", path, "--fault", "spring@4=0.5", "-o", faulty)
    header = healthy.read_text().splitlines()[0].split(",")
    assert {"F", "D", "x1", "x2", "x2_ref"} <= set(header)
    data = np.loadtxt(healthy, delimiter=",", skiprows=1)
    assert data.shape[0] == 800  # [simulation] duration = 8 s at 0.01 s
    d = data[:, header.index("D")]
    assert np.all(d == 1.0)  # not controlled: held at its operating value D0, not 0
    ok = json.loads(_invoke("detect", healthy, "--model", path, "--json"))
    bad = json.loads(_invoke("detect", faulty, "--model", path, "--json"))
    assert ok["flags"] == []
    assert bad["flags"] and min(f["t_raised"] for f in bad["flags"]) >= 4.0
    _invoke("report", faulty, "--model", path, "-o", tmp_path / "spring.png")
    assert (tmp_path / "spring.png").stat().st_size > 0
    tuned = json.loads(_invoke("tune", "--model", path, "--runs", "3", "--duration", "4",
                               "--validation-runs", "1", "--fault-sizes", "1",
                               "--fault-starts", "1", "--scheduler", "synchronous", "--json"))
    assert set(tuned["thresholds"]) == {"R1", "R2"}
    assert all(v > 0 for v in tuned["thresholds"].values())


def _scratch_with(old: str, new: str) -> str:
    assert old in SCRATCH
    return SCRATCH.replace(old, new)


@pytest.mark.parametrize("old, new, field", [
    ('[faults.spring]\nclass = "spring"', '[faults.spring]\nclass = "spring"\nbogus = 1',
     "faults.spring"),
    ('type = "pi"', 'type = "pi"\nkff = 1.0', "simulation.controllers.position"),
    ("duration = 8.0", "duration = 8.0\nnoise = true", "simulation"),
    ('target = "v1"', 'target = "nowhere"', "faults.spring.terms[0].target"),
    ('measurement = "y2"', 'measurement = "y9"', "simulation.controllers.position.measurement"),
    ('reference_column = "x2_ref"', 'reference_column = "x2"',
     "simulation.controllers.position.reference_column"),
])
def test_bad_fault_and_simulation_keys_are_refused_at_load(old, new, field):
    with pytest.raises(ModelFileError) as err:
        parse_model_text(_scratch_with(old, new), source="m.toml")
    assert field in str(err.value)


def test_list_target_and_list_controller_are_refused_with_the_right_message():
    bad = _scratch_with('target = "F"', 'target = ["F", "D"]')
    with pytest.raises(ModelFileError, match="terms = ") as err:
        parse_model_text(bad, source="m.toml")
    assert "missing or non-text 'target'" not in str(err.value)
    cyl = load_model()
    text = open(cyl.source).read().replace(
        'controller = "min(max(40*(xref - x3), -5), 5)"',
        'controller = ["min(max(40*(xref - x3), -5), 5)"]')
    with pytest.raises(ModelFileError, match="simulation.controller"):
        parse_model_text(text, source="cyl.toml")


def test_pi_controller_does_not_wind_up():
    """The logged command is the PI law with conditional integration, recomputed here from
    the logged measurement: the integrator holds while the command is saturated in the
    direction the error pushes; an integrator that always integrates would differ."""
    from fdigen.sim.plant import simulate

    text = _scratch_with("limits = [-20.0, 20.0]", "limits = [-3.0, 3.0]").replace(
        'reference = "0.05 + 0.04*sin(2*pi*0.3*t) + 0.02*sin(2*pi*0.7*t + 1.0)"',
        'reference = "0.2"')
    model = parse_model_text(text, source="m.toml")
    sim = simulate(model, 8.0, noise=False)
    dt, kp, ki = 0.01, 40.0, 20.0
    e = 0.2 - sim.y[:, 1]
    held, always = 0.0, 0.0
    want, wound = [], []
    for ek in e:
        v = kp * ek + ki * held
        want.append(min(max(v, -3.0), 3.0))
        wound.append(min(max(kp * ek + ki * always, -3.0), 3.0))
        if not ((v > 3.0 and ek > 0) or (v < -3.0 and ek < 0)):
            held += dt * ek
        always += dt * ek
    assert np.max(np.abs(sim.u[:, 0] - want)) < 1e-12
    assert sim.u[:, 0].max() == 3.0  # it did saturate
    assert np.max(np.abs(sim.u[:, 0] - wound)) > 0.1
    assert abs(sim.y[-1, 1] - 0.2) < 5e-3  # and reaches the reference


# -- shipped plants ---------------------------------------------------------------------

NEW_MODELS = ("three_tank", "heat_exchanger")


@pytest.fixture(scope="module", params=NEW_MODELS)
def shipped(request):
    from fdigen.design.fdi_design import fdi_design

    model = load_model(request.param)
    return fdi_design(model)


def test_shipped_model_verifies_and_detects_every_declared_fault(shipped):
    """C equals the reference; each declared fault at its test size raises a flag after its
    onset and none before (short runs: 0.5 of the model's [simulation] duration)."""
    from fdigen.backends.c.loader import CFdi
    from fdigen.sim.plant import FaultEvent, simulate
    from fdigen.verify.equivalence import verify

    model = shipped.model
    duration = 0.5 * float(model.simulation["duration"])
    rep = verify(shipped, backends=("c",), n_points=40, trajectories=[])
    assert rep["backends"]["c"]["summary"]["ok"]
    core = CFdi(shipped)
    healthy = core.run(*(lambda s: (s.u, s.y))(simulate(model, duration, seed=5)))
    assert not np.any(np.asarray(healthy["flags"]))
    t0 = 0.3 * duration
    for k, fault in enumerate(model.faults):
        sim = simulate(model, duration, seed=10 + k,
                       faults=(FaultEvent(fault.name, t0, fault.test_size),))
        flags = np.asarray(core.run(sim.u, sim.y)["flags"])
        raised = np.flatnonzero(flags)
        assert raised.size, f"{model.name}: {fault.name} not detected"
        assert sim.t[raised[0]] >= t0, f"{model.name}: flag before {fault.name}'s onset"


@pytest.mark.parametrize("name", NEW_MODELS)
def test_committed_float_c_passes_wconversion(name, tmp_path):
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "generated" / name / "c_float" / f"{name}_fdi.c"
    subprocess.run(["cc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wshadow",
                    "-Wconversion", "-c", str(src), "-o", str(tmp_path / "f.o")], check=True)


def test_inspect_text_is_readable_and_fits_the_terminal():
    # a 60-column terminal (piped output is printed wide, never cut: tests/test_cli_output.py)
    terminal = {"COLUMNS": "60", "TTY_COMPATIBLE": "1", "NO_COLOR": "1", "FORCE_COLOR": None}
    res = CliRunner().invoke(main, ["inspect", "--model", "three_tank"], env=terminal,
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    out = re.sub(r"\x1b\[[0-9;]*m", "", res.output)  # bold of the model name
    assert "DiracDelta" not in out and "Piecewise" not in out and "nan" not in out
    assert "…" not in out  # no name cut
    assert max(map(len, out.splitlines())) <= 60
    assert "leak1/pump1" in out  # the pairs the structure cannot separate, in text too
    for name in ("R1", "R4", "R5", "nf_y3", "tank1_outflow", "level_sensor_3"):
        assert name in out
    js = CliRunner().invoke(main, ["inspect", "--model", "three_tank", "--json"]).output
    assert "DiracDelta" not in js and "Piecewise" not in js
    assert json.loads(js)["unresolved_pairs_within_class"] == [["leak1", "pump1"]]


# -- discover: effects by role, windows from the plant -------------------------------------

def test_effect_library_by_role_for_liquid_and_thermal_plants():
    from fdigen.discover.effects import library

    def lib(name):
        return {e.name: e for e in library(load_model(name))}

    tanks, heat = lib("three_tank"), lib("heat_exchanger")
    assert dict(tanks["leak_sqrt_h1"].states) == {"h1": "-Kl_h1*sqrt(max(h1, 0))/A"}
    # clogging of the pipe q12: the flow comes back to T1 and is missing in T2
    assert dict(tanks["flow_loss_q12"].states) == {"h1": "-kc_q12*(-1/A)*q12",
                                                   "h2": "-kc_q12*(1/A)*q12"}
    assert dict(tanks["gain_loss_q1"].states) == {"h1": "-kw_q1*(1/A)*q1"}
    assert dict(heat["heat_loss_Th"].states) == {"Th": "-Ll_Th*(Th - (Ta))/Ch"}
    assert set(heat["flow_loss_Qx"].states) == {"Th", "Tc"}
    # nothing of these families applies to the cylinder or the motor (their Ra is
    # calibrated, so a resistance drift would be the calibration itself)
    new = {"liquid", "thermal", "transfer", "gain", "electrical"}
    for name in ("pneumatic_cylinder", "dc_motor"):
        assert not {e.family for e in lib(name).values()} & new


def test_discover_windows_follow_the_sample_time_and_time_constants():
    from fdigen.discover.windows import discover_windows, slowest_time_constant

    for name, dt, want in (("pneumatic_cylinder", 1e-3, (0.05, 0.025)),
                           ("dc_motor", 1e-3, (0.05, 0.025)),
                           ("three_tank", 0.1, (5.0, 2.5))):
        model = load_model(name)
        assert discover_windows(model, np.arange(2000) * dt) == want
        assert 10 * slowest_time_constant(model) >= want[0]
    model = load_model("dc_motor")
    capped = discover_windows(model, np.arange(2000) * 0.002)[0]  # 500 Hz: 10 tau_slow caps
    assert capped < 50 * 0.002
    assert capped == pytest.approx(10 * slowest_time_constant(model), abs=0.002)


def test_discover_finds_a_heater_gain_loss(tmp_path):
    from fdigen.discover.effects import get_effect
    from fdigen.discover.pipeline import discover
    from fdigen.sim.log import write_log
    from fdigen.sim.plant import simulate

    model = load_model("heat_exchanger")
    eff = get_effect("gain_loss_P", model)
    sim = simulate(model, seed=3, effects=eff.plant_effects(model, {"kw_P": 0.15}))
    log = tmp_path / "heater.csv"
    write_log(log, sim.columns())
    res = discover(log, "heat_exchanger", out=tmp_path / "out", build=False, fdi=False,
                   plot=False).as_dict()
    assert res["effect"] == "gain_loss_P"
    assert abs(res["parameters"]["kw_P"] - 0.15) < 0.05


# -- a fault entering several equations is one fault ---------------------------------------

def _tank_variant_in_definitions():
    """three_tank with the clogging written inside the definition of q12 instead."""
    from fdigen.model.model_file import builtin_model_path

    text = builtin_model_path("three_tank").read_text()
    text = text.replace('q12 = "az12*Sn*sign(h1 - h2)*sqrt(2*g*abs(h1 - h2))"',
                        'q12 = "(1 - clog12)*az12*Sn*sign(h1 - h2)*sqrt(2*g*abs(h1 - h2))"')
    text = text.replace(
        'terms = [{ target = "h1", term = "clog12*q12/A" }, '
        '{ target = "h2", term = "-clog12*q12/A" }]', 'location = "plant"')
    return parse_model_text(text, source="three_tank_defs.toml")


def test_terms_and_definition_forms_give_the_same_single_fault_column():
    from fdigen.derive.linearisation import linearise
    from fdigen.design.fdi_design import fdi_design

    terms, defs = load_model("three_tank"), _tank_variant_in_definitions()
    assert defs.fault("clog12").terms == ()
    Et, Ed = linearise(terms).E, linearise(defs).E
    j = [f.name for f in terms.faults].index("clog12")
    assert Et.shape[1] == len(terms.faults) == Ed.shape[1]
    assert Et[1, j] < 0 < Et[0, j] and Et[2, j] == 0  # T1 keeps its water, T2 misses it
    np.testing.assert_allclose(Et, Ed, rtol=1e-12, atol=0)
    # the nominal model is the same (fault symbol 0 in the definition)
    x = {s: v for s, v in zip(terms.x, (0.45, 0.33, 0.25))}
    subs = {**terms.parameter_values, **x, terms.u[0]: 3e-5, terms.u[1]: 2e-5}
    assert [float(e.xreplace(subs)) for e in terms.f()] == \
        [float(e.xreplace(subs)) for e in defs.f()]
    assert fdi_design(terms).signature_table == fdi_design(defs).signature_table


def test_multi_target_fault_is_decoupled_as_one_fault():
    """The clogging enters h1 and h2 with opposite signs: h1 + h2 (c = (1, 1)) is blind to
    it, and not to the leak of T1."""
    from fdigen.design.decoupling import decoupled_submodel, decoupling_direction

    model = load_model("three_tank")
    clog = model.fault("clog12")
    idx, m = decoupling_direction(model, clog)
    h1, h2 = (model.states[i].symbol for i in idx)
    assert idx == [0, 1] and sp.diff(m, h1) == sp.diff(m, h2) != 0
    signature = decoupled_submodel(model, clog, "m")[-1]
    assert signature["clog12"] is False
    assert signature["leak1"] is True and signature["pump1"] is True


def test_tune_varies_every_controller_demand_about_its_own_mean():
    from fdigen.sim.plant import reference_signal
    from fdigen.tune.cases import varied_simulation

    import dataclasses

    model = load_model("three_tank")
    t = np.arange(0.0, 6000.0, 0.5)
    base = reference_signal(model, t)
    same = dataclasses.replace(model, simulation=varied_simulation(model, 1.0, 0.0, {}))
    np.testing.assert_allclose(reference_signal(same, t), base, rtol=0, atol=1e-12)
    half = dataclasses.replace(model, simulation=varied_simulation(model, 0.5, 37.0, {}))
    varied = reference_signal(half, t)
    assert varied.shape == base.shape == (t.size, 2)
    for j in range(2):  # each demand scaled by 0.5 about its own mean
        assert np.ptp(varied[200:, j]) == pytest.approx(0.5 * np.ptp(base[200:, j]), rel=0.05)
        assert varied[:, j].mean() == pytest.approx(base[:, j].mean(), abs=2e-3)


def test_expression_controller_of_the_several_loops_form():
    """`type = "expression"`: u = law(outputs, ref), recomputed from the logged signals."""
    from fdigen.sim.plant import simulate

    old = SCRATCH[SCRATCH.index("[simulation.controllers.position]"):]
    text = SCRATCH.replace(old, '''[simulation.controllers.position]
type = "expression"
input = "F"
law = "min(max(60*(ref - y2) - 5*y1, -20), 20)"
reference = "0.05 + 0.02*sin(2*pi*0.5*t)"
''')
    model = parse_model_text(text, source="m.toml")
    sim = simulate(model, 4.0, seed=2)
    want = np.clip(60 * (sim.ref[:, 0] - sim.y[:, 1]) - 5 * sim.y[:, 0], -20, 20)
    np.testing.assert_allclose(sim.u[:, 0], want, rtol=1e-12, atol=1e-12)
    assert np.all(sim.u[:, 1] == 1.0)  # D held at its operating value
    assert "position_ref" in sim.columns()
    with pytest.raises(ModelFileError, match="simulation.controllers.position.law"):
        parse_model_text(text.replace("ref - y2", "ref - y7"), source="m.toml")


def test_fault_with_terms_on_a_state_an_output_and_an_input():
    """One fault, three kinds of target: one column of E = df/dphi and of F = dh/dphi."""
    from fdigen.derive.linearisation import linearise

    text = SCRATCH.replace("[operating_point]", '''[faults.mixed]
class = "mixed"
terms = [{ target = "v2", term = "mixed/m2" }, { target = "y1", term = "2*mixed" },
         { target = "F", term = "3*mixed" }]

[operating_point]''').replace('sensor2 = "none"', 'sensor2 = "none"\nmixed = "none"')
    model = parse_model_text(text, source="m.toml")
    assert model.fault("mixed").location == "plant"
    lin = linearise(model)
    j = [f.name for f in model.faults].index("mixed")
    m1, m2 = 1.0, 0.5
    np.testing.assert_allclose(lin.E[:, j], [0.0, 3.0 / m1, 0.0, 1.0 / m2], rtol=1e-12)
    np.testing.assert_allclose(lin.F[:, j], [2.0, 0.0], rtol=1e-12)

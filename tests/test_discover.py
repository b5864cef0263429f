"""`fdigen discover`: find the missing effect in a log, add it, report before/after.

Logs are made with fdigen's own simulator, one library effect at a time (a size that
matters, datasheet Ff and K off by up to 10 %, sensor noise as in the rig README), plus a
healthy log; and the reference rig's discrepancy logs (their JSON gives the truth).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.discover import effects as fx
from fdigen.discover.augment import augmented_text, check_augmented, rebuild
from fdigen.discover.pipeline import DiscoverSettings, discover
from fdigen.errors import FdigenError
from fdigen.model.model_file import builtin_model_path, load_model
from fdigen.sim.log import write_log
from fdigen.sim.plant import simulate

from conftest import RIG

MOTOR_EFFECTS = ["coulomb_friction", "stribeck_friction", "external_load", "quadratic_drag",
                 "actuator_deadband",
                 "sensor_offset_w_tach", "sensor_offset_i_meas"]
# (each effect's seed is its index: quadratic_drag, added later, is last)
CYLINDER_EFFECTS = ["coulomb_friction", "stribeck_friction", "external_load", "leak_p",
                    "leak_n", "cross_leak", "valve_deadband", "sensor_offset_pp",
                    "sensor_offset_pn", "quadratic_drag"]


# -- the library ---------------------------------------------------------------------------

def test_library_applies_to_the_cylinder_only_where_symbols_exist(cylinder, motor):
    names = {e.name for e in fx.library(cylinder)}
    assert names == set(CYLINDER_EFFECTS)
    coulomb = fx.get_effect("coulomb_friction", cylinder)
    assert coulomb.needs == {"xdot", "M"}
    assert coulomb.applicable(cylinder) and not coulomb.applicable(motor)
    # effects are declared by role: the DC motor's speed equation is a torque balance
    # (rad/s over the inertia J), it has no gas chamber, and its voltage is an actuator
    assert {e.name for e in fx.library(motor)} == set(MOTOR_EFFECTS)
    mc = fx.get_effect("coulomb_friction", motor)
    assert mc.needs == {"w", "J"} and mc.parameters[0].name == "Tc"
    assert mc.parameters[0].unit == "N m" and mc.text("w") == "-Tc/J*tanh(w/5.0)"
    # sizes from the model: viscous damping x speed amplitude (1e-5 N m s x 300 rad/s)
    assert mc.parameters[0].nominal == pytest.approx(1e-5 * 300.0)
    assert coulomb.parameters[0].nominal == pytest.approx(100.0 * 0.3)
    with pytest.raises(FdigenError, match="unknown effect"):
        fx.get_effect("leak_p", motor)
    with pytest.raises(FdigenError, match="family"):
        fx.get_effect("sensor_offset", cylinder)


def test_effect_terms_and_footprints(cylinder):
    cross = fx.get_effect("cross_leak", cylinder)
    terms = cross.terms(cylinder)
    # mass flow p -> n: chamber p loses, chamber n gains, each over its own volume
    assert str(terms["Pp"]).startswith("-") and "Vp" in str(terms["Pp"])
    assert "Vn" in str(terms["Pn"]) and not str(terms["Pn"]).startswith("-")
    assert fx.get_effect("valve_deadband", cylinder).footprint(cylinder) == {"Pp", "Pn"}
    assert fx.get_effect("sensor_offset_pp", cylinder).footprint(cylinder) == {"Pp", "xdot"}
    assert fx.get_effect("coulomb_friction", cylinder).text("xdot") == \
        "-Fc/M*tanh(xdot/0.005)"
    # the leak's factor from mass flow to dP/dt is the chamber's own valve gain over K
    assert fx.get_effect("leak_p", cylinder).text("Pp") == "-(R*Ts*gamma/Vp)*Cl_p*(Pp - Patm)"


def test_new_effect_is_searched_without_touching_the_search(cylinder):
    from fdigen.discover.explain import candidates_for
    from fdigen.discover.locate import prepare

    extra = fx.LibraryEffect("cubic_damping", "damping ~ xdot^3",
                             (fx.EffectParameter("Cc", "N s^3/m^3", (0.0, 1e4), 100.0),),
                             states={"xdot": "-Cc/M*xdot**3"})
    fx.register(extra)
    try:
        sim = simulate(cylinder, 2.0, substeps=2)
        data = prepare(cylinder, sim.t, sim.u, sim.y)
        assert "cubic_damping" in {e.name for e in candidates_for(data, ["xdot"])}
        assert "cubic_damping" not in {e.name for e in candidates_for(data, ["Pp"])}
    finally:
        fx.unregister("cubic_damping")
    assert "cubic_damping" not in {e.name for e in fx.library(cylinder)}


def test_effect_terms_go_through_the_whitelist_parser(cylinder):
    with pytest.raises(FdigenError):
        fx.register(fx.LibraryEffect("evil", "", (fx.EffectParameter("q", "", (0, 1), 1),),
                                     states={"x": "__import__('os').system('true')"}))
    bad = fx.LibraryEffect("evil2", "", (fx.EffectParameter("q", "", (0, 1), 1),),
                           states={"x": "q*x.real"})
    with pytest.raises(FdigenError):
        bad.terms(cylinder)


# -- simulated logs, one effect at a time ----------------------------------------------------

def _sim_log(tmp_path, model, effect, seed):
    rng = np.random.default_rng(1000 + seed)
    params = {"Ff": 100.0 * (1 + rng.uniform(-0.1, 0.1)),
              "K": 1e-3 * (1 + rng.uniform(-0.1, 0.1))}
    effs, truth = (), None
    if effect is not None:
        e = fx.get_effect(effect, model)
        truth = {e.parameters[0].name: e.parameters[0].nominal}
        effs = e.plant_effects(model, truth)
    sim = simulate(model, 20.0, effects=effs, parameters=params, seed=seed, substeps=4)
    path = tmp_path / f"{effect or 'healthy'}.csv"
    write_log(path, sim.columns())
    return path, truth, params


@pytest.mark.parametrize("effect", CYLINDER_EFFECTS + [None])
def test_simulated_effect_is_found(tmp_path, cylinder, effect):
    path, truth, params = _sim_log(tmp_path, cylinder, effect, seed=CYLINDER_EFFECTS.index(
        effect) if effect else 99)
    res = discover(path, out=tmp_path / "out", build=False, fdi=False, plot=False).as_dict()
    if effect is None:
        assert res["effect"] is None and res["effects"] == []
        assert res["equation"] is None
        assert "no effect" in res["message"]
        # calibration alone recovers the datasheet deviations
        for k in ("Ff", "K"):
            assert res["calibrated"][k] == pytest.approx(params[k], rel=0.02)
        return
    e = fx.get_effect(effect, cylinder)
    assert res["effects"] == [effect]
    assert res["equation"] in e.footprint(cylinder)
    if e.states:
        assert res["equation"] in e.states
    (pname, value), = truth.items()
    assert res["parameters"][pname] == pytest.approx(value, rel=0.2)
    assert res["uncertainty"][pname] < 0.2 * abs(value)
    for k in ("Ff", "K"):
        assert res["parameters"][k] == pytest.approx(params[k], rel=0.05)
    # validation (held-back) errors go down: equation error and output error
    eq = res["equation"]
    assert res["equation_error_after"][eq] < res["equation_error_before"][eq]
    before, after = res["error_before"], res["error_after"]
    assert sum(after[k] / before[k] for k in ("x", "pp", "pn")) < 3.0
    assert res["validation"][0] == pytest.approx(12.0, abs=0.01)


# -- the reference rig's discrepancy logs --------------------------------------------------

def _rig(name):
    path = RIG / "logs" / f"{name}.csv"
    if not path.is_file():
        pytest.skip(f"reference rig log {path} not available")
    return path, json.loads(path.with_suffix(".json").read_text())["truth"]


@pytest.mark.parametrize("case,effect,pname,tname,equation", [
    ("discrepancy_leak_n", "leak_n", "Cl_n", "Cl_n", "Pn"),
    ("discrepancy_none", None, None, None, None),
])
def test_rig_discrepancy_logs(tmp_path, case, effect, pname, tname, equation):
    path, truth = _rig(case)
    res = discover(path, out=tmp_path, build=False, fdi=False, plot=False).as_dict()
    assert res["effect"] == effect
    assert res["equation"] == equation
    for k in ("Ff", "K"):
        assert res["parameters"][k] == pytest.approx(truth[k], rel=0.05)
    if effect:
        assert res["parameters"][pname] == pytest.approx(truth[tname], rel=0.2)
        for k in ("x", "pp", "pn"):
            assert res["error_after"][k] < res["error_before"][k]


def test_rig_coulomb_full_loop(tmp_path):
    """The whole loop on the rig's Coulomb log: found, added, rebuilt, reported."""
    path, truth = _rig("discrepancy_coulomb")
    out = tmp_path / "discovered"
    res = discover(path, out=out, build=True, fdi=True, plot=True).as_dict()
    assert (res["effect"], res["equation"]) == ("coulomb_friction", "xdot")
    assert res["parameters"]["Fc"] == pytest.approx(truth["Fc"], rel=0.2)
    assert res["parameters"]["Ff"] == pytest.approx(truth["Ff"], rel=0.1)
    assert 0 < res["uncertainty"]["Fc"] < 2.0
    for k in ("x", "pp", "pn"):
        assert res["error_after"][k] < 0.2 * res["error_before"][k]
    # the augmented model file: original text + term + parameter, parsed back
    aug = load_model(res["model_file"])
    assert aug.parameter_values[aug.parameters[[q.name for q in aug.parameters]
                                               .index("Fc")].symbol] == pytest.approx(
        res["parameters"]["Fc"], rel=1e-5)
    text = (out / "pneumatic_cylinder_discovered.toml").read_text()
    assert 'xdot = "A/M*(Pp - Pn) - Ff/M*xdot - Fc/M*tanh(xdot/0.005)"' in text
    assert "substeps = 2" in text  # the stiff friction term needs RK4 sub-steps
    # generated code includes the effect
    c_src = next((out / "pneumatic_cylinder" / "c").glob("*_fdi.c")).read_text()
    assert "tanh" in c_src
    assert (out / "pneumatic_cylinder" / "casadi").is_dir()
    # FDI residuals of the original and augmented designs on the validation part
    for r in ("R1", "R2", "R3", "R5"):
        assert res["fdi_after"][r] < res["fdi_before"][r]
    # the augmented Kalman filters predict through the friction: they improve too, and the
    # augmented design raises no flag on the log (the original raised R1-R7)
    for r in ("R4", "R6"):
        assert res["fdi_after"][r] < res["fdi_before"][r]
    assert res["fdi_flags_after"] == [] and res["fdi_flags_before"]
    assert (out / "discover.png").stat().st_size > 10_000
    saved = json.loads((out / "discover.json").read_text())
    for key in ("equation", "effect", "parameters", "error_before", "error_after",
                "validation"):
        assert key in saved
    assert set(saved["error_before"]) >= {"x", "pp", "pn"}
    # the built-in model's folder is never a target
    from fdigen.pipeline import DEFAULT_OUT

    with pytest.raises(FdigenError, match="refusing"):
        rebuild(res["model_file"], DEFAULT_OUT)


# -- the augmented file, for every effect --------------------------------------------------

@pytest.mark.parametrize("effect", CYLINDER_EFFECTS)
def test_augmented_text_parses_back(cylinder, effect):
    e = fx.get_effect(effect, cylinder)
    text = builtin_model_path().read_text()
    values = {p.name: p.nominal for p in e.parameters}
    aug = augmented_text(text, cylinder, [e], values, {p.name: 0.1 * p.nominal
                                                       for p in e.parameters},
                         calibrated={"Ff": 97.5, "K": 1.02e-3}, origin="x.csv")
    new = check_augmented(aug, cylinder, [e], "<test>")
    assert {p.name for p in e.parameters} <= {q.name for q in new.parameters}
    assert new.parameter_values[new.parameters[[q.name for q in new.parameters]
                                               .index("Ff")].symbol] == 97.5
    # everything else untouched: faults, FDI tables, other equations
    assert [f.name for f in new.faults] == [f.name for f in cylinder.faults]
    assert new.fdi == cylinder.fdi
    untouched = set(s.name for s in cylinder.states) - set(e.states)
    for name in untouched:
        k = cylinder.state_index(name)
        assert new.dynamics[k] == cylinder.dynamics[k]


# -- command line --------------------------------------------------------------------------

def test_cli_simulate_effect_and_discover_json(tmp_path):
    from fdigen.cli import main

    runner = CliRunner()
    log = tmp_path / "load.csv"
    r = runner.invoke(main, ["simulate", "--duration", "20", "--effect", "external_load=25",
                             "--seed", "3", "-o", str(log)])
    assert r.exit_code == 0, r.output
    truth = json.loads(log.with_suffix(".json").read_text())["truth"]
    assert truth["effects"] == [{"effect": "external_load", "parameters": {"Fload": 25.0},
                                "units": {"Fload": "N"}}]
    r = runner.invoke(main, ["discover", str(log), "--out", str(tmp_path / "d"), "--no-build",
                             "--no-fdi", "--json"])
    assert r.exit_code == 0, r.output
    res = json.loads(r.output)
    assert (res["equation"], res["effect"]) == ("xdot", "external_load")
    assert res["parameters"]["Fload"] == pytest.approx(25.0, rel=0.05)
    # the keys and types the issue fixes: equation/effect str|null, parameters {name:
    # float}, error_before/after {signal: float} with x, pp, pn, validation [start, end]
    for key in ("equation", "effect", "parameters", "error_before", "error_after",
                "validation"):
        assert key in res
    assert isinstance(res["equation"], str) and isinstance(res["effect"], str)
    assert all(isinstance(v, float) for v in res["parameters"].values())
    for key in ("error_before", "error_after"):
        assert set(res[key]) >= {"x", "pp", "pn"}
        assert all(isinstance(v, float) for v in res[key].values())
    t0, t1 = res["validation"]
    assert isinstance(t0, float) and t0 < t1
    r = runner.invoke(main, ["simulate", "--duration", "1", "--effect", "warp_drive=1",
                             "-o", str(tmp_path / "bad.csv")])
    assert r.exit_code == 2 and "unknown effect" in r.output
    r = runner.invoke(main, ["simulate", "--duration", "1", "--effect", "leak_p",
                             "-o", str(tmp_path / "bad.csv")])
    assert r.exit_code == 2 and "NAME=VALUE" in r.output


def test_settings_are_validated(tmp_path, cylinder):
    sim = simulate(cylinder, 0.3, substeps=2)
    path = tmp_path / "short.csv"
    write_log(path, sim.columns())
    with pytest.raises(FdigenError):
        discover(path, out=tmp_path, settings=DiscoverSettings(), build=False, fdi=False,
                 plot=False)

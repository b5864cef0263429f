"""Plants a first-time user wrote from the README (2026-11-28, round 30): an EV battery
thermal loop, a water network in cm and bar, a CSTR with transmitters in volts and mA.

* ``detect`` on the battery's pump fault said "action: safety_stop (every consistent
  class calls for it: coolant_flow)" beside "consistent faults: pump or cool_sensor": the
  summary read a late flag (``Rb_p``, after its validity horizon) as evidence, which the
  core leaves out; the action was the ambiguity policy's most severe one.
"""

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser30"


def test_late_flags_are_read_as_the_core_keeps_them(tmp_path, monkeypatch):
    from fdigen.backends.reference import ReferenceFdi
    from fdigen.design.cache import cached_design
    from fdigen.detect import late_flags
    from fdigen.model.model_file import load_model
    from fdigen.sim.log import read_log

    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    model_path = str(DATA / "ev_battery.toml")
    log = tmp_path / "pump.csv"
    res = CliRunner().invoke(main, ["simulate", "--model", model_path, "--duration", "2400",
                                    "--fault", "pump@1200=0.4", "-o", str(log)])
    assert res.exit_code == 0, res.output
    design = cached_design(load_model(model_path))
    lg = read_log(log, design.model)
    ref = ReferenceFdi(design)
    ref.reset()
    flags, late = [], []
    for k in range(len(lg.t)):
        out = ref.step(lg.u[k], lg.y[k])
        flags.append(out["flags"])
        late.append(ref.state.late)
    assert np.array_equal(late_flags(design, np.array(flags)), np.array(late))
    assert any(late)              # the case the summary got wrong has a late flag
    res = CliRunner().invoke(main, ["detect", "--model", model_path, str(log), "--json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    d = summary["diagnosis"]
    late_names = [f["residual"] for f in summary["flags"] if f["late"]]
    assert late_names
    if d["action_basis"] in ("unanimous", "most_severe"):
        # the classes the action reads are those of the faults consistent then, whatever
        # the late flags say
        classes = {design.model.fault(f).fault_class for f in d["consistent_faults"]}
        assert classes <= set(d["action_classes"]), (classes, d["action_classes"])
        acts = {design.evaluation.actions[design.evaluation.classes.index(c)]
                for c in d["action_classes"]}
        assert (d["action_basis"] == "unanimous") == (len(acts) == 1)
    res = CliRunner().invoke(main, ["detect", "--model", model_path, str(log)])
    assert f"{late_names[0]} (late)" in res.output


def test_a_declared_fault_on_a_healthy_log_is_advised_as_a_nominal_term():
    """A user's air tunnel (round 31): the duct's normal heat loss had the form of its
    declared insulation fault, and the refusal said only "check the rig". What the user
    did by hand, declare the loss as a nominal parameter and keep the fault as the change
    from it, is what the advice now says."""
    from fdigen.commission.verdict import design_verdict
    from fdigen.model.model_file import load_model

    model = load_model(str(DATA / "ev_battery.toml"))
    found = [{"fault": "chiller", "effect": "heat_loss_Tc", "size": 4.99,
              "times_test_size": 0.333}]
    v = design_verdict(model, {}, {}, np.zeros((10, len(model.outputs))), 0.1,
                       faulty_log=found)
    assert not v["usable"]
    assert "the commissioning log shows the declared fault chiller" in v["failures"][0]
    fix = " ".join(v["fixes"][0].split())
    assert "normal physics (heat_loss_Tc)" in fix and "nominal term" in fix
    assert "keep chiller as the change from it" in fix


def test_a_combination_residual_has_the_unit_its_parts_make():
    """A user's CSTR (round 30) and hydraulic press (round 32): a balance residual read
    "that of the expression (T0: K, V: m^3, ...)", its threshold no quantity. The units'
    algebra gives K*m^3 and bar*mm^3; where there is none, the parts are still listed."""
    import sympy as sp

    from fdigen.design.cache import cached_design
    from fdigen.design.residual_scale import residual_scales
    from fdigen.design.unit_algebra import expression_unit, unit_expr
    from fdigen.model.model_file import load_model
    from fdigen.tune.model_update import fill_missing_thresholds
    from fdigen.tune.settings import NO_FLAG

    a, b, c = sp.symbols("a b c", real=True)
    assert expression_unit(a * b + c, {a: "mm^2", b: "bar", c: "bar*mm^2"}) == "bar*mm^2"
    assert expression_unit(sp.sqrt(a) / b, {a: "m^2", b: "s"}) == "m/s"
    assert expression_unit(a / (c - b) ** 2, {a: "1", b: "1", c: "1"}) == "1"
    assert expression_unit(a + b, {a: "m", b: "s"}) is None          # no unit: parts listed
    assert expression_unit(sp.exp(a), {a: "m"}) is None
    assert unit_expr("%") is None and unit_expr("J/(kg K)") is not None
    design = cached_design(fill_missing_thresholds(load_model(str(DATA / "cstr.toml")),
                                                   NO_FLAG)[0])
    units = {r: s["unit"] for r, s in residual_scales(design).items()}
    assert "K*m^3" in units.values()
    assert not any(u.startswith("that of the expression") for u in units.values())

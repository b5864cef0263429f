"""Isolation at the best the model's structure allows, and to the fault where it can."""

import numpy as np
import pytest

from fdigen.design.structure import (isolability, isolability_report, mso_sets,
                                     model_structure, non_isolable_pairs, table_isolability)
from fdigen.design.structural_selection import check_driven_parallel
from fdigen.design.signatures import candidate_residuals
from fdigen.detect import fault_names, summarise_run

# the numbers of the issue (an independent structural analysis): ordered pairs not isolable
ISSUE_NON_ISOLABLE = {"pneumatic_cylinder": 4, "dc_motor": 2}


@pytest.mark.parametrize("which", ["cylinder", "motor"])
def test_derived_table_reaches_the_structural_isolability(which, request):
    design = request.getfixturevalue(f"{which}_design")
    achievable = non_isolable_pairs(isolability(model_structure(design.model)))
    achieved = non_isolable_pairs(table_isolability(design.signature_table))
    assert achieved == achievable
    assert len(achieved) == ISSUE_NON_ISOLABLE[design.name]


def test_cylinder_only_leak_and_blockage_of_one_line_stay_together(cylinder_design):
    pairs = non_isolable_pairs(table_isolability(cylinder_design.signature_table))
    assert sorted(pairs) == [("blockage_n", "leak_n"), ("blockage_p", "leak_p"),
                             ("leak_n", "blockage_n"), ("leak_p", "blockage_p")]
    # every MSO set is a test; each fault that some MSO sees is detectable
    st = model_structure(cylinder_design.model)
    msos = mso_sets(st)
    assert msos and all(len(m) >= 2 for m in msos)
    seen = set().union(*[{f for f, e in st.faults.items() if e & m} for m in msos])
    assert seen == set(st.faults)


def test_motor_sensor_placement_names_the_armature_voltage(motor_design):
    rep = isolability_report(motor_design.model, motor_design.signature_table)
    assert rep["achievable_non_isolable"] == [["drive", "winding"], ["winding", "drive"]]
    # a voltage sensor on what the power stage delivers separates drive from winding;
    # the current and speed are measured already
    assert {tuple(e["pair"]): e["sensors"] for e in rep["sensor_placement"]} == {
        ("drive", "winding"): ["V_eff"], ("winding", "drive"): ["V_eff"]}
    assert rep["achieved"] == rep["achievable"]


def test_unrealisable_candidate_is_refused_with_the_reason(cylinder_design):
    model, cfg = cylinder_design.model, cylinder_design.config
    cands = {(c.keep, c.check): c for c in candidate_residuals(model, [f.name for f in
                                                                       model.faults])}
    # chamber p, position and velocity driven by pn, checked on pp: position is an
    # unobservable integrator there, the realignment gain does not exist
    why = check_driven_parallel(model, cfg, cands[(("Pp", "x", "xdot"), "pp")])
    assert "not detectable" in why
    assert check_driven_parallel(model, cfg, cands[(("Pp", "x", "xdot"), "x3")]) == ""


@pytest.fixture(scope="module")
def fault_runs(cylinder_design):
    """Short closed-loop runs of the pneumatic faults, through the compiled core."""
    from fdigen.detect import fdi_runner
    from fdigen.sim.plant import FaultEvent, simulate

    runner = fdi_runner(cylinder_design)
    out = {}
    for name in ("valve", "leak_p", "leak_n", "blockage_p", "blockage_n"):
        size = cylinder_design.model.fault(name).test_size
        sim = simulate(cylinder_design.model, 5.0, seed=11,
                       faults=(FaultEvent(name, 2.5, size),))
        out[name] = (sim, runner.run(sim.u, sim.y))
    return out


def test_each_newly_isolable_pair_is_isolated_in_simulation(cylinder_design, fault_runs):
    """Before R8/R9, the valve and the four leaks/blockages were one group; now every
    fault is narrowed to the faults with its own signature (its line)."""
    table = cylinder_design.signature_table
    ev = cylinder_design.evaluation
    for name, (sim, out) in fault_runs.items():
        d = summarise_run(cylinder_design, sim.t, out)["diagnosis"]
        # the last set that explained every flag (late closed-loop consequences, e.g. w1
        # when the estimate diverges after an actuator loss, may contradict every fault)
        best = sorted(f for f, s in table.items() if s == table[name])
        assert sorted(d["last_consistent_faults"]) == best, (name, d)
        assert d["t_fault_set"] is not None and d["t_fault_set"] > 2.5
        assert d["fault"] == "pneumatic_or_actuator"
        # the mask is the consistent faults of the flags, as the evaluation defines it
        flags = np.asarray(out["flags"])
        assert all(int(m) == ev.consistent_faults(int(f))
                   for m, f in zip(out["faults"][::97], flags[::97]))


def test_ambiguous_diagnosis_lists_the_consistent_faults(cylinder_design, fault_runs):
    sim, out = fault_runs["leak_p"]
    ev = cylinder_design.evaluation
    # the same run cut just after the first flag: no class yet, several faults consistent
    k = int(np.flatnonzero(np.asarray(out["flags"]) != 0)[0]) + 1
    cut = {key: np.asarray(v)[:k] for key, v in out.items()}
    cut["fault_class"] = np.zeros(k, dtype=np.int64)
    summary = summarise_run(cylinder_design, sim.t[:k], cut)
    d = summary["diagnosis"]
    assert d["fault"] == "none" and summary["flags"]
    expected = fault_names(cylinder_design, ev.consistent_faults(int(cut["flags"][-1])))
    assert d["candidates"] == expected and len(expected) > 1
    assert d["fault_set"] == " or ".join(expected)


def test_fault_simulation_confirms_every_new_signature_entry(cylinder_design):
    """Each fault moves the new residuals exactly as the structural table says (over the
    whole horizon: these entries separate faults of one class, often after its decision)."""
    from fdigen.verify.sensitivity import numeric_signatures

    new = {e["residual"] for e in cylinder_design.extra_residuals
           if e["purpose"].endswith("structural isolability")}
    assert new == {"R8", "R9"}
    numeric = numeric_signatures(cylinder_design, duration=5.0, t_fault=2.5, horizon=2.0,
                                 stop_at_isolation=False)
    assert numeric["healthy"] == []
    for fault, responded in numeric["faults"].items():
        assert set(responded) & new == cylinder_design.signature_table[fault] & new, fault


def test_inspect_reports_isolability_text_and_json():
    import json

    from click.testing import CliRunner

    from fdigen.cli import main

    res = CliRunner().invoke(main, ["inspect", "--model", "dc_motor", "--json"])
    assert res.exit_code == 0, res.output
    iso = json.loads(res.output)["isolability"]
    assert iso["achieved"] == iso["achievable"]
    assert iso["achieved_non_isolable"] == [["drive", "winding"], ["winding", "drive"]]
    res = CliRunner().invoke(main, ["inspect", "--model", "dc_motor"])
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "ordered pairs not isolable: 2 achieved, 2 achievable" in text
    assert "drive from winding: a sensor on V as the actuator delivers it (V_eff)" in text

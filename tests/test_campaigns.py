"""Every shipped model through the tune campaign at test size (issue 16's must-hold).

For each model of ``src/fdigen/models/`` the campaign of ``fdigen tune`` runs with the
committed thresholds (every tuned residual kept: the design as shipped is what is checked)
and a few seeded runs, and the test asserts

* no false alarm in the validation runs,
* no wrong isolation (a class isolated while another class's fault was injected),
* every declared fault detected at its test size,
* every fault isolated (its class) where the signature table says it is isolable.

*Isolable* is computed from the design's evaluation, never written down: fault ``f`` is
class-isolable when its class-level signature (the flags the class decision reads, without
the measurement-validity indicators ``nf_<y>``, which only an invalid sample raises) is not
empty and contained in the class-level signature of no fault of another class. Under the
sound rule (``docs/isolation.md``) a fault whose signature is contained in another
class's is never isolated from it, so these are exactly the faults the rule can isolate.

Where a must-hold is not met for a reason the design cannot fix by its thresholds, the
failure is listed in :data:`KNOWN` (and explained with numbers in ``docs/models.md``); the
test asserts that the failures are exactly these, so a new one fails and a fixed one
asks for its entry to be removed.
"""

from __future__ import annotations

import dataclasses

import pytest

from fdigen.design.cache import cached_design
from fdigen.model.model_file import builtin_model_path, load_model
from fdigen.tune import TuneSettings, tune
from fdigen.tune.fault_summary import wrong_isolation
from fdigen.tune.pipeline import class_isolable_faults

#: run length [s] per model: longer than the slowest isolation at test size after the
#: onset at half the run (three_tank's clogging needs its T2 balance R4: ~220 s)
DURATION = {"pneumatic_cylinder": 10.0, "dc_motor": 10.0, "three_tank": 600.0,
            "heat_exchanger": 1200.0}

#: must-holds not met, (kind, fault) -> why (docs/isolation.md, section 7)
KNOWN = {
    # the dc_motor tachometer is isolated at test size as the campaign now runs it (a 20
    # rad/s step and a 200 rad/s^2 drift); the former 20 rad/s^2 drift is still followed by
    # R1 (docs/models.md, "dc_motor tach")
    "three_tank": {
        # the drifts reach their test size half-way through the run's time after the onset
        # (1.3e-4 m/s: 2 cm 150 s after it) and are detected; the slower drifts of
        # earlier campaigns (3.9e-5 m/s, test size after the plant's 515 s time constant,
        # never reached within the run) were missed: docs/isolation.md, sections 7, 12
        ("not_isolated_ramp", "s2"): "R5 (a filter) absorbs the drift; s2 stays with clog12",
        # the s2 step, never isolated before, is: R6 (the T1 + T2 volume, blind to the
        # clogging) decides classes (structural_classes). It also makes these faults
        # class-isolable, isolated in some runs of the larger campaign (docs/isolation.md,
        # section 18) but not in this one run at the test size:
        ("not_isolated", "pump1"): "R6 and R1 alone: consistent with level sensor 1 until R2",
        ("not_isolated", "s1"): "R1, R6: consistent with the leak and the pump until R4",
        ("not_isolated_ramp", "s1"): "R1, R6: consistent with the leak and the pump",
    },
    # heat exchanger: the cold-thermometer drift, missed before, is detected since R2 (the
    # stored heat, blind to fouling) joined the design; deciding classes, R2 makes the
    # heater, the insulation and the thermometers class-isolable (heater, insulation and
    # the cold step isolated here), and these stay:
    "heat_exchanger": {
        ("not_isolated", "hot_sensor"): "Rh, R2: consistent with the hot-loop losses",
        ("not_isolated_ramp", "cold_sensor"): "R1 and Rc absorb part of the drift",
    },
}


def class_isolable(design) -> dict:
    """Fault -> whether the class decision can isolate it (see the module docstring;
    computed by the campaign's own :func:`fdigen.tune.pipeline.class_isolable_faults`)."""
    ok = set(class_isolable_faults(design))
    return {f.name: f.name in ok for f in design.model.faults}


def campaign(name: str) -> tuple[dict, dict]:
    model = load_model(builtin_model_path(name))
    design = cached_design(model)
    kept = tuple(n for n in design.residual_names if n in design.config.thresholds)
    settings = TuneSettings(runs=2, validation_runs=2, duration=DURATION[name],
                            fault_factors=(1.0,), fault_starts=1, seed=1, keep=kept)
    report = tune(name, settings, scheduler="synchronous", progress=False)
    return report, class_isolable(design)


def must_hold_failures(report: dict, isolable: dict) -> set:
    """(kind, fault) for every must-hold not met; ("false_alarm", "validation") for the
    validation runs. Additive sensor faults run as a step and as a ramp (drift at the
    fault's ``test_rate``, or test_size over the plant's slowest time constant): a ramp's
    miss is ``missed_ramp``, its class not isolated ``not_isolated_ramp``."""
    out = set()
    if report["false_alarm"]["validation_false_alarms"]:
        out.add(("false_alarm", "validation"))
    for run in report["runs"]["fault"]:
        fault, ramp = run["fault"], "_ramp" if run["ramp"] else ""
        if wrong_isolation(run):
            out.add(("wrong_isolation", fault))
        if not run["detected"]:
            out.add(("missed" + ramp, fault))
        if isolable[fault] and not run["isolation_correct"]:
            out.add(("not_isolated" + ramp, fault))
    return out


@pytest.mark.parametrize("name", sorted(DURATION))
def test_campaign_at_test_size_meets_the_must_holds(name):
    report, isolable = campaign(name)
    assert {f.name for f in load_model(builtin_model_path(name)).faults} \
        == set(report["faults"])
    # the thresholds checked are the committed ones
    assert report["thresholds"] == report["current_thresholds"]
    assert report["false_alarm"]["validation_runs"] == 2
    failures = must_hold_failures(report, isolable)
    assert failures == set(KNOWN.get(name, {})), (name, failures)
    # every case missed at its test size says whether the parameter spread masks it
    missed = {(r["fault"], "drift" if r["ramp"] else "step") for r in report["runs"]["fault"]
              if not r["detected"] and not r["false_alarm_before_onset"]}
    masking = report["parameter_masking"]
    assert {(e["fault"], e["kind"]) for e in masking} == missed
    assert all(e["remainder"] >= 0 and e["effect"] > 0 for e in masking)
    # what holds besides: no false alarm, and no wrong isolation on any shipped model
    assert report["false_alarm"]["validation_false_alarms"] == 0
    assert not {f for k, f in failures if k == "wrong_isolation"}
    assert not report["wrong_isolations_by_class"]
    for fault, entry in report["faults"].items():
        steps = [b for b in entry["by_size"] if b["kind"] == "step"]
        assert [b["runs"] for b in steps] == [1], fault
        assert entry["runs"] == (2 if entry["ramp"] else 1), fault
        assert entry["false_alarms_before_onset"] == 0, fault


def test_class_isolability_follows_the_signature_table():
    """The cylinder: every fault isolable; the heat exchanger: with R2 (blind to fouling)
    deciding classes, every fault is; without it a thermometer offset lay inside fouling's
    signature (R1 and its own balance). The class decision reads the class-deciding
    residuals only."""
    cyl = class_isolable(cached_design(load_model(builtin_model_path("pneumatic_cylinder"))))
    assert all(cyl.values())
    design = cached_design(load_model(builtin_model_path("heat_exchanger")))
    he = class_isolable(design)
    ev = design.evaluation
    deciding = {n for i, n in enumerate(ev.residuals) if ev.class_flags >> i & 1}
    assert {"Rh", "Rc", "R1", "R2"} <= deciding
    table = {f: {r for r in rs if r in deciding and not r.startswith("nf_")}
             for f, rs in design.signature_table.items()}
    for f, ok in he.items():
        inside = any(design.model.fault(g).fault_class != design.model.fault(f).fault_class
                     and table[f] <= table[g] for g in table)
        assert ok == (not inside), f
    assert he["cold_sensor"] and he["fouling"] and he["heater"]
    old = cached_design(dataclasses.replace(design.model, fdi={
        **design.model.fdi, "structural_classes": False}))
    assert not class_isolable(old)["cold_sensor"]

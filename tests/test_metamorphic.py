"""Metamorphic tests: a plant written another way means the same plant.

For every shipped model and holdout plant, a twin written another way (every name changed;
states, equations, outputs, faults and residual tables reordered; a state in another unit
(x100: m -> cm); a parameter in another unit (x1e-3); an input in another unit (x100:
a pump's voltage in percent, the controllers' gains and limits with it); a sensor read through a gain and an
offset (volts); definitions inlined, or each equation moved into a definition; a sensor
fault written inside its sensor's map, an actuator fault inside the input the plant
receives) must derive
the same signature table (up to renaming the residuals), the same fault pairs left
unresolved, and simulate the same closed loop (same seed) up to the scaling, to
``SIM_RTOL``. The rewrites are pure functions over the TOML document
(``tests/metamorphic/rewrite.py``); the invariants are in ``tests/metamorphic/invariants.py``.

``FDIGEN_FULL_SWEEP=1`` runs each rewrite on its own as well.
"""

import copy
import os
from pathlib import Path

import numpy as np
import pytest

from fdigen.model.model_file import builtin_model_path
from metamorphic import rewrite as rw
from fdigen.sim.plant import FaultEvent
from metamorphic.invariants import (SIM_RTOL, canonical_table, close, design_of, diagnose,
                                    doc_of, paper_table, simulate_pair, unresolved,
                                    with_twin_thresholds)

DATA = Path(__file__).parent / "data"
PLANTS = {**{m: builtin_model_path(m) for m in ("pneumatic_cylinder", "dc_motor",
                                                 "three_tank", "heat_exchanger")},
          **{p.stem: p for p in sorted((DATA / "holdout").glob("*.toml"))},
          "two_tanks": DATA / "two_tanks.toml"}
FULL = os.environ.get("FDIGEN_FULL_SWEEP") == "1"
#: CI runs the composite rewrite on every plant (issue 20: every shipped and holdout model)
IN_CI = bool(os.environ.get("CI"))
#: Plants whose composite twin runs with FDIGEN_FULL_SWEEP=1 only, to keep the default tier
#: within its time budget (two designs each: 25 s, 9 s, 7.5 s, 5 s measured cold on the
#: shared machine; 3 s, 8 s, 8.5 s, 5 s with the designs of the originals in the cache).
SLOW = {"pneumatic_cylinder", "boost_converter", "three_tank", "heated_tank"}


def _voted_or_mixed(doc):
    """Outputs a scale would change the meaning of without more rewriting: the voter's
    channels (its tolerance is in their common unit)."""
    fdi = doc.get("fdi", {})
    return set(fdi.get("voter", {}).get("channels", []))


def renames(doc) -> dict:
    names = {}
    for sect in ("states", "inputs", "outputs", "parameters", "definitions", "faults"):
        for name in doc.get(sect, {}):
            names[name] = f"{name}w"
    return names


def _movable_sensor_fault(doc):
    """The first sensor fault with one term on an output outside the voter: the one the
    composite twin writes inside its sensor's map."""
    for name, f in doc.get("faults", {}).items():
        if f.get("location") == "sensor" and "target" in f and \
                f["target"] not in _voted_or_mixed(doc):
            return name
    return None


def composite(doc, reorder: bool = True) -> rw.Twin:
    """Every rewrite at once (see the module docstring)."""
    tw = rw.twin(doc)
    tw = tw.then(rw.inline_definitions) if doc.get("definitions") else \
        tw.then(rw.extract_definitions)
    sensor = _movable_sensor_fault(doc)
    if sensor:
        tw = tw.then(rw.sensor_fault_in_map, sensor)
    actuator = next((f for f, spec in doc.get("faults", {}).items()
                     if spec.get("location") == "actuator" and "target" in spec), None)
    if actuator:
        tw = tw.then(rw.actuator_fault_in_definition, actuator)
    first_state = next(iter(doc["states"]))
    tw = tw.then(rw.scale_state, first_state, 100.0)
    par = next(p for p in doc["parameters"])
    tw = tw.then(rw.scale_parameter, par, 1e-3)
    tw = tw.then(rw.scale_input, next(iter(doc["inputs"])), 100.0)
    out = [o for o in doc["outputs"] if o not in _voted_or_mixed(doc)]
    if out:
        tw = tw.then(rw.scale_output, out[-1], 20.0, 0.5)
    if reorder:
        tw = tw.then(rw.reorder)
    return tw.then(rw.rename, renames(tw.doc))


def single_rewrites(doc):
    states = list(doc["states"])
    outs = [o for o in doc["outputs"] if o not in _voted_or_mixed(doc)]
    yield "rename", rw.rename(doc, renames(doc))
    yield "reorder", rw.reorder(doc)
    yield "extract", rw.extract_definitions(doc)
    if doc.get("definitions"):
        yield "inline", rw.inline_definitions(doc)
    yield "scale_state", rw.scale_state(doc, states[-1], 0.01)
    yield "scale_parameter", rw.scale_parameter(doc, list(doc["parameters"])[-1], 1e5)
    yield "scale_input", rw.scale_input(doc, list(doc["inputs"])[-1], 1e-2)
    if outs:
        yield "volts", rw.scale_output(doc, outs[0], 0.5, -1.0)
    for name, f in doc.get("faults", {}).items():
        if f.get("location") == "actuator" and "target" in f:
            yield f"fault_on_equations_{name}", rw.fault_on_equations(doc, name)
            yield f"actuator_fault_in_definition_{name}", \
                rw.actuator_fault_in_definition(doc, name)
        if f.get("location") == "sensor" and "target" in f:
            yield f"sensor_fault_in_map_{name}", rw.sensor_fault_in_map(doc, name)


def check_twin(plant, doc, tw, noise=True):
    d0 = design_of(doc, f"{plant}.toml", PLANTS.get(plant.split(":")[0]))
    d1 = design_of(tw.doc, f"{plant}_twin.toml")
    assert canonical_table(d1, tw.names) == canonical_table(d0), plant
    assert paper_table(d1, tw.names) == paper_table(d0), plant
    assert unresolved(d1, tw.names) == unresolved(d0), plant
    check_simulation(plant, doc, tw, noise)


def check_simulation(plant, doc, tw, noise=True):
    r0, (r1, u1, y1) = simulate_pair(doc, tw, samples=200, noise=noise)
    assert close(r0.y, y1) < SIM_RTOL, (plant, close(r0.y, y1))
    assert close(r0.u, u1) < SIM_RTOL, (plant, close(r0.u, u1))


@pytest.mark.parametrize("plant", sorted(PLANTS))
def test_composite_rewrite_keeps_the_meaning(plant):
    if plant in SLOW and not (FULL or IN_CI):
        pytest.skip("CI or FDIGEN_FULL_SWEEP=1: slow design")
    doc = doc_of(PLANTS[plant])
    check_twin(plant, doc, composite(doc), noise=False)    # outputs reordered
    check_simulation(plant, doc, composite(doc, reorder=False))


@pytest.mark.skipif(not FULL, reason="FDIGEN_FULL_SWEEP=1: each rewrite on its own")
@pytest.mark.parametrize("plant", sorted(PLANTS))
def test_each_rewrite_keeps_the_meaning(plant):
    doc = doc_of(PLANTS[plant])
    for name, tw in single_rewrites(doc):
        check_twin(f"{plant}:{name}", doc, tw, noise=name != "reorder")


def test_rewriter_is_pure_and_round_trips():
    doc = doc_of(PLANTS["three_tank"])
    before = repr(doc)
    tw = composite(doc)
    assert repr(doc) == before                       # the original is never changed
    assert tw.doc != doc
    import tomllib
    assert tomllib.loads(rw.dumps(doc)) == rw._reorder_like(doc, None)
    np.testing.assert_equal(rw._guard("a*sqrt(2*g*(h1 - h2)) + sqrt(x)"),
                            "a*sqrt(max(2*g*(h1 - h2), 0)) + sqrt(max(x, 0))")
    assert rw.unguard_sqrt({"d": {"q": "sqrt(max(2*g*(h1 - h2), 0))"}}).doc == \
        {"d": {"q": "sqrt(2*g*(h1 - h2))"}}


# -- plants written the way a user would, and their rewritten twins --------------------------
USER = DATA / "metamorphic"


def quadruple_twin(doc) -> rw.Twin:
    """The quadruple tank as the README's examples write it: flows inline (so the pump
    fault on ``v1`` acts in [dynamics]), sensors in cm (``2*kc*h = h``), guarded sqrt,
    the offset of level sensor 1 written inside its map, pump 1's voltage in percent."""
    tw = rw.twin(doc).then(rw.inline_definitions).then(rw.sensor_fault_in_map, "s1")
    tw = tw.then(rw.scale_input, "v1", 10.0)
    for y in doc["outputs"]:
        tw = tw.then(rw.scale_output, y, 2.0, 0.0)
    return tw.then(rw.guard_sqrt)


def servo_twin(doc) -> rw.Twin:
    """The servo actuator with the valve flow inline, the load pressure in Pa, the
    position read in mm, the sqrt guarded and the position sensor's fault written inside
    its map."""
    return (rw.twin(doc).then(rw.inline_definitions).then(rw.sensor_fault_in_map, "sx")
            .then(rw.scale_state, "PL", 1e5)
            .then(rw.scale_output, "yx", 10.0, 0.0).then(rw.guard_sqrt))


#: plant -> (twin, fault start [s], samples per log, faults that must be detected: each
#: fault at its test size, each sensor also stuck)
USER_PLANTS = {"quadruple_tank": (quadruple_twin, 150.0, 3000, {"pump1", "leak1", "s1", "s2",
                                                                  "s1 stuck", "s2 stuck"}),
               "servo_valve": (servo_twin, 2.0, 5000, {"valve", "leak", "sx", "spl",
                                                        "sx stuck", "spl stuck"})}


@pytest.mark.parametrize("plant", sorted(USER_PLANTS))
def test_user_plant_same_table_simulation_and_diagnosis(plant):
    """An input fault acting through [definitions], a sensor in volts, an unguarded sqrt:
    the same signature table, simulation and diagnosis of every fault case as the twin."""
    make, t0, samples, detected = USER_PLANTS[plant]
    doc = doc_of(USER / f"{plant}.toml")
    tw = make(doc)
    d0 = design_of(doc, f"{plant}.toml", USER / f"{plant}.toml")
    d1 = design_of(tw.doc, f"{plant}_twin.toml")
    actuator = next(f for f, spec in doc["faults"].items() if spec["location"] == "actuator")
    assert d0.signature_table[actuator], d0.signature_table   # the input fault acts
    assert canonical_table(d1) == canonical_table(d0)
    assert unresolved(d1) == unresolved(d0)
    d1 = with_twin_thresholds(d0, d1, tw)
    cases = [()] + [(FaultEvent(f, t0, spec["test_size"]),)
                    for f, spec in doc["faults"].items()]
    cases += [(FaultEvent(f, t0, 0.0, stuck=True),) for f, spec in doc["faults"].items()
              if spec["location"] == "sensor"]
    decisions = {}
    for case in cases:
        r0, (r1, u1, y1) = simulate_pair(doc, tw, samples=samples, faults=case)
        assert close(r0.y, y1) < SIM_RTOL
        a, b = diagnose(d0, r0.u, r0.y), diagnose(d1, r1.u, r1.y)
        decisions[(case[0].name + (" stuck" if case[0].stuck else "")) if case
                  else "healthy"] = a
        b["candidates"] = sorted({v: k for k, v in tw.names.items()}.get(c, c)
                                 for c in b["candidates"])
        assert a == b, (case, a, b)
    print(plant, decisions)
    assert decisions["healthy"]["fault"] == "none"
    assert {k for k, d in decisions.items() if d["detected"]} == detected, decisions


def test_quadruple_tank_derives_residuals_through_volt_sensors():
    doc = doc_of(USER / "quadruple_tank.toml")
    d0 = design_of(doc, "quadruple_tank.toml", USER / "quadruple_tank.toml")
    assert {e["blind_to"] for e in d0.extra_residuals} == {None, "pump1"}


def test_user_plant_fault_on_equations_same_table():
    """The pump loss written as terms on the two balances its flow feeds derives the same
    table as the same fault on the input (it was an xfail: the structure saw one fault in
    two equations and not the one unknown flow a combination of the two eliminates, so
    the residual blind to pump1 was not derived; design/structure.py, ``_one_channel``)."""
    doc = doc_of(USER / "quadruple_tank.toml")
    tw = rw.twin(doc).then(rw.fault_on_equations, "pump1")
    d0 = design_of(doc, "quadruple_tank.toml", USER / "quadruple_tank.toml")
    d1 = design_of(tw.doc, "quadruple_tank_terms.toml")
    assert canonical_table(d1) == canonical_table(d0)


def _inspect_json(path) -> dict:
    import json

    from click.testing import CliRunner

    from fdigen.cli import main

    res = CliRunner().invoke(main, ["inspect", "--model", str(path), "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.output)


def _derived(report: dict) -> list:
    keep = ("residual", "equations", "drivers", "check", "blind_to", "realisation", "purpose")
    return [{k: e[k] for k in keep} for e in report["extra_residuals"]]


def test_nonsmooth_flow_with_volt_sensors_derives_what_cm_sensors_derive(tmp_path):
    """A first-time user's two tanks: the pipe flow ``a12*sign(h1 - h2)*sqrt(2 g |h1 - h2|)``
    in [definitions] and level sensors in volts (``y = kv*h``). Substituting the sensor's
    inverse ``h2 = y2/kv`` into the sub-model of ``h1`` left ``sign(h1 - y2/kv)``, whose
    argument sympy cannot prove real (``kv`` might be 0), differentiated as an unevaluated
    ``Derivative``: inspect exited 3 ("Can't calculate derivative wrt 0"). The same plant
    read in cm (``y = h``) must derive the same residuals and signature table."""
    volts = DATA / "user_twotank_volts.toml"
    doc = doc_of(volts)
    cm = copy.deepcopy(doc)
    kv = doc["parameters"]["kv"]["value"]
    for y, h in (("y1", "h1"), ("y2", "h2")):
        cm["outputs"][y]["expr"] = h
        cm["outputs"][y]["noise_std"] = doc["outputs"][y]["noise_std"] / kv
    cm["simulation"]["controllers"]["level2"]["measurement"] = "y2"
    (tmp_path / "user_twotank_cm.toml").write_text(rw.dumps(cm))
    a = _inspect_json(volts)
    b = _inspect_json(tmp_path / "user_twotank_cm.toml")
    assert [e["residual"] for e in a["extra_residuals"]] == ["R3", "R4"]
    assert _derived(a) == _derived(b)
    assert a["signature_table"] == b["signature_table"]
    # the physics: the balance of T1 driven by y2 does not see the leak of T2, the balance
    # of T2 driven by y1 does not see the pump; a fault of y2 reaches both through y2
    table = a["signature_table"]
    assert {r: sorted(f for f, v in table[r].items() if v) for r in ("R3", "R4")} == {
        "R3": ["lvl_drift", "lvl_offset", "pumploss"],
        "R4": ["leak2", "lvl_drift", "lvl_offset"]}, table

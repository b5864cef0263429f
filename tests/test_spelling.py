"""Derivations depend on the physics, not on how the plant is spelled.

The three cases users met (issue 20), each on a small variant of the holdout two-tank
plant: an actuator fault whose input is used in [definitions]; level sensors in volts
(``kc*h + off``); an unguarded ``sqrt`` of a level difference.
"""

from pathlib import Path

import pytest
import sympy as sp

from fdigen.design.signatures import candidate_residuals
from fdigen.errors import DesignError
from fdigen.model.model_file import parse_model_text
from fdigen.model.sensor_maps import not_invertible, sensor_maps
from metamorphic.invariants import doc_of
from metamorphic import rewrite as rw

BASE = doc_of(Path(__file__).parent / "data" / "holdout" / "two_tank.toml")


def model(doc):
    return parse_model_text(rw.dumps(doc), source="variant.toml")


def with_pump_flow_defined(doc):
    """The pump flow ``qin = Kp*u`` as a definition: the pump fault on ``u`` reaches the
    dynamics only through it."""
    doc = rw.twin(doc).doc
    doc["definitions"] = {"qin": "Kp*u", **doc["definitions"]}
    doc["dynamics"]["h1"] = "(qin - q1)/A1"
    return doc


def test_actuator_fault_acts_through_definitions():
    inline, defined = model(BASE), model(with_pump_flow_defined(BASE))
    pump = sp.Symbol("pump", real=True)
    point = {s: 0.1 + 0.01 * k for k, s in enumerate(
        sorted(defined.f(with_faults=True).free_symbols, key=str))}
    assert defined.f(with_faults=True).xreplace(point).evalf() == \
        inline.f(with_faults=True).xreplace(point).evalf()
    # before: f(with_faults) replaced u in [dynamics] only, and the fault was lost
    assert defined.f(with_faults=True)[0].has(pump)


def test_sensor_in_volts_is_inverted():
    doc = rw.scale_output(BASE, "L1", 20.0, 0.5).doc
    m = model(doc)
    (sm,) = sensor_maps(m)["h1"]
    y = sp.Symbol("L1", real=True)
    assert sp.simplify(sm.inverse - (y - sp.Rational(1, 2)) / 20) == 0
    assert sm.gain == pytest.approx(20.0)
    # the volts sensor drives the same sub-model residual as the metres one
    labels = {c.label for c in candidate_residuals(m, [f.name for f in m.faults])}
    assert "equations [h2] driven by [h1<-L1], checked on L2" in labels


def test_output_not_invertible_over_its_range_is_named():
    doc = rw.twin(BASE).doc
    doc["states"]["h1"]["range"] = [-0.1, 0.25]
    doc["outputs"]["L1"]["expr"] = "h1**2"
    reasons = not_invertible(model(doc))
    assert "not monotonic in h1" in reasons["L1"]
    assert "h1" not in sensor_maps(model(doc))


def difference_flow(doc, h1_range=(0.15, 0.28)):
    """Tank 1 drains into tank 2 through ``sqrt(2*g*(h1 - h2))``, unguarded: defined
    where the ranges keep ``h1 > h2``."""
    doc = rw.twin(doc).doc
    doc["definitions"]["q1"] = "a1*sqrt(2*g*(h1 - h2))"
    doc["states"]["h1"]["range"] = list(h1_range)
    doc["states"]["h2"]["range"] = [0.05, 0.13]
    doc["operating_point"].update(h1="2*h0", h2="h0")
    doc["parameters"]["h0"]["value"] = 0.1
    doc["faults"]["leak1"]["term"] = "-leak1/A1"
    doc["simulation"]["reference"] = "0.1 + 0.01*sin(2*pi*0.01*t)"
    doc["simulation"]["initial"] = {"h1": 0.2, "h2": 0.1}
    doc["fdi"]["thresholds"] = {k: v for k, v in doc["fdi"]["thresholds"].items()
                                if k in ("R1", "R2", "K1", "K2")}
    return doc


def test_unguarded_sqrt_builds_like_the_guarded_one():
    """Before: 'TypeError: Cannot convert complex to float' (the driver input of the
    sub-model [h1] driven by L2 was drawn in (-1, 1), outside the declared ranges)."""
    doc = difference_flow(BASE)
    cands = []
    for variant in (doc, rw.guard_sqrt(doc).doc):
        m = model(variant)
        cands.append({(c.label, tuple(sorted(f for f, hit in c.signature.items() if hit)))
                      for c in candidate_residuals(m, [f.name for f in m.faults])})
    assert cands[0] == cands[1]
    assert any("driven by [h2<-L2]" in label for label, _ in cands[0]), cands[0]


def test_sqrt_outside_its_domain_names_equation_point_and_fix():
    doc = difference_flow(BASE, h1_range=(0.05, 0.28))     # h1 - h2 < 0 in the ranges
    m = model(doc)
    with pytest.raises(DesignError, match=r"dynamics\.h\d .*not real at h1 = .*max\(h, 0\)"):
        candidate_residuals(m, [f.name for f in m.faults])


def test_inspect_reports_sensor_maps():
    from fdigen.design.describe import sensor_map_report

    volts = sensor_map_report(model(rw.scale_output(BASE, "L1", 20.0, 0.5).doc))
    assert volts["measures"]["L1"]["inverse"] == "h1 = L1/20 - 1/40"
    doc = rw.twin(BASE).doc
    doc["states"]["h1"]["range"] = [-0.1, 0.25]
    doc["outputs"]["L1"]["expr"] = "h1**2"
    assert "L1" in sensor_map_report(model(doc))["not_measurements"]
    assert sensor_map_report(model(BASE)) == {"measures": {}, "not_measurements": {}}


def test_a_sensor_fault_written_in_its_map_sticks_and_drifts_like_its_term():
    """A sensor fault declared without target, inside the sensor's map (a definition the
    output reads): the same outputs reached, validity flag, stuck sensor and drift as the
    term spelling (the stuck case and the validity flag read the fault's target, which it
    has not)."""
    import numpy as np
    from fdigen.design.fdi_design import fdi_design
    from fdigen.sim.plant import FaultEvent, simulate
    m0 = model(BASE)
    m1 = model(rw.sensor_fault_in_map(BASE, "level1").doc)
    assert m1.fault("level1").target in (None, "")
    assert m1.outputs_reached(m1.fault("level1")) == m0.outputs_reached(m0.fault("level1")) \
        == ("L1",)
    dt = float(BASE["fdi"]["sample_time"])
    for ev in (FaultEvent("level1", 40 * dt, 0.0, stuck=True),
               FaultEvent("level1", 40 * dt, 0.02),
               FaultEvent("level1", 40 * dt, 1e-4, ramp=True)):
        y0, y1 = (simulate(m, 200 * dt, faults=(ev,), seed=4).y for m in (m0, m1))
        assert np.max(np.abs(y0 - y1)) <= 1e-12 * np.max(np.abs(y0)), ev
    t0, t1 = (fdi_design(m).signature_table["level1"] for m in (m0, m1))
    assert "nf_L1" in t1 and t0 == t1
    # and the sensitivity line says it the same way: "offsets from 0.02 m"
    from fdigen.tune.fault_sensitivity import fault_unit, offset_of
    assert [(offset_of(m, m.fault("level1")), fault_unit(m, m.fault("level1")))
            for m in (m0, m1)] == [("L1", "m")] * 2

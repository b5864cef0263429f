"""An action for every state, contradiction escalates, and the fault sensitivity report
(``docs/isolation.md`` section 10).

The three tanks with a leak in tank 1: the flags leave several classes consistent, every
one of them calling for ``safety_stop`` (after a short ambiguity with a sensor class): the
action is taken long before any class is (on main: ``none`` for the whole run), bit for
bit on the reference, CasADi and C backends.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from fdigen.backends.c import CFdi
from fdigen.backends.casadi_backend.runner import CasadiFdi
from fdigen.backends.reference import ReferenceFdi
from fdigen.design.cache import cached_design
from fdigen.design.config import read_fdi_config
from fdigen.detect import summarise_run
from fdigen.errors import ModelFileError
from fdigen.model.model_file import builtin_model_path, load_model
from fdigen.sim.plant import FaultEvent, simulate
from fdigen.tune.fault_sensitivity import measured_sensitivity


@pytest.fixture(scope="module")
def tank():
    return cached_design(load_model(builtin_model_path("three_tank")))


@pytest.fixture(scope="module")
def leak_run(tank):
    sim = simulate(tank.model, 600.0, faults=(FaultEvent("leak1", 300.0, 0.25),), seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        out = ReferenceFdi(tank).run(sim.u, sim.y)
    return sim, out


def test_leak_in_tank_1_is_acted_on_before_any_isolation(tank, leak_run):
    sim, out = leak_run
    ev = tank.evaluation
    flags, act = np.asarray(out["flags"]), np.asarray(out["action"])
    k_flag = int(np.flatnonzero(flags)[0])
    k_act = int(np.flatnonzero(act)[0])
    assert sim.t[k_flag] >= 300.0
    # no class is isolated, yet the action is safety_stop, confirm samples after the
    # consistent classes' most severe action first held
    assert not np.any(out["fault_class"])
    assert act[-1] == 2
    assert k_act - k_flag == ev.confirm - 1
    s = summarise_run(tank, sim.t, out)["diagnosis"]
    assert s["fault"] == "none" and s["action"] == "safety_stop"
    assert s["t_action"] == pytest.approx(sim.t[k_act])
    # R6 (T1 + T2 volume, blind to the clogging between them) rose: the clogging is not
    # among the consistent classes; the leak and the level sensor are
    assert set(s["action_classes"]) == {"tank1_outflow", "level_sensor_1"}
    # with the policy "wait", the action waits until every consistent class calls for it.
    # Here it never does: R2 rises more than its validity horizon after the freeze (the
    # dedicated R2 model, frozen, drifts past its threshold within 14.1 s on a healthy
    # plant), so R2 is no evidence and level_sensor_1 (action none) stays consistent
    wait = dataclasses.replace(tank, evaluation=dataclasses.replace(ev, ambiguity="wait"))
    bit_r2, h_r2 = 1 << ev.residuals.index("R2"), ev.horizons[ev.residuals.index("R2")]
    assert h_r2 == 141                                 # 14.1 s in samples of 0.1 s
    w_out = _run(wait, sim)
    k_r2 = int(np.flatnonzero(flags & bit_r2)[0])
    assert k_r2 - k_flag > h_r2
    assert not np.any(w_out["action"])
    s1 = 1 << ev.fault_names.index("s1")
    assert np.all(np.asarray(w_out["faults"][k_flag:]) & s1)
    # a leak four times larger: R2 within its horizon excludes the sensor, then it acts
    big = simulate(tank.model, 420.0, faults=(FaultEvent("leak1", 300.0, 1.0),), seed=1)
    b_out = _run(wait, big)
    b_flags = np.asarray(b_out["flags"])
    k_b, k_b2 = int(np.flatnonzero(b_flags)[0]), int(np.flatnonzero(b_flags & bit_r2)[0])
    assert k_b2 - k_b <= h_r2
    k_wait = int(np.flatnonzero(b_out["action"])[0])
    assert k_wait - k_b2 == ev.confirm - 1 and b_out["action"][-1] == 2
    faults = b_out["faults"][k_wait]
    classes = {tank.model.fault(n).fault_class for k, n in enumerate(ev.fault_names)
               if faults >> k & 1}
    assert "level_sensor_1" not in classes
    assert {ev.actions[ev.classes.index(c)] for c in classes} == {"safety_stop"}


def _run(design, sim):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return ReferenceFdi(design).run(sim.u, sim.y)


def test_every_backend_takes_the_same_action(tank, leak_run, tmp_path):
    """With ``[fdi] ambiguity_time`` (here 150 samples): the most severe action of the
    ambiguous classes waits that long, on every backend."""
    sim, _ = leak_run
    ev = tank.evaluation
    slow = dataclasses.replace(tank, evaluation=dataclasses.replace(ev, ambiguity_confirm=150))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        r_out = ReferenceFdi(slow).run(sim.u, sim.y)
    k_flag = int(np.flatnonzero(r_out["flags"])[0])
    assert int(np.flatnonzero(r_out["action"])[0]) - k_flag == 150 - 1
    c_out = CFdi(slow, cache_dir=tmp_path).run(sim.u, sim.y)
    k_out = CasadiFdi(slow, compiled=True).run(sim.u, sim.y)
    for key in ("flags", "fault_class", "action", "faults"):
        assert np.array_equal(c_out[key], r_out[key]), key
        assert np.array_equal(k_out[key], r_out[key]), key


def test_policy_keys_are_validated(tank):
    model = tank.model
    for key, value, match in (("ambiguity", "most", "ambiguity"),
                              ("ambiguity_time", -1.0, "ambiguity_time"),
                              ("unexplained_action", "stop", "unexplained_action"),
                              ("escalate_after_isolation", 1, "escalate_after_isolation")):
        bad = dataclasses.replace(model, fdi={**model.fdi, key: value})
        with pytest.raises(ModelFileError, match=match):
            read_fdi_config(bad)
    cfg = read_fdi_config(model)
    assert (cfg.ambiguity, cfg.unexplained_action, cfg.escalate_after_isolation) == (
        "most_severe", "safety_stop", True)
    assert tank.evaluation.classes[-1] == "unexplained"
    assert tank.evaluation.actions[-1] == "safety_stop"


def test_measured_sensitivity_reads_the_campaign_sizes(tank):
    def size(s, runs, det, iso, delay):
        return {"size": s, "runs": runs, "detected": det, "isolated_correct": iso,
                "isolation_delay": {"max": delay}}

    summary = {"s1": {"ramp": False, "by_size": [size(0.01, 4, 3, 0, None),
                                                  size(0.02, 4, 4, 2, 30.0),
                                                  size(0.04, 4, 4, 4, 12.5)]},
               "leak1": {"ramp": False, "by_size": [size(0.125, 2, 1, 0, None)]}}
    out = measured_sensitivity(tank.model, summary)
    assert out["s1"]["detected_from"] == 0.02 and out["s1"]["isolated_from"] == 0.04
    assert out["s1"]["isolation_delay_max"] == 12.5
    unit = tank.model.outputs[0].unit
    assert out["s1"]["text"] == (f"s1: offsets from 0.02 {unit} detected, from 0.04 {unit} "
                                 "isolated within 12.5 s")
    assert out["leak1"]["detected_from"] is None
    assert "detected at 0.125 in some run, but not in every run" in out["leak1"]["text"]
    # missed in every run of every size is said so (a user's thermocouple offsets of
    # 0.5-2 K read "not detected in every run up to", as if some runs had seen them)
    blind = measured_sensitivity(tank.model, {"s3": {"ramp": False, "by_size": [
        size(0.5, 1, 0, 0, None), size(1.0, 1, 0, 0, None)]}})
    assert "offsets never detected, in no run of any size tried (0.5" in blind["s3"]["text"]
    # "from" holds for every larger size too: a user's room was told "from 25 detected"
    # with 50 missed in its one run
    gap = {"w": {"ramp": False, "by_size": [size(25.0, 1, 1, 0, None), size(50.0, 1, 0, 0, None),
                                             size(100.0, 1, 1, 1, 8.0)]}}
    out = measured_sensitivity(tank.model, {"s1": gap["w"]})["s1"]
    assert (out["detected_from"], out["isolated_from"]) == (100.0, 100.0)
    # one run per size says what one run did (a user's conveyor)
    assert out["text"].endswith("(1 run per size: more --fault-starts make it a rate)")
    # steps and ramps of one sensor fault (the campaign runs both): each its own smallest
    # size, ramps in units per second (a first-time user read a 0.05 step as "drifts
    # from 0.05 /s")
    both = {"s1": {"ramp": True, "by_size": [
        {**size(0.02, 4, 4, 4, 12.5), "kind": "step"},
        {**size(0.001, 4, 4, 0, None), "kind": "ramp"},
        {**size(0.002, 4, 4, 4, 40.0), "kind": "ramp"}]}}
    out = measured_sensitivity(tank.model, both)["s1"]
    assert (out["ramp"], out["detected_from"], out["isolated_from"]) == (False, 0.02, 0.02)
    assert (out["drift"]["ramp"], out["drift"]["detected_from"],
            out["drift"]["isolated_from"]) == (True, 0.001, 0.002)
    assert out["text"] == (f"s1: offsets from 0.02 {unit} detected, from 0.02 {unit} "
                           f"isolated within 12.5 s; drifts from 0.001 {unit}/s detected, "
                           f"from 0.002 {unit}/s isolated within 40 s")

"""The validity horizon of frozen residuals (``[fdi.frozen_horizon]``, docs/isolation.md).

A flag that rises more than ``H_r`` after the realignment froze is *late*: it stays in the
flags, and the class decision leaves it out. Checked on the three-tank level-sensor drift
that the frozen parallel model used to turn into a wrong ``clogging`` isolation, on every
backend (reference, CasADi, C double; C float the same flags), bit for bit.
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
from fdigen.design.evaluation import HORIZON_NONE, horizon_samples, late_mask
from fdigen.model.model_file import builtin_model_path, load_model
from fdigen.sim.plant import FaultEvent, simulate
from fdigen.tune.cases import make_cases, varied_simulation
from fdigen.tune.settings import TuneSettings


@pytest.fixture(scope="module")
def tank():
    return cached_design(load_model(builtin_model_path("three_tank")))


@pytest.fixture(scope="module")
def s1_log(tank):
    """The tune campaign's level-sensor-1 drift (onset at 0.5 of 900 s, seed 2; parameters
    drawn within +-10 %) that used to be isolated as clogging: the campaign's run at test
    size, with the drift it used to run (test_size per second, 0.02 m/s; the campaign now
    runs a step and a drift at test_size over the plant's time constant)."""
    model = tank.model
    settings = TuneSettings(runs=2, validation_runs=0, duration=900.0,
                            fault_factors=(1.0,), fault_starts=3, seed=2)
    case = next(c for c in make_cases(model, settings)["fault"]
                if c.fault[0] == "s1" and c.fault[1] == 450.0)
    case = dataclasses.replace(case, fault=("s1", 450.0, model.fault("s1").test_size, True))
    sim_model = dataclasses.replace(model, simulation=varied_simulation(
        model, case.ref_scale, case.ref_shift, {}))
    sim = simulate(sim_model, case.duration, faults=(FaultEvent(*case.fault),),
                   parameters=case.parameters, seed=case.seed)
    return sim.u, sim.y


def test_horizon_in_samples():
    assert horizon_samples(None, 0.1) == HORIZON_NONE
    assert horizon_samples(18.8, 0.1) == 188
    assert late_mask((HORIZON_NONE, 5, 0), 5) == 0b100
    assert late_mask((HORIZON_NONE, 5, 0), HORIZON_NONE) == 0b110


def test_late_flags_are_left_out_of_the_class_decision_on_every_backend(tank, s1_log, tmp_path):
    ev = tank.evaluation
    assert any(h != HORIZON_NONE for h in ev.horizons)
    ref = ReferenceFdi(tank)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        r_out = ref.run(*s1_log)
    flags = r_out["flags"]
    # the run exercises the rule: flags rose after their horizon and were left out
    assert ref.state.late != 0
    assert ref.state.late & ~int(flags[-1]) == 0
    late_names = {n for i, n in enumerate(ev.residuals) if ref.state.late >> i & 1}
    assert late_names - {"R1", "R2", "R3"} == set()
    # never a wrong class: the drift's late consequence R5 (no horizon, outside every
    # signature) escalates to unexplained, with its action; before it, no class
    assert _first_class(ev, r_out) in ("none", "level_sensor_1", "unexplained")
    assert ev.classes[int(r_out["fault_class"][-1])] == "unexplained"
    k_esc = int(np.flatnonzero(r_out["fault_class"] == ev.unexplained)[0])
    new = int(flags[k_esc]) & ~int(flags[k_esc - 1])
    assert [n for i, n in enumerate(ev.residuals) if new >> i & 1] == ["R5"]
    assert r_out["action"][-1] == 2
    # `fdigen detect` names the contradicting flag and what it contradicts
    from fdigen.detect import summarise_run

    t = np.arange(len(flags)) * tank.config.sample_time
    esc = summarise_run(tank, t, r_out)["diagnosis"]["unexplained"]
    assert esc["contradicting_flags"] == ["R5"]
    # R6 deciding classes (structural_classes) isolates the drift as its sensor first;
    # R5 then contradicts that class
    assert esc["contradicts"] == _first_class(ev, r_out) == "level_sensor_1"
    assert esc["t"] == pytest.approx(t[k_esc])
    # with R6 out of the class decision (structural_classes = false) and without the
    # horizon, the same log is isolated as clogging (the wrong isolation); the horizon
    # alone prevents it
    from fdigen.design.cache import cached_design

    fl = cached_design(dataclasses.replace(tank.model, fdi={
        **tank.model.fdi, "structural_classes": False}))
    bare = dataclasses.replace(fl, evaluation=dataclasses.replace(
        fl.evaluation, horizons=(HORIZON_NONE,) * len(fl.evaluation.residuals)))
    b_out = CFdi(bare, cache_dir=tmp_path).run(*s1_log)
    assert np.array_equal(b_out["flags"], flags)
    assert _first_class(fl.evaluation, b_out) == "clogging"
    h_out = CFdi(fl, cache_dir=tmp_path).run(*s1_log)
    assert _first_class(fl.evaluation, h_out) in ("none", "unexplained")
    # every backend, bit for bit
    c_out = CFdi(tank, cache_dir=tmp_path).run(*s1_log)
    k_out = CasadiFdi(tank, compiled=True).run(*s1_log)
    for key in ("flags", "fault_class", "action", "faults"):
        assert np.array_equal(c_out[key], r_out[key]), key
        assert np.array_equal(k_out[key], r_out[key]), key
    f_out = CFdi(tank, float_type="float", cache_dir=tmp_path).run(*s1_log)
    assert _first_class(ev, f_out) in ("none", "level_sensor_1", "unexplained")


def _first_class(ev, out):
    """The first class the run decided (``none`` if it decided none)."""
    cls = np.asarray(out["fault_class"])
    on = np.flatnonzero(cls)
    return ev.classes[int(cls[on[0]])] if on.size else "none"


def test_horizons_are_measured_on_healthy_runs_with_the_freeze_forced(tank):
    """One healthy run of the campaign, frozen at 0.35 and 0.65 of it: only the residuals
    of the parallel models (R1-R3, and R6, the T1 + T2 volume blind to the clogging)
    drift to their thresholds, never the balances R4, R5; and the committed horizons
    (earliest over 20 runs) are at most this run's."""
    from fdigen.tune.frozen_horizon import frozen_horizons, healthy_logs

    model = tank.model
    cases = make_cases(model, TuneSettings(runs=2, validation_runs=0, duration=900.0,
                                           seed=0))["healthy"][:1]
    out = frozen_horizons(tank, healthy_logs(model, cases), margin=1.25)
    assert out["trials"] == 2
    assert set(out["horizons"]) <= {"R1", "R2", "R3", "R6"}
    assert out["crossed"]["R4"] == out["crossed"]["R5"] == 0
    committed = tank.config.frozen_horizon
    for name, h in out["horizons"].items():
        assert h == pytest.approx(out["earliest"][name] / 1.25, rel=1e-2)
        assert committed[name] <= h * 1.001, name


def test_tune_writes_the_horizon_table():
    from fdigen.tune.model_update import updated_model_text

    text = builtin_model_path("three_tank").read_text()
    new = updated_model_text(text, {}, horizons={"R1": 50.0, "R3": 20.5})
    model = load_model(builtin_model_path("three_tank"))
    import tomllib
    fdi = tomllib.loads(new)["fdi"]
    assert fdi["frozen_horizon"] == {"R1": 50.0, "R3": 20.5}
    assert fdi["thresholds"] == tomllib.loads(text)["fdi"]["thresholds"]
    assert model.fdi["frozen_horizon"] != fdi["frozen_horizon"]


def test_fault_runs_bound_the_horizons_of_residuals_outside_the_fault_signature(tank, s1_log):
    """The s1 drift above raises R1 first, then, with every parallel model frozen, R2 and
    R3 (outside s1's signature R1, R4). ``fault_run_horizons`` forces the freeze at the
    run's first flag; its times must be those at which the core's own run (which freezes
    itself at its first flag) raises R2 and R3, to a sample, and they bound the horizons
    (``combined_horizons``) below the healthy runs' when earlier."""
    from fdigen.tune.frozen_horizon import combined_horizons, fault_run_horizons

    ev = tank.evaluation
    dt = tank.config.sample_time
    flags = np.asarray(CFdi(tank).run(*s1_log)["flags"])
    k_f = int(np.flatnonzero(flags)[0])
    raised = {n: int(np.flatnonzero(flags >> i & 1)[0]) for i, n in enumerate(ev.residuals)
              if flags[-1] >> i & 1}
    outside = sorted(set(raised) - set(tank.signature_table["s1"]))
    assert {"R2", "R3"} <= set(outside)
    got = fault_run_horizons(tank, [("s1", *s1_log)])
    assert got["runs"] == 1 and set(got["earliest"]) == set(outside)
    for n in outside:
        assert got["earliest"][n] == pytest.approx((raised[n] - k_f) * dt, abs=1.01 * dt)
        assert got["fault"][n] == "s1"
    healthy = {"horizons": {"R2": 99.0}, "earliest": {"R2": 123.75, "R3": 1e9, "R4": None},
               "trials": 2}
    both = combined_horizons(healthy, got, margin=1.25)
    for n in outside:
        assert both["earliest"][n] == min(got["earliest"][n], healthy["earliest"].get(n)
                                          or np.inf)
        assert both["horizons"][n] == pytest.approx(both["earliest"][n] / 1.25, rel=5e-3)
    assert set(both["set_by_fault"]) == {n for n in outside
                                         if got["earliest"][n] < (healthy["earliest"].get(n)
                                                                  or np.inf)}
    assert "R4" not in both["horizons"]          # never crossed: no horizon


def test_horizons_set_without_a_derivation_equal_the_derived_design(tank, s1_log):
    """tune's campaign checks the design with the horizons it has just measured: setting
    them on the derived design must be the design a derivation of the written file gives
    (same late masks, same core outputs on the s1 drift log, bit for bit)."""
    from fdigen.tune.model_update import design_with_horizons, model_with_horizons

    horizons = {"R1": 40.0, "R3": 7.5, "R4": 120.0}
    quick = design_with_horizons(tank, horizons)
    derived = cached_design(model_with_horizons(tank.model, horizons))
    assert quick.evaluation.horizons == derived.evaluation.horizons
    assert quick.evaluation.horizons != tank.evaluation.horizons
    assert quick.config.frozen_horizon == derived.config.frozen_horizon == horizons
    a, b = CFdi(quick).run(*s1_log), CFdi(derived).run(*s1_log)
    for key in ("flags", "fault_class", "action", "faults"):
        assert np.array_equal(np.asarray(a[key]), np.asarray(b[key])), key


def test_rewritten_horizon_table_says_how_it_was_measured():
    """The table's header comment describes the measurement that wrote it (a file tuned
    once with other settings kept its old comment: `fault runs` appeared nowhere); the
    comment's column stays, and a second write with the same note changes nothing."""
    import tomlkit

    from fdigen.tune.model_update import horizon_note, updated_model_text

    text = builtin_model_path("pneumatic_cylinder").read_text()
    before = tomlkit.parse(text)["fdi"]["frozen_horizon"].trivia
    measured = {"trials": 8, "runs": 4, "margin": 1.5, "fractions": [0.35, 0.65],
                "fault_runs": 2}
    note = horizon_note(measured, 0.1, 20.0)
    assert note == ("s; `fdigen tune`: 8 freezes of 4 healthy runs (+-10 %) at 0.35, 0.65 "
                    "of each 20 s run and 2 fault runs at test size, earliest time to "
                    "threshold / 1.5")
    new = updated_model_text(text, {}, horizons={"R1": 0.3, "R8": 0.4}, horizon_note=note)
    header = next(line for line in new.splitlines() if line.startswith("[fdi.frozen_horizon]"))
    assert header == "[fdi.frozen_horizon]" + before.comment_ws + "# " + note
    assert updated_model_text(new, {}, horizons={"R1": 0.3, "R8": 0.4},
                              horizon_note=note) == new



@pytest.mark.parametrize("float_type", ["double", "float"])
def test_core_run_is_the_per_sample_core_over_a_log(tank, s1_log, float_type):
    """``CFdi.core_run`` (the horizons' loop, buffers converted once) gives the residuals of
    ``CFdi.core`` called sample by sample with the state carried and the realignment
    frozen from ``k_f`` on, bit for bit."""
    u, y = s1_log[0][:600], s1_log[1][:600]
    c = CFdi(tank, float_type=float_type)
    ref = ReferenceFdi(tank)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref.initialise(u[0], y[0])
    k_f = 250
    fast = c.core_run(ref.z, u, y, k_f)
    z, slow = ref.z, np.empty_like(fast)
    for k in range(len(u)):
        z, slow[k], _ = c.core(z, u[k], y[k], (1.0 if k >= k_f else 0.0, 0.0))
    assert fast.shape == (600, len(tank.evaluation.residuals))
    assert np.array_equal(fast, slow, equal_nan=True)
    assert np.ptp(fast[k_f:], axis=0).max() > 0    # not a constant

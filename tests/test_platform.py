"""The Stewart-Gough platform: kinematics, demands, six-leg simulation, supervisor, C bank.

Isolation is checked for every fault of the cylinder model on every leg (9 x 6 short
open-loop runs, each ending 1 s after its fault; the onsets put the faulty leg at the top,
middle or bottom of its stroke, during heave or yaw, see ``ONSETS``; the single-leg FDI is
the compiled C core), plus mixed cases and closed-loop runs with the bank and the
supervisor in the loop. A primary position-sensor loss above ~140 mm is not isolated by the
single-leg design (an expected failure, with its cause).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import time

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from fdigen.cli import main
from fdigen.design.cache import cached_design
from fdigen.detect import fdi_runner
from fdigen.platform.codegen import PlatformCFdi, render_platform_sources
from fdigen.platform.demands import MotionSequence, leg_demands, quintic, stroke_use
from fdigen.platform.geometry import (DOF_NAMES, PlatformGeometry, ReachabilityError,
                                      default_geometry, rotation_matrix)
from fdigen.platform.simulate import (LegFault, parse_leg_fault, simulate_platform, six_legs)
from fdigen.platform.supervisor import (PlatformFdi, check_safety_path, platform_summary,
                                        safety_path, supervise)
from fdigen.sim.plant import FaultEvent, simulate

STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wshadow", "-Wconversion"]
#: The motion of the short runs: heave first (all legs move), then yaw.
SHORT = MotionSequence(order=("heave", "yaw"), segment=4.0)


@pytest.fixture(scope="module")
def geo():
    return default_geometry()


@pytest.fixture(scope="module")
def design(cylinder):
    return cached_design(cylinder)


@pytest.fixture(scope="module")
def runner(design):
    return fdi_runner(design, "c")


@pytest.fixture(scope="module")
def cbank(design, geo, tmp_path_factory):
    return PlatformCFdi(design, geo, cache_dir=tmp_path_factory.mktemp("platform_c"))


def _offline(design, geo, runner, run):
    """Leg FDIs (compiled single-leg core, one call per log) + the Python supervisor."""
    fc = np.stack([runner.run(run.u[:, i], run.y[:, i])["fault_class"] for i in range(6)],
                  axis=1)
    rec = supervise(design, geo, fc, run.xref)
    return rec, platform_summary(design, run.t, rec)


def _random_poses(geo, n, seed=0):
    rng = np.random.default_rng(seed)
    scale = np.array([0.06, 0.06, 0.05, 0.12, 0.12, 0.15])
    q = rng.uniform(-1, 1, (n, 6)) * scale
    x = geo.piston_positions(q)
    return q[np.all((x > 0) & (x < geo.stroke), axis=1)]


# -- geometry ---------------------------------------------------------------------------------
def test_ik_matches_an_independent_forward_computation(geo):
    q = _random_poses(geo, 300)
    assert len(q) > 100
    lengths = geo.leg_lengths(q)
    for pose, l in zip(q, lengths):
        R = Rotation.from_euler("ZYX", [pose[5], pose[4], pose[3]]).as_matrix()
        p = np.array([pose[0], pose[1], geo.home_height + pose[2]])
        top_in_base = (R @ geo.top.T).T + p            # rebuild the top joints
        np.testing.assert_allclose(np.linalg.norm(top_in_base - geo.base, axis=1), l,
                                   rtol=0, atol=1e-12)
    np.testing.assert_allclose(geo.piston_positions(q), lengths - geo.l_min)
    np.testing.assert_allclose(rotation_matrix(q[:, 3], q[:, 4], q[:, 5]),
                               Rotation.from_euler("xyz", q[:, 3:]).as_matrix(), atol=1e-15)


def test_home_pose_by_hand(geo):
    # base joint 1 at -10 deg on r = 0.5, its top joint at -50 deg on r = 0.3: 40 deg apart
    d2 = 0.5 ** 2 + 0.3 ** 2 - 2 * 0.5 * 0.3 * np.cos(np.radians(40.0))
    assert geo.home_height == pytest.approx(np.sqrt(0.55 ** 2 - d2), abs=1e-12)
    np.testing.assert_allclose(geo.home_lengths, 0.55, atol=1e-12)   # equal by symmetry
    np.testing.assert_allclose(geo.piston_positions(np.zeros(6)), 0.1, atol=1e-12)
    h = 0.03                                            # pure heave, still by hand
    np.testing.assert_allclose(geo.leg_lengths([0, 0, h, 0, 0, 0]),
                               np.sqrt(d2 + (geo.home_height + h) ** 2), atol=1e-12)
    yaw = geo.leg_lengths([0, 0, 0, 0, 0, 0.1])          # alternate legs equal under yaw
    np.testing.assert_allclose(yaw[0::2], yaw[0], atol=1e-12)
    np.testing.assert_allclose(yaw[1::2], yaw[1], atol=1e-12)
    np.testing.assert_allclose(geo.rest_positions, 0.02, atol=1e-12)


def test_forward_kinematics_round_trip(geo):
    for q in _random_poses(geo, 20, seed=3):
        np.testing.assert_allclose(geo.forward_kinematics(geo.leg_lengths(q)), q, atol=1e-9)


def test_reachability_errors_name_the_leg_and_the_excess(geo):
    with pytest.raises(ReachabilityError, match=r"leg 1 .* beyond full extension") as exc:
        geo.check_reachable([0, 0, 0.13, 0, 0, 0])    # all legs equal: the first is named
    excess = geo.piston_positions([0, 0, 0.13, 0, 0, 0])[0] - geo.stroke
    assert exc.value.leg == 1 and exc.value.side == "extension"
    assert exc.value.excess == pytest.approx(excess) and f"{excess * 1e3:.2f} mm" in str(exc.value)
    pose = [0, 0, 0, 0, np.radians(25), 0]
    worst = int(np.argmax(geo.piston_positions(pose))) + 1
    with pytest.raises(ReachabilityError, match=rf"leg {worst} ") as exc:
        geo.check_reachable(pose)
    assert exc.value.leg == worst
    with pytest.raises(ReachabilityError, match="beyond full retraction") as exc:
        geo.check_reachable([0, 0, -0.15, 0, 0, 0])
    assert exc.value.side == "retraction"
    big = MotionSequence(amplitudes=(0.1, 0.09, 0.2, 0.2, 0.2, 0.2), order=("heave",))
    with pytest.raises(ReachabilityError, match=r"at t = \d+\.\d+ s: leg \d"):
        leg_demands(geo, big, np.arange(0, big.duration, 1e-3))
    with pytest.raises(ReachabilityError, match="home pose"):
        PlatformGeometry(geo.base, geo.top, geo.l_min, geo.stroke, geo.home_height + 0.2)
    geo.check_reachable([0, 0, 0.1, 0, 0, 0])             # 182 mm: in stroke...
    with pytest.raises(ReachabilityError, match="less a 20 mm margin"):
        geo.check_reachable([0, 0, 0.1, 0, 0, 0], margin=0.02)   # ...not 20 mm from the stop


def test_geometry_round_trips_through_json(geo):
    again = PlatformGeometry.from_dict(json.loads(json.dumps(geo.to_dict())))
    np.testing.assert_array_equal(again.rest_lengths, geo.rest_lengths)
    np.testing.assert_array_equal(again.base, geo.base)


# -- demands ----------------------------------------------------------------------------------
def test_motion_sequence_moves_each_dof_in_turn_smoothly_within_stroke(geo):
    motion = MotionSequence()
    dt = 1e-3
    t = np.arange(0, motion.duration, dt)
    q, x = leg_demands(geo, motion, t, margin=0.03)    # >= 30 mm from both end stops
    np.testing.assert_array_equal(q[0], 0)
    for seg in motion.segments():
        on = (t >= seg["t_start"]) & (t < seg["t_end"])
        j = DOF_NAMES.index(seg["dof"])
        assert np.max(np.abs(q[on, j])) == pytest.approx(seg["amplitude"], rel=1e-6)
        others = np.delete(q[on], j, axis=1)
        assert np.all(others == 0)
    # C2: velocity and acceleration continuous (no jump bigger than the smooth rate allows)
    v = np.diff(x, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    assert np.max(np.abs(np.diff(a, axis=0))) / dt < 50.0     # bounded jerk [m/s^3]
    assert np.max(np.abs(v)) < 0.12
    use = stroke_use(geo, motion)
    assert 50 < use["all"]["use_percent"] < 70
    assert quintic(0.0) == 0 and quintic(1.0) == 1 and quintic(0.5) == 0.5


# -- six-leg simulation -------------------------------------------------------------------------
def test_six_leg_plant_equals_the_single_leg_simulator(cylinder, geo):
    """Leg 2 of the six-leg plant driven like `fdigen.sim.plant.simulate` gives its run."""
    from fdigen.sim.plant import reference_signal

    K = 1500
    ev = FaultEvent("leak_p", 0.7, 3e-10)
    single = simulate(cylinder, K * 1e-3, faults=(ev,), noise=False, seed=0)
    legs = six_legs(cylinder, 10, 1e-3)
    p, nf = len(cylinder.outputs), len(cylinder.faults)
    drive = np.zeros((K, 6, legs.nd))
    drive[:, :, p + nf] = reference_signal(cylinder, single.t)[:, None]
    drive[single.t >= 0.7, 1, p + [f.name for f in cylinder.faults].index("leak_p")] = 3e-10
    x0 = np.tile(np.r_[single.x[0], np.zeros(p)], (6, 1))
    par = np.tile([q.value for q in cylinder.parameters], (6, 1))
    _, uy = legs.run(x0, drive, par)
    np.testing.assert_allclose(uy[:, 1, 1:], single.y, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(uy[:, 1, 0], single.u[:, 0], rtol=1e-9, atol=1e-9)
    assert np.max(np.abs(uy[:, 0, 1:] - single.y)) > 1e-3   # leg 1 healthy: differs


def test_parse_leg_fault():
    f = parse_leg_fault("3:valve@2.5=-1")
    assert f.leg == 3 and f.event == FaultEvent("valve", 2.5, -1.0)
    assert parse_leg_fault("6:pressure_sensor_n@1=2e4/s").event.ramp
    assert parse_leg_fault("1:position_sensor@1=stuck").event.stuck
    from fdigen.errors import FdigenError
    for bad in ("7:valve@1=-1", "valve@1=-1", "2:valve@x=1"):
        with pytest.raises(FdigenError, match="LEG:NAME@T0=SIZE"):
            parse_leg_fault(bad)


#: Fault onset per leg (1..6) in the SHORT motion: representative poses, so that every
#: fault type is tried at the top, middle and bottom of the stroke and under yaw (legs at
#: different extensions): 1.3 s heave top (every piston ~156 mm), 2.0 s heave crossing
#: mid-stroke at speed (~111 mm), 2.75 s heave bottom (~47 mm), 5.3 s yaw + (legs 1, 3, 5
#: at ~55 mm, legs 2, 4, 6 at ~160 mm), 6.75 s yaw - (the other way round).
ONSETS = {1: 1.3, 2: 5.3, 3: 2.75, 4: 6.75, 5: 2.0, 6: 5.3}
#: The primary position sensor's loss at other poses (full extension, where the chambers'
#: stiffness and the valve gain are furthest from mid-stroke, in
#: test_position_signal_loss_near_full_extension_is_isolated).
ONSETS_POSITION = {1: 2.0, 2: 6.75, 3: 2.75, 4: 6.75, 5: 5.3, 6: 2.0}


@pytest.mark.parametrize("fault", ["valve", "leak_p", "leak_n", "blockage_p", "blockage_n",
                                   "position_sensor", "redundant_position_sensor",
                                   "pressure_sensor_p", "pressure_sensor_n"])
def test_fault_on_each_leg_is_isolated_to_that_leg(cylinder, design, geo, runner, fault):
    f = cylinder.fault(fault)
    cls = f.fault_class
    action = design.evaluation.actions[design.evaluation.classes.index(cls)]
    onsets = ONSETS_POSITION if fault == "position_sensor" else ONSETS
    report, at = [], []
    for leg in range(1, 7):
        t0 = onsets[leg]
        run = simulate_platform(cylinder, t0 + 1.0, motion=SHORT, seed=10 * leg,
                                faults=[LegFault(leg, FaultEvent(fault, t0, f.test_size))])
        rec, s = _offline(design, geo, runner, run)
        p = s["platform"]
        assert p["faulty_leg"] == leg and p["fault_class"] == cls, (leg, t0, p)
        assert p["legs_with_decision"] == [leg], (leg, t0, p)
        assert t0 <= p["t_decision"] < t0 + 1.0 and p["action"] == action
        assert p["safety_sequence"] == (action == "safety_stop")
        x0 = run.x[int(round(t0 / 1e-3)), leg - 1, cylinder.state_index("x")]
        at.append(x0)
        report.append(f"leg {leg} at {x0 * 1e3:.0f} mm: {(p['t_decision'] - t0) * 1e3:.0f} ms")
    assert min(at) < 0.06 and max(at) > (0.10 if fault == "position_sensor" else 0.15)
    print(f"{fault}: isolation delay " + ", ".join(report))


def test_mixed_faults_name_the_most_severe_leg(cylinder, design, geo, runner):
    run = simulate_platform(cylinder, 4.0, motion=SHORT, seed=5, faults=[
        parse_leg_fault("2:pressure_sensor_p@1.2=3e4"),
        parse_leg_fault("4:position_sensor@2.0=-1"),
        parse_leg_fault("5:blockage_n@2.4=0.95"),
        parse_leg_fault("1:leak_p@2.8=3e-10")])
    rec, s = _offline(design, geo, runner, run)
    legs = {e["leg"]: e for e in s["legs"]}
    assert legs[2]["fault_class"] == "pressure_sensor_p" and legs[2]["action"] == "none"
    assert legs[4]["fault_class"] == "position_sensor" and legs[4]["action"] == "accommodate"
    assert legs[5]["fault_class"] == "pneumatic_or_actuator"
    assert legs[3]["fault_class"] == legs[6]["fault_class"] == "none"
    p = s["platform"]
    assert p["faulty_leg"] == 5 and p["action"] == "safety_stop"     # the first safety stop
    k = rec["trigger_sample"]
    assert 2.4 < run.t[k] < 2.8
    # before the stop the platform action followed the legs: none, then accommodate
    assert rec["faulty_leg"][k - 1] == 3 and rec["action"][k - 1] == 1
    t_p = legs[2]["t_isolated"]
    assert rec["faulty_leg"][int(round(t_p / 1e-3))] == 1


@pytest.mark.parametrize("leg", range(1, 7))
def test_position_signal_loss_near_full_extension_is_isolated(cylinder, design, geo, runner,
                                                             leg):
    """The loss saturates the valve at full extension; R4 and R5 predict with the model
    scheduled on the measured pressures and the voted position (``schedule = "measured"``),
    so only the position-sensor signature builds up."""
    t0 = 1.3 if leg <= 3 else {4: 5.3, 5: 6.75, 6: 5.3}[leg]   # heave top, yaw extremes
    run = simulate_platform(cylinder, t0 + 1.0, motion=SHORT, seed=1,
                            faults=[LegFault(leg, FaultEvent("position_sensor", t0, -1.0))])
    assert run.x[int(round(t0 / 1e-3)), leg - 1, cylinder.state_index("x")] > 0.15
    _, s = _offline(design, geo, runner, run)
    assert s["platform"]["faulty_leg"] == leg
    assert s["platform"]["fault_class"] == "position_sensor"
    assert t0 <= s["platform"]["t_decision"] < t0 + 0.05


def test_healthy_paper_sequence_raises_no_decision(cylinder, design, geo, runner):
    run = simulate_platform(cylinder, seed=7)                   # one pass: 36 s
    rec, s = _offline(design, geo, runner, run)
    assert s["platform"]["action"] == "none" and s["platform"]["faulty_leg"] is None
    x = run.x[:, :, cylinder.state_index("x")]
    assert np.max(np.abs(x[1000:] - run.xref[1000:])) < 0.01    # every leg tracks its demand


# -- safety sequence ----------------------------------------------------------------------------
def test_safety_sequence_stays_within_every_leg_stroke(geo):
    rng = np.random.default_rng(4)
    starts = [np.zeros(6), np.full(6, geo.stroke), rng.uniform(0, geo.stroke, 6),
              geo.piston_positions([0.05, -0.04, 0.03, 0.1, -0.08, 0.12])]
    for start in starts:
        info = check_safety_path(geo, start, 3.0, 1e-3, every=100)
        path = safety_path(start, geo.rest_positions, 3.0, 1e-3)
        assert np.all(path >= 0) and np.all(path <= geo.stroke)
        np.testing.assert_allclose(path[0], start)
        np.testing.assert_allclose(path[-1], geo.rest_positions, atol=1e-15)
        d = np.diff(path, axis=0)
        assert np.all(d * np.sign(geo.rest_positions - start) >= -1e-15)  # monotonic
        bound = 15 / 8 * np.max(np.abs(geo.rest_positions - start)) / 3.0
        assert info["max_speed"] <= bound * (1 + 1e-6)
        assert info["end_pose_error"] < 1e-9 and info["max_pose_step"] < 0.05
    with pytest.raises(ReachabilityError):
        geo.check_positions(np.full(6, 0.21), what="safety sequence")


def test_closed_loop_stop_takes_every_leg_to_rest(cylinder, design, geo, cbank):
    run = simulate_platform(cylinder, 5.0, motion=SHORT, seed=11, bank=cbank,
                            faults=[parse_leg_fault("6:leak_n@1.0=3e-10")])
    k = run.bank["trigger_sample"]
    assert run.bank["faulty_leg"][-1] == 5 and 1.0 < run.t[k] < 1.5
    after = run.xref[k + 1:]
    assert np.all(after >= 0) and np.all(after <= geo.stroke)
    np.testing.assert_allclose(run.xref[-1], geo.rest_positions, atol=1e-12)
    x = run.x[-1, :, cylinder.state_index("x")]
    np.testing.assert_allclose(x[:5], geo.rest_positions[:5], atol=2e-3)   # healthy legs
    assert np.max(np.abs(np.diff(run.xref[k:], axis=0))) < 1e-4            # smooth demands
    # the pistons themselves (not only the demands) keep clear of both end stops: every
    # leg, the faulty one included, stays at least as far from them as the demands do
    # (less 1 mm of tracking error)
    xs = run.x[k:, :, cylinder.state_index("x")]
    margin = np.minimum(xs, geo.stroke - xs).min(axis=0)
    demand_margin = np.minimum(after, geo.stroke - after).min()
    assert np.all(margin > demand_margin - 1e-3), (margin, demand_margin)
    print(f"safety sequence from t = {run.t[k]:.3f} s: demand margin {demand_margin * 1e3:.1f} "
          f"mm, piston margin per leg [mm] {np.round(margin * 1e3, 1).tolist()}")


# -- the generated C bank -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def sources(design, geo):
    return {ft: render_platform_sources(design, geo, float_type=ft)
            for ft in ("double", "float")}


@pytest.mark.parametrize("cc", ["gcc", "clang"])
@pytest.mark.parametrize("float_type", ["double", "float"])
def test_platform_c_compiles_with_strict_flags(sources, tmp_path, cc, float_type):
    if shutil.which(cc) is None:
        pytest.skip(f"{cc} not installed")
    src = sources[float_type]
    for name, text in src.items():
        (tmp_path / name).write_text(text)
    for name in src:
        if name.endswith(".c"):
            proc = subprocess.run([cc, *STRICT, "-O2", "-c", name], cwd=tmp_path,
                                  capture_output=True, text=True)
            assert proc.returncode == 0, proc.stderr
    c = src["pneumatic_cylinder_platform_fdi.c"]
    assert not re.search(r"\b(malloc|calloc|realloc|free)\b", c)
    assert c.startswith("// Generated by fdigen")
    assert "pneumatic_cylinder_fdi_step(&state->leg[i]" in c


def test_ctypes_mirror_matches_the_c_struct_sizes(sources, cbank, tmp_path):
    for name, text in sources["double"].items():
        (tmp_path / name).write_text(text)
    (tmp_path / "sizes.c").write_text(
        '#include <stdio.h>\n#include "pneumatic_cylinder_platform_fdi.h"\n'
        'int main(void) { printf("%lu %lu %lu\\n",'
        ' (unsigned long)sizeof(pneumatic_cylinder_platform_params),'
        ' (unsigned long)sizeof(pneumatic_cylinder_platform_state),'
        ' (unsigned long)sizeof(pneumatic_cylinder_platform_output)); return 0; }\n')
    subprocess.run(["gcc", "-std=c99", "-o", "sizes", "sizes.c"], cwd=tmp_path, check=True)
    out = subprocess.run(["./sizes"], cwd=tmp_path, capture_output=True, text=True, check=True)
    s = cbank.struct_sizes
    assert out.stdout.split() == [str(s["params"]), str(s["state"]), str(s["output"])]


def test_c_bank_decisions_equal_the_python_supervisor(cylinder, design, geo, cbank):
    faults = [parse_leg_fault("3:position_sensor@0.8=-1"), parse_leg_fault("2:valve@1.6=-1"),
              parse_leg_fault("6:leak_p@2.0=3e-10")]
    online_c = simulate_platform(cylinder, 3.5, motion=SHORT, seed=21, faults=faults,
                                 bank=cbank)
    online_py = simulate_platform(cylinder, 3.5, motion=SHORT, seed=21, faults=faults,
                                  bank=PlatformFdi(design, geo, backend="c"))
    # the same closed loop, sample for sample (accommodation and safety stop included)
    np.testing.assert_array_equal(online_c.y, online_py.y)
    for key in ("decision", "action", "faulty_leg", "safety", "demand_next"):
        np.testing.assert_array_equal(online_c.bank[key], online_py.bank[key], err_msg=key)
    # offline: the C bank in one call and the Python supervisor over the same run
    c = cbank.run(online_c.u, online_c.y, online_c.xref)
    fc = np.stack([fdi_runner(design, "c").run(online_c.u[:, i], online_c.y[:, i])
                   ["fault_class"] for i in range(6)], axis=1)
    py = supervise(design, geo, fc, online_c.xref)
    for key in ("decision", "action", "faulty_leg", "safety", "demand_next"):
        np.testing.assert_array_equal(c[key], py[key], err_msg=key)
    assert c["trigger_sample"] == py["trigger_sample"] == online_c.bank["trigger_sample"]
    s = platform_summary(design, online_c.t, py)["platform"]
    assert s["faulty_leg"] == 2 and {2, 3} <= set(s["legs_with_decision"])
    assert c["decision"][-1, 2] == design.evaluation.classes.index("position_sensor")


def test_c_bank_parameter_checks(design, geo, cbank):
    import ctypes
    p = cbank._Params()
    ctypes.memmove(ctypes.byref(p), ctypes.byref(cbank.params), ctypes.sizeof(p))
    check = cbank._fn("check_params")
    assert check(ctypes.byref(p)) == 0
    p.stroke = -1.0
    assert check(ctypes.byref(p)) == -3
    p.stroke = 0.2
    p.safety_duration = 0.0
    assert check(ctypes.byref(p)) == -4
    p.safety_duration = 3.0
    p.rest_position[4] = 0.25
    assert check(ctypes.byref(p)) == -14
    p.rest_position[4] = 0.02
    p.leg[2].Ff = 1e6                      # out of its bounds: leg 3 (index 2), param 5
    assert check(ctypes.byref(p)) == -1000 - 2000 + (-100 - 5)


def test_platform_step_costs_about_six_legs(design, cylinder, cbank, runner):
    """Print the cost ratio of one platform step to one leg step (not asserted)."""
    run = simulate_platform(cylinder, 2.0, motion=SHORT, seed=2)
    u1, y1 = run.u[:, 0], run.y[:, 0]
    best_leg = best_platform = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        runner.run(u1, y1)
        best_leg = min(best_leg, time.perf_counter() - t0)
        t0 = time.perf_counter()
        cbank.run(run.u, run.y, run.xref)
        best_platform = min(best_platform, time.perf_counter() - t0)
    K = len(run.t)
    print(f"platform step {best_platform / K * 1e6:.2f} us, leg step {best_leg / K * 1e6:.2f} "
          f"us per sample: ratio {best_platform / best_leg:.2f} (6 legs + supervisor)")


# -- command line -------------------------------------------------------------------------------
def test_cli_ik(geo):
    res = CliRunner().invoke(main, ["platform", "ik", "--pose", "0,0,0,0,0,0", "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    np.testing.assert_allclose(data["leg_lengths"], 0.55, atol=1e-12)
    np.testing.assert_allclose(data["piston_positions"], 0.1, atol=1e-12)
    assert len(data["geometry"]["base_joints"]) == 6 and data["geometry"]["stroke"] == 0.2
    assert "Rz(yaw) Ry(pitch) Rx(roll)" in data["geometry"]["pose_convention"]
    res = CliRunner().invoke(main, ["platform", "ik", "--pose", "0,0,0,0,25,0", "--degrees"])
    assert res.exit_code == 2
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and re.search(r"error: .*out of reach: leg \d .* mm beyond", lines[0])


def test_cli_simulate_detect_report(tmp_path):
    out = tmp_path / "run"
    res = CliRunner().invoke(main, ["platform", "simulate", "-o", str(out), "--duration", "3",
                                    "--fault", "2:valve@1.5=-1"])
    assert res.exit_code == 0, res.output
    assert "online decision: leg 2: pneumatic_or_actuator" in res.output
    names = sorted(p.name for p in out.iterdir())
    assert names == ["leg1.csv", "leg2.csv", "leg3.csv", "leg4.csv", "leg5.csv", "leg6.csv",
                     "pose_demand.csv", "truth.json"]
    assert (out / "leg1.csv").read_text().splitlines()[0] == "t,u,x,x2,pp,pn,xref"
    truth = json.loads((out / "truth.json").read_text())
    assert truth["truth"]["faults"][0]["leg"] == 2
    res = CliRunner().invoke(main, ["platform", "detect", str(out), "--json"])
    assert res.exit_code == 0, res.output
    s = json.loads(res.output)
    assert s["platform"]["faulty_leg"] == 2 and s["platform"]["action"] == "safety_stop"
    # offline on the logs = online in the loop
    # (same sample: the log's time column is written in decimal, the loop's is k * dt)
    assert abs(s["platform"]["t_decision"] - truth["online_decision"]["t_decision"]) < 0.5e-3
    png = tmp_path / "overview.png"
    res = CliRunner().invoke(main, ["platform", "report", str(out), "-o", str(png),
                                    "--no-per-leg"])
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    res = CliRunner().invoke(main, ["platform", "detect", str(tmp_path / "nothing")])
    assert res.exit_code == 2

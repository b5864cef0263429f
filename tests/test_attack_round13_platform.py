"""Security review, round 13: the platform, the FMU wrapper and the example program.

* F1 (high): the six-leg safety sequence let a NaN leg demand through (the clamp
  ``d < 0 ? 0 : (d > stroke ? stroke : d)`` passes NaN): one leg was commanded NaN for the
  rest of the run, status OK. ``set_demand`` now refuses a non-finite demand
  (``_ERR_DEMAND``, the leg keeps its demand in force) and the sequence's start replaces
  a non-finite one by the rest position, both by selects; the Python supervisor does the
  same; a leg log's non-finite ``xref`` is refused like the FDI's own columns, and
  ``platform detect --json`` never prints ``NaN``.
* F7: ``platform simulate --duration 20000`` / ``1e7`` ended in a MemoryError (or was
  killed), ``--segment 1e300`` in a ValueError (exit 3): now a usage error naming the
  option and the limit, before any array.
* F9: a ``platform simulate`` killed mid-write left a folder mixing two runs: the folder
  is now written whole and swapped in one step.
* F13: ``platform build --float-type float --safety-duration 1e-300`` wrote
  ``SAFETY_DURATION 0.0f``; ``1e-45`` (subnormal) passed; ``1e300`` blamed "a constant of
  the design": now a usage error naming ``--safety-duration``.
* F14: the FMU did not name parameter 0 out of its bounds, accepted a ``fmi2DoStep`` back
  in time with fmi2OK, and ran up to 2e9 samples in one call.
* F11: ``window = 100000`` built, but the example ``main.c`` put the 12.8 MB state on the
  stack (segmentation fault): its objects have static storage now.
"""

from __future__ import annotations

import ctypes
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.design.cache import cached_design
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "attack13_platform"
SRC = Path(__file__).resolve().parents[1] / "src"


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def design():
    return cached_design(load_model())


@pytest.fixture(scope="module")
def cbank(design, tmp_path_factory):
    from fdigen.platform.codegen import PlatformCFdi

    return PlatformCFdi(design, cache_dir=tmp_path_factory.mktemp("platform_c13"))


def _strict_json(text: str):
    """json.loads that refuses NaN / Infinity (not JSON)."""
    def bad(name):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=bad)


# -- F1: a NaN demand never reaches the safety sequence ---------------------------------------
def _safety_class(design) -> int:
    ev = design.evaluation
    return next(c for c in range(1, len(ev.classes)) if ev.actions[c] == "safety_stop")


def test_c_set_demand_refuses_a_nan_demand_and_the_sequence_never_commands_one(design, cbank):
    """Before: set_demand stored NaN (status 0), the sequence started from NaN and leg 4
    was commanded NaN to the end. After: status _ERR_DEMAND (-6), leg 4 keeps its last
    finite demand, every commanded demand is finite and ends at the rest position."""
    from fdigen.platform.supervisor import PlatformFdi

    rest = np.array(cbank.params.rest_position[:])
    set_demand = cbank._fn("set_demand")
    d = np.ascontiguousarray(np.linspace(0.05, 0.15, 6))
    cbank.reset()
    assert set_demand(ctypes.byref(cbank.state), cbank._ptr(d)) == 0
    for bad in (np.nan, np.inf, -np.inf):
        e = d.copy() + 0.01
        e[3] = bad
        e = np.ascontiguousarray(e)
        assert set_demand(ctypes.byref(cbank.state), cbank._ptr(e)) == -6
        held = np.array(cbank.state.demand[:])
        assert held[3] == d[3]                                # leg 4 keeps its demand
        np.testing.assert_array_equal(np.delete(held, 3), np.delete(e, 3))  # others set
    # the same through a whole closed loop of steps, C bank and Python reference alike;
    # a safety-stop decision of leg 2 starts the sequence while leg 4's demand is NaN
    u = np.zeros((6, cbank.nu))
    y = np.zeros((6, cbank.ny))
    py = PlatformFdi(design, cbank.geometry, backend="c")
    for bank in (cbank, py):
        bank.reset()
        out = bank.step(u, y, d)
        assert not out["safety"]
        nan4 = d.copy()
        nan4[3] = np.nan
        if bank is cbank:
            cbank.state.decision[1] = _safety_class(design)
        else:
            py.supervisor.decision[1] = _safety_class(design)
        demands = []
        for _ in range(3200):                     # 3 s sequence at 1 ms, and beyond
            out = bank.step(u, y, nan4)
            demands.append(out["demand"])
        demands = np.array(demands)
        assert out["safety"] and out["faulty_leg"] == 1
        assert np.all(np.isfinite(demands)), "a NaN demand was commanded"
        np.testing.assert_allclose(demands[0], d, atol=1e-4)   # from the demands in force
        np.testing.assert_allclose(demands[-1], rest, atol=1e-12)


def test_c_sequence_start_replaces_a_corrupted_nan_demand_by_the_rest_position(design, cbank):
    """The start's clamp itself: a NaN in the state's demands (corrupted, or written
    around set_demand) starts that leg at its rest position, not at NaN."""
    from fdigen.platform.supervisor import Supervisor, safe_start

    rest = np.array(cbank.params.rest_position[:])
    cbank.reset()
    u = np.zeros((6, cbank.nu))
    y = np.zeros((6, cbank.ny))
    cbank.step(u, y, np.full(6, 0.1))
    cbank.state.demand[3] = float("nan")
    cbank.state.demand[4] = 5.0                     # beyond the stroke: clipped
    cbank.state.decision[0] = _safety_class(design)
    out = cbank._out
    cbank._call("step", ctypes.byref(cbank.state), ctypes.byref(cbank.params),
                cbank._u.ctypes.data, cbank._y.ctypes.data, ctypes.byref(out))
    start = np.array(cbank.state.start[:])
    assert out.safety == 1 and np.all(np.isfinite(out.demand[:]))
    assert start[3] == rest[3] and start[4] == cbank.params.stroke
    np.testing.assert_array_equal(
        safe_start([0.1, 0.1, 0.1, np.nan, 5.0, -np.inf], rest, 0.2),
        [0.1, 0.1, 0.1, rest[3], 0.2, rest[5]])
    sup = Supervisor(design, cbank.geometry)
    sup.demand[3] = np.nan
    sup.decision[0] = _safety_class(design)
    s = sup.step(np.zeros(6, dtype=int), np.full(6, np.nan))
    assert s.safety and np.all(np.isfinite(s.demand)) and sup.start[3] == rest[3]


def test_c_run_stops_at_a_nan_demand(cbank):
    K = 5
    u = np.zeros((K, 6, cbank.nu))
    y = np.zeros((K, 6, cbank.ny))
    dm = np.full((K, 6), 0.1)
    assert cbank.run(u, y, dm)["safety"].sum() == 0
    dm[2, 5] = np.nan
    with pytest.raises(RuntimeError, match="status -6"):
        cbank.run(u, y, dm)


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    from fdigen.platform.simulate import simulate_platform, write_platform_logs

    out = tmp_path_factory.mktemp("r13") / "run"
    run = simulate_platform(load_model(), 0.3, seed=2)
    write_platform_logs(run, out)
    return out


def test_platform_detect_refuses_a_nan_demand_column(run_folder, tmp_path):
    """Before: a leg log's xref = nan was read (the log in "refuse" mode refuses a NaN in
    the FDI's columns, not in the demand) and went into the supervisor: exit 0. After:
    refused like the other columns, naming the log, the column, the time."""
    folder = tmp_path / "nanref"
    shutil.copytree(run_folder, folder)
    lines = (folder / "leg4.csv").read_text().splitlines()
    head = lines[0].split(",")
    j = head.index("xref")
    for k in (101, 102):
        row = lines[k].split(",")
        row[j] = "nan"
        lines[k] = ",".join(row)
    (folder / "leg4.csv").write_text("\n".join(lines) + "\n")
    res = _invoke("platform", "detect", folder, "--json")
    assert res.exit_code == 2, res.output
    err = _strict_json(res.stdout)["error"]["message"]
    assert "leg4.csv" in err and "'xref'" in err and "t = 0.1 s" in err
    assert "NaN and Inf are not accepted" in err and "2 such sample" in err
    # the healthy folder still reads, as strict JSON
    res = _invoke("platform", "detect", run_folder, "--json")
    assert res.exit_code == 0, res.output
    assert _strict_json(res.stdout)["platform"]["action"] == "none"


def test_platform_detect_json_never_prints_nan(run_folder, monkeypatch):
    """Whatever the summary holds, --json prints strict JSON: a non-finite number is
    null (before: json.dumps printed NaN, which JSON parsers refuse)."""
    import fdigen.platform.supervisor as sup
    from fdigen.platform.supervisor import finite_json

    real = sup.detect_platform

    def poisoned(*args, **kwargs):
        summary, raw = real(*args, **kwargs)
        summary["safety"] = {"t_start": 1.0, "start_positions": [0.1, np.nan, np.inf],
                             "n": np.int64(3), "ok": np.bool_(True)}
        return summary, raw

    monkeypatch.setattr(sup, "detect_platform", poisoned)
    res = _invoke("platform", "detect", run_folder, "--json")
    assert res.exit_code == 0, res.output
    doc = _strict_json(res.stdout)
    assert doc["safety"]["start_positions"] == [0.1, None, None]
    assert doc["safety"]["n"] == 3 and doc["safety"]["ok"] is True
    assert finite_json({"a": (np.float32(np.nan), 2.5)}) == {"a": [None, 2.5]}


# -- F7: platform simulate run length ---------------------------------------------------------
@pytest.mark.parametrize("args, option", [
    (("--duration", "20000"), "--duration"), (("--duration", "1e7"), "--duration"),
    (("--segment", "1e300"), "--segment"), (("--segment", "1e300", "--duration", "1e9"),
                                            "--duration"),
    (("--segment", "0.5"), "--segment")])
def test_platform_simulate_refuses_a_run_too_long_to_hold(tmp_path, args, option):
    """Before: exit 3, internal error (MemoryError / ValueError), or killed for memory.
    After: exit 2 at once, naming the option and the limit; nothing written."""
    t0 = time.perf_counter()
    res = _invoke("platform", "simulate", "-o", tmp_path / "r", "--bank", "none", *args)
    assert res.exit_code == 2, res.output
    assert f"'{option}'" in res.output
    assert "internal error" not in res.output
    if args != ("--segment", "0.5"):
        assert "at most 1e+06" in res.output
    assert not (tmp_path / "r").exists()
    assert time.perf_counter() - t0 < 10


def test_simulate_platform_caps_the_samples():
    from fdigen.platform.demands import MotionSequence
    from fdigen.platform.simulate import (MAX_SAMPLES, RunLengthError, run_samples,
                                          simulate_platform)

    m = load_model()
    assert run_samples(m, 1000.0, MotionSequence()) == MAX_SAMPLES == 1_000_000
    with pytest.raises(RunLengthError, match="at most 1e\\+06") as exc:
        simulate_platform(m, 1000.002)
    assert exc.value.option == "duration"
    with pytest.raises(RunLengthError) as exc:
        simulate_platform(m, motion=MotionSequence(segment=1e300))
    assert exc.value.option == "segment" and "6e+300 s" in str(exc.value)


# -- F9: the run folder is written whole --------------------------------------------------------
_KILL = """
import os, signal, sys
sys.path.insert(0, {src!r})
from fdigen.model.model_file import load_model
from fdigen.platform import simulate as ps
import fdigen.sim.log as sl
run = ps.simulate_platform(load_model(), 0.3, seed=7,
                           faults=[ps.parse_leg_fault("5:leak_p@0.1=2e-9")])
real, n = sl.write_log, [0]
def write_log(path, columns):
    real(path, columns)
    n[0] += 1
    if n[0] == 3:                      # legs 1..3 written: killed
        os.kill(os.getpid(), signal.SIGKILL)
sl.write_log = write_log
ps.write_platform_logs(run, {out!r})
"""


def test_a_run_killed_mid_write_leaves_the_old_run_whole(run_folder, tmp_path):
    """Before: truth.json and legs 1-3 of the new run beside legs 4-6 of the old one.
    After: the old run, every byte; the killed run's hidden folder is removed by the
    next run, which replaces the folder whole."""
    from fdigen.platform.simulate import simulate_platform, write_platform_logs

    out = tmp_path / "mix"
    shutil.copytree(run_folder, out)
    os.chmod(out, 0o750)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    proc = subprocess.run([sys.executable, "-c", _KILL.format(src=str(SRC), out=str(out))],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == -9, proc.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    left = [p.name for p in tmp_path.iterdir() if p.name.startswith(".mix-")]
    assert len(left) == 1                          # the killed run's temporary folder
    run = simulate_platform(load_model(), 0.3, seed=8)
    write_platform_logs(run, out)
    assert [p.name for p in tmp_path.iterdir() if p.name != "mix"] == []
    truth = json.loads((out / "truth.json").read_text())
    assert truth["seed"] == 8 and (out.stat().st_mode & 0o777) == 0o750
    import hashlib
    for name in [f"leg{i}.csv" for i in range(1, 7)] + ["pose_demand.csv"]:
        assert truth["log_sha256"][name] == hashlib.sha256((out / name).read_bytes()
                                                           ).hexdigest()
        assert (out / name).read_bytes() != before[name] or name == "pose_demand.csv"


def test_a_run_never_replaces_a_folder_holding_other_files(run_folder, tmp_path):
    """The folder is replaced whole, so a folder with a user's file in it is refused
    (--force or not), before the simulation; so is the current folder."""
    out = tmp_path / "mine"
    shutil.copytree(run_folder, out)
    (out / "notes.txt").write_text("mine\n")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    for extra in ((), ("--force",)):
        res = _invoke("platform", "simulate", "-o", out, "--duration", "0.1", "--bank",
                      "none", *extra)
        assert res.exit_code == 2 and "notes.txt" in res.output, res.output
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    (out / "notes.txt").unlink()
    cwd = os.getcwd()
    try:
        os.chdir(out)
        res = _invoke("platform", "simulate", "-o", ".", "--duration", "0.1", "--bank", "none")
    finally:
        os.chdir(cwd)
    assert res.exit_code == 2 and "current folder" in res.output, res.output
    res = _invoke("platform", "simulate", "-o", out, "--duration", "0.1", "--bank", "none")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"leg{i}.csv" for i in range(1, 7)] + ["pose_demand.csv", "truth.json"])


# -- F13: --safety-duration against the float type ----------------------------------------------
@pytest.mark.parametrize("value, words", [
    ("1e-300", "shorter than one sample"), ("1e-45", "shorter than one sample"),
    ("1e300", "longer than 2147483647 samples"), ("nan", "not a finite number"),
    ("0", "must be greater than 0")])
def test_platform_build_range_checks_the_safety_duration(tmp_path, value, words):
    """Before: 1e-300 wrote SAFETY_DURATION 0.0f (its own defaults then failed _init),
    1e-45 was a subnormal float, 1e300 blamed "a constant of the design". After: a usage
    error naming the option, nothing written."""
    res = _invoke("platform", "build", "-o", tmp_path / "b", "--float-type", "float",
                  "--safety-duration", value)
    assert res.exit_code == 2, res.output
    assert "'--safety-duration'" in res.output and words in res.output, res.output
    assert "a constant of the design" not in res.output
    assert not (tmp_path / "b").exists()


def test_safety_duration_is_a_normal_number_of_the_real_type(design):
    from fdigen.errors import FdigenError
    from fdigen.platform.codegen import render_platform_sources
    from fdigen.platform.supervisor import check_safety_duration

    assert check_safety_duration(3.0, 1e-3, "float") == 3.0
    assert check_safety_duration(1e-3, 1e-3, "float") == 1e-3
    with pytest.raises(FdigenError, match="normal single-precision"):
        check_safety_duration(1e-39, 1e-40, "float")       # a subnormal float
    assert check_safety_duration(1e-39, 1e-40, "double") == 1e-39
    for T in (1e-300, 1e-45, 1e300):
        with pytest.raises(FdigenError, match="safety duration"):
            render_platform_sources(design, safety_duration=T, float_type="float")
    h = render_platform_sources(design, safety_duration=0.25, float_type="float")
    assert "#define PNEUMATIC_CYLINDER_PLATFORM_SAFETY_DURATION 0.25f" in \
        h["pneumatic_cylinder_platform_fdi.h"]


# -- F14: the FMU wrapper -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def motor_fmu(tmp_path_factory):
    pytest.importorskip("fmpy", reason="the FMU tests need fmpy")
    from fdigen.backends.c import render_c_sources
    from fdigen.backends.fmu import fmu_archive, render_fmu_sources

    d = cached_design(load_model("dc_motor"))
    core = {n: t for n, t in render_c_sources(d, float_type="double", model_source="m",
                                              model_hash="0" * 64).items()
            if n.endswith((".c", ".h")) and n != "main.c"}
    texts = render_fmu_sources(d, model_source="m", model_hash="0" * 64, core_files=core)
    wrapper = next(n for n in texts if n.endswith(".c"))
    path = tmp_path_factory.mktemp("fmu13") / "dc_motor_fdi.fmu"
    path.write_bytes(fmu_archive(wrapper[:-len("_fmi2.c")], texts["modelDescription.xml"],
                                 {**core, wrapper: texts[wrapper]}, wrapper))
    return path, texts[wrapper]


class _Slave:
    """An fmpy FMU2Slave with fmpy's own callbacks: its logger prints ``[LEVEL] message``
    (read back with capsys; a logger of the test's own through fmpy's native proxy would
    stay registered in that library after the test, for every later FMU of the process)."""

    def __init__(self, fmu, capsys):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        self.capsys = capsys
        self.md = read_model_description(str(fmu))
        self.dir = extract(str(fmu))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.s = FMU2Slave(guid=self.md.guid, unzipDirectory=self.dir,
                           modelIdentifier=self.md.coSimulation.modelIdentifier,
                           instanceName="i")
        self.s.instantiate(loggingOn=True)
        self.s.setupExperiment(startTime=0.0)
        self.s.enterInitializationMode()
        capsys.readouterr()

    def messages(self) -> list[str]:
        """The messages logged since the last call."""
        return [line.split("] ", 1)[-1] for line in self.capsys.readouterr().out.splitlines()]

    def close(self):
        self.s.freeInstance()
        shutil.rmtree(self.dir, ignore_errors=True)


def test_fmu_names_the_first_parameter_out_of_its_bounds(motor_fmu, capsys):
    """Before: "the parameters are not accepted" for parameter 0 (the check s < BASE
    left out _ERR_PARAM(0) == BASE), the name for every other one."""
    fmu, _ = motor_fmu
    slave = _Slave(fmu, capsys)
    params = [v.name for v in slave.md.modelVariables if v.causality == "parameter"]
    slave.close()
    for name in params[:2]:
        slave = _Slave(fmu, capsys)
        slave.s.setReal([slave.vr[name]], [-1e9])
        with pytest.raises(Exception, match="fmi2ExitInitializationMode"):
            slave.s.exitInitializationMode()
        logged = slave.messages()
        assert f"parameter {name} is not finite or out of its bounds" in logged, logged
        slave.close()


def test_fmu_do_step_must_start_at_the_fmu_time_and_is_bounded(motor_fmu, capsys):
    """Before: a step back in time returned fmi2OK and did nothing; one call ran up to
    2e9 samples (minutes). After: fmi2Error with a message for a step that does not start
    where the last ended, or longer than FMU_MAX_STEP_SAMPLES (1e6) samples; nothing done."""
    from fmpy.fmi2 import fmi2LastSuccessfulTime

    fmu, wrapper = motor_fmu
    assert "#define DC_MOTOR_FDI_FMU_MAX_STEP_SAMPLES 1000000L" in wrapper
    slave = _Slave(fmu, capsys)
    s = slave.s
    s.exitInitializationMode()
    s.setReal([slave.vr["u"], slave.vr["w"], slave.vr["i"]], [12.0, 238.8, 0.0478])
    s.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.5)
    s.doStep(currentCommunicationPoint=0.5, communicationStepSize=0.5)
    assert s.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(1.0)
    slave.messages()
    for t, h in ((0.5, 0.1), (-100.0, 1.0), (2.0, 0.1)):     # back, far back, ahead
        with pytest.raises(Exception, match="fmi2DoStep"):
            s.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        logged = slave.messages()
        assert any("is not the FMU's time 1 " in m for m in logged), logged
        assert s.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(1.0)
    t0 = time.perf_counter()
    with pytest.raises(Exception, match="fmi2DoStep"):
        s.doStep(currentCommunicationPoint=1.0, communicationStepSize=1e6)
    assert time.perf_counter() - t0 < 1.0
    logged = slave.messages()
    assert any("more than the 1000000 one call runs" in m for m in logged), logged
    assert s.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(1.0)
    s.doStep(currentCommunicationPoint=1.0 + 1e-12, communicationStepSize=1000.0)  # 1e6: ok
    assert s.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(1001.0)
    slave.close()


# -- F11: the example program with a long window ------------------------------------------------
def test_example_main_runs_with_a_12_mb_state(tmp_path):
    """Before: the example main.c of a design with window = 100000 (state 12.8 MB) died of
    a segmentation fault at once (the state a local, on an 8 MB stack). After: it runs."""
    import resource

    from fdigen.backends.c import render_c_sources

    d = cached_design(load_model(DATA / "pc_win.toml"))
    assert d.evaluation.window == 100000
    src = render_c_sources(d, float_type="double", model_source="pc_win.toml",
                           model_hash="0" * 64)
    for name, text in src.items():
        (tmp_path / name).write_text(text)
    assert "static pneumatic_cylinder_fdi_state state;" in src["main.c"]
    cfiles = [n for n in src if n.endswith(".c")]
    subprocess.run(["gcc", "-std=c99", "-O2", "-o", "example", *cfiles, "-lm"], cwd=tmp_path,
                   check=True, capture_output=True)
    rows = ["t,u,x,x2,pp,pn"] + [f"{k * 1e-3:.3f},0.1,0.1,0.1,350000,350000"
                                  for k in range(20)]

    def stack_8mb():
        resource.setrlimit(resource.RLIMIT_STACK, (8 << 20, 8 << 20))

    proc = subprocess.run(["./example"], cwd=tmp_path, input="\n".join(rows) + "\n",
                          capture_output=True, text=True, timeout=60, preexec_fn=stack_8mb)
    assert proc.returncode == 0, (proc.returncode, proc.stderr)
    assert "summary: 20 samples" in proc.stdout

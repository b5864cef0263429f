"""``fdigen build --fmu``: the FMI 2.0 co-simulation FMU of the C core validates, is
byte-deterministic, and ``fmpy simulate`` over a rig log gives the C backend's residuals,
RMS, flags, class and action bit for bit; its thresholds and parameters are parameters."""

import subprocess
import sys
import zipfile

import numpy as np
import pytest

from conftest import RIG

fmpy = pytest.importorskip(
    "fmpy", reason="fmpy is not installed: the FMU tests need it (pip install 'fdigen[fmu]')")

LOG = RIG / "logs" / "fdi_leak_p.csv"


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    from fdigen.pipeline import build

    out = tmp_path_factory.mktemp("fmu")
    result = build("pneumatic_cylinder", out, fmu=True)
    fmu = result.folder / "fmu" / "pneumatic_cylinder_fdi.fmu"
    assert fmu.is_file() and "fmu/pneumatic_cylinder_fdi.fmu" in result.files
    return out, result, fmu


def test_fmu_validates_and_is_deterministic(built):
    from fdigen.pipeline import build

    out, result, fmu = built
    proc = subprocess.run([sys.executable, "-m", "fmpy", "validate", str(fmu)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "No problems found" in proc.stdout, proc.stdout + proc.stderr
    md = fmpy.read_model_description(str(fmu))
    assert md.fmiVersion == "2.0" and md.coSimulation.modelIdentifier == "pneumatic_cylinder_fdi"
    kinds = {}
    for v in md.modelVariables:
        kinds.setdefault(v.causality, []).append(v.name)
    assert kinds["input"] == ["u", "x", "x2", "pp", "pn"]
    assert {"J_R1", "J_nf_pn", "Ff", "K"} <= set(kinds["parameter"])
    assert {"r_R1", "rms_R9", "flag_R7", "flags", "fault_class", "action"} <= set(kinds["output"])
    with zipfile.ZipFile(fmu) as zf:
        infos = zf.infolist()
        assert [i.filename for i in infos] == sorted(i.filename for i in infos)
        assert {i.date_time for i in infos} == {(1980, 1, 1, 0, 0, 0)}
        assert "binaries/linux64/pneumatic_cylinder_fdi.so" in zf.namelist()
        assert "sources/pneumatic_cylinder_fdi.c" in zf.namelist()
    again = build("pneumatic_cylinder", out, fmu=True, check=True)   # rebuilt in memory
    assert again.up_to_date and not again.changed


def _rig_inputs(model, samples=None):
    from fdigen.sim.log import read_log

    if not LOG.is_file():
        pytest.skip(f"rig log {LOG} not available")
    log = read_log(LOG, model)
    k = len(log.t) if samples is None else samples
    ts = log.sample_time
    names = [s.column for s in model.inputs] + [o.column for o in model.outputs]
    signals = np.zeros(k, dtype=[("time", float)] + [(n, float) for n in names])
    signals["time"] = np.arange(k) * ts       # the FMU is sampled at its communication points
    for j, s in enumerate(model.inputs):
        signals[s.column] = log.u[:k, j]
    for j, o in enumerate(model.outputs):
        signals[o.column] = log.y[:k, j]
    return log, signals, ts


def _simulate(fmu, signals, ts, outputs, **kwargs):
    k = len(signals)
    return fmpy.simulate_fmu(str(fmu), start_time=0.0, stop_time=(k - 1) * ts,
                             output_interval=ts, input=signals, output=outputs, **kwargs)


def test_fmu_equals_the_c_backend_on_a_rig_log(built, cylinder_design):
    from fdigen.backends.c import CFdi

    _, _, fmu = built
    log, signals, ts = _rig_inputs(cylinder_design.model)
    names = list(cylinder_design.evaluation.residuals)
    outputs = ([f"r_{n}" for n in names] + [f"rms_{n}" for n in names]
               + [f"flag_{n}" for n in names] + ["flags", "fault_class", "action", "faults"])
    res = _simulate(fmu, signals, ts, outputs)
    c = CFdi(cylinder_design).run(log.u, log.y)
    k = len(res) - 1          # row j + 1 of the FMU: after the doStep that ran sample j
    assert k == len(log.t) - 1
    r = np.column_stack([res[f"r_{n}"] for n in names])[1:]
    rms = np.column_stack([res[f"rms_{n}"] for n in names])[1:]
    assert np.array_equal(r, c["r"][:k]) and np.array_equal(rms, c["rms"][:k])
    for key in ("flags", "fault_class", "action", "faults"):
        assert np.array_equal(res[key][1:], np.asarray(c[key])[:k]), key
    bits = np.column_stack([res[f"flag_{n}"] for n in names])[1:].astype(int)
    assert np.array_equal(bits @ (1 << np.arange(len(names))), res["flags"][1:])
    # not trivially equal: the leak is detected and isolated on this log
    assert res["flags"][-1] != 0 and res["fault_class"][-1] == \
        cylinder_design.evaluation.classes.index("pneumatic_or_actuator")


def test_thresholds_and_parameters_are_parameters(built, cylinder_design):
    _, _, fmu = built
    _, signals, ts = _rig_inputs(cylinder_design.model, samples=12000)
    names = list(cylinder_design.evaluation.residuals)
    default = _simulate(fmu, signals, ts, ["flag_R1", "flags"])
    assert default["flag_R1"].any()
    raised = _simulate(fmu, signals, ts, ["flag_R1", "flags"], start_values={"J_R1": 1e9})
    assert not raised["flag_R1"].any()
    others = (1 << len(names)) - 2
    assert np.array_equal(raised["flags"] & others, default["flags"] & others)
    lo, _ = next(q.bounds for q in cylinder_design.model.parameters if q.name == "K")
    with pytest.raises(Exception, match="fmi2ExitInitializationMode"):
        _simulate(fmu, signals[:10], ts, ["flags"], start_values={"K": lo - abs(lo) - 1.0})


def test_without_fmpy_the_fmu_build_says_what_to_install(monkeypatch):
    import importlib.util

    from fdigen.backends.fmu.package import fmi_headers
    from fdigen.errors import BuildError

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "fmpy" else real(name, *a))
    with pytest.raises(BuildError, match=r"pip install 'fdigen\[fmu\]'"):
        fmi_headers()

"""`fdigen pil`: the float core on the emulated Cortex-M4F computes what the host computes
(issue 24): the seven fdi_* rig logs replayed under QEMU (mps2-an386) and on the host,
every output byte compared, and the target's outputs equal to the in-process float
library's (CFdi), so the replay itself is checked too.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import RIG
from fdigen.backends.c import CFdi
from fdigen.cli import main
from fdigen.sim.log import read_log
from fdigen.verify.pil import run_pil
from fdigen.verify.tools import missing_tools

LOGS = ("fdi_healthy", "fdi_leak_p", "fdi_blockage_p", "fdi_actuator_loss",
        "fdi_position_sensor_loss", "fdi_pressure_n_drift", "fdi_pressure_p_loss")


@pytest.fixture(autouse=True, scope="module")
def _tools():
    missing = missing_tools("arm-none-eabi-gcc", "arm-none-eabi-size", "qemu-system-arm")
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed (Debian gcc-arm-none-eabi, "
                    "libnewlib-arm-none-eabi, qemu-system-arm; scripts/setup installs them): "
                    "the processor-in-the-loop run was NOT checked")


@pytest.fixture(scope="module")
def logs(cylinder_design):
    paths = [RIG / "logs" / f"{name}.csv" for name in LOGS]
    if not all(p.is_file() for p in paths):
        pytest.skip(f"reference rig logs not available under {RIG / 'logs'}")
    out = []
    for p in paths:
        log = read_log(p, cylinder_design.model, sample_time=cylinder_design.config.sample_time)
        out.append((log.u, log.y))
    return out


@pytest.fixture(scope="module")
def pil_run(cylinder_design, logs):
    return run_pil(cylinder_design, logs, keep_records=True)


def test_target_equals_host_on_the_seven_rig_logs(pil_run, logs):
    rep = pil_run
    assert rep["samples"] == sum(len(u) for u, _ in logs)
    assert rep["equal"], f"{rep['mismatched_samples']} samples differ"
    assert rep["max_abs_difference"] == 0.0
    assert 500 < rep["instructions_per_step"] < 50000
    assert 0 < rep["stack_bytes"] <= rep["stack_bytes_static"] + 64
    assert rep["code_bytes"][".text"] > 1000
    assert rep["code_bytes"].get(".data", 0) + rep["code_bytes"].get(".bss", 0) == 0


def test_target_equals_the_in_process_float_library(pil_run, logs, cylinder_design, tmp_path):
    """The target's residuals, RMS, flags and classes are the float CFdi's, bit for bit, and
    the faulty logs raise flags (the comparison is not of empty outputs)."""
    target = pil_run["records"]["target"]
    fdi = CFdi(cylinder_design, float_type="float", cache_dir=tmp_path)
    start = 0
    for (u, y), name in zip(logs, LOGS):
        ref = fdi.run(u, y)
        rec = target[start:start + len(u)]
        start += len(u)
        np.testing.assert_array_equal(rec["r"], ref["r"].astype(np.float32), err_msg=name)
        np.testing.assert_array_equal(rec["rms"], ref["rms"].astype(np.float32), err_msg=name)
        np.testing.assert_array_equal(rec["flags"], ref["flags"], err_msg=name)
        np.testing.assert_array_equal(rec["fault_class"], ref["fault_class"], err_msg=name)
        if name != "fdi_healthy":
            assert rec["flags"][-1] != 0, f"{name}: no flag on the target"


def test_pil_cli_json(logs, tmp_path):
    """The command on a short log (the first 2,000 rows of fdi_leak_p: the build dominates)."""
    lines = (RIG / "logs" / "fdi_leak_p.csv").read_text().splitlines(keepends=True)
    path = tmp_path / "leak_start.csv"
    path.write_text("".join(lines[:2001]))
    res = CliRunner().invoke(main, ["pil", str(path), "--json"])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.output)
    assert rep["equal"] is True and rep["max_abs_difference"] == 0.0
    assert rep["samples"] == 2000 and rep["logs"] == ["leak_start.csv"]
    assert rep["instructions_per_step"] > 0 and rep["step"] == "pneumatic_cylinder_fdi_step"


def test_platform_step_on_the_target_equals_host_and_library(cylinder_design, logs, pil_run,
                                                            tmp_path):
    """The six-leg bank (legs = six of the rig logs, demands their xref): target = host
    bit for bit, and the decisions, flags, actions, faulty leg, safety sequence, demands
    and positions for control equal the in-process float bank's (PlatformCFdi)."""
    from fdigen.platform.codegen import PlatformCFdi

    legs = [RIG / "logs" / f"{name}.csv" for name in LOGS[:6]]
    reads = [read_log(p, cylinder_design.model, sample_time=cylinder_design.config.sample_time,
                      extra_columns=("xref",))
             for p in legs]
    demand = np.stack([lg.extra["xref"] for lg in reads], axis=1)
    u = np.stack([lg.u for lg in reads], axis=1)
    y = np.stack([lg.y for lg in reads], axis=1)
    rep = run_pil(cylinder_design, [(demand, u, y)], platform=True, keep_records=True)
    assert rep["equal"] and rep["max_abs_difference"] == 0.0, rep["mismatched_samples"]
    assert rep["samples"] == len(u)
    target = rep["records"]["target"]
    ref = PlatformCFdi(cylinder_design, float_type="float", cache_dir=tmp_path).run(
        u, y, demand)
    for key in ("decision", "action", "faulty_leg"):
        np.testing.assert_array_equal(target[key], ref[key], err_msg=key)
    np.testing.assert_array_equal(target["flags"], ref["flags"])
    np.testing.assert_array_equal(target["safety"].astype(bool), ref["safety"])
    np.testing.assert_array_equal(target["demand"], ref["demand_next"].astype(np.float32))
    np.testing.assert_array_equal(target["position_for_control"],
                                  ref["position_for_control"].astype(np.float32))
    assert target["safety"][-1] == 1, "the faulty legs never started the safety sequence"
    # six leg steps and the supervisor
    assert 6 * pil_run["instructions_per_step"] < rep["instructions_per_step"] \
        < 7 * pil_run["instructions_per_step"]


def test_pil_cli_bad_log_is_a_usage_error(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,u\n0,1\n")
    res = CliRunner().invoke(main, ["pil", str(bad), "--json"])
    assert res.exit_code == 2
    assert "error" in json.loads(res.output.splitlines()[0])

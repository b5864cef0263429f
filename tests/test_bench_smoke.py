"""Smoke test of the benchmark suite: `python bench/run.py --smoke` with tiny sizes.

Part of the test suite (the alarm of bench/handwritten/): the day the design outgrows the
hand-written step -- a residual, a state, an extra residual's structure or an evaluation
part it does not compute -- hand_consts.design_constants (bench_c re-exports it) fails
naming what differs, and so does this test; the day they compute different things, the
equivalence on the seven fdi_* rig logs fails. It checks that the command runs end to end and writes its table,
not any timing.

    python -m pytest tests/test_bench_smoke.py      # hand, python, platform, m4
    FDIGEN_FULL_SWEEP=1 python -m pytest tests/test_bench_smoke.py   # + build and Dask
"""

from __future__ import annotations

import importlib
import json
import os
import shutil
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


def _bench(name: str):
    """A module of bench/ (bench/ is on sys.path; not an installed package)."""
    return importlib.import_module(name)


def _run(tmp_path, sections):
    run = _bench("run")
    out = tmp_path / "out"
    run.main(["--smoke", "--out", str(out), "--build-dir", str(tmp_path / "build"),
              "--only", ",".join(sections)])
    results = json.loads((out / "results.json").read_text())
    table = (out / "results.md").read_text()
    for name in sections:
        assert name in results, name
        assert "error" not in results[name], (name, results[name].get("error"),
                                              results[name].get("traceback"))
    assert "| # | measurement | result | target | status |" in table
    assert results["machine"]["cpus"] >= 1
    return results, table


def test_smoke_c_and_python(tmp_path):
    common = _bench("common")
    FDI_LOGS, LOGS = common.FDI_LOGS, common.LOGS
    missing = [n for n in FDI_LOGS if not (LOGS / f"{n}.csv").is_file()]
    if missing:
        pytest.skip(f"reference rig logs {missing} not available in {LOGS}")
    results, table = _run(tmp_path, ["hand", "python", "platform", "m4"])
    eq = results["hand"]["equivalence"]
    assert set(eq["logs"]) == set(FDI_LOGS)
    assert eq["passed"], eq["worst"]
    assert eq["discrete_identical"]
    assert eq["worst"]["one_step_z"] <= eq["one_step_tolerance"]
    assert results["hand"]["time_gcc"]["gen"]["ns_per_sample_cpu"] > 0
    cn = results["hand"]["casadi_native"]      # the CasADi chunk driven from C
    assert "error" not in cn, cn.get("error")
    assert cn["check"]["flags_equal"] and cn["check"]["r_max_scaled_diff"] <= 1e-12
    for name in ("variant", "variant_all"):     # the what-if copies of the generated C
        v = results["hand"][name]
        assert "error" not in v, v.get("error")
        assert v["discrete_identical"], name
    assert results["python"]["cfdi_run_s"] > 0
    if "filterpy_flags_identical" in results["python"]:
        assert results["python"]["filterpy_flags_identical"]
    assert results["platform"]["ratio_cpu"] > 1
    assert "## 1. Generated step vs the hand-written limit" in table


@pytest.mark.skipif(not (os.environ.get("FDIGEN_FULL_SWEEP")
                         or os.environ.get("FDIGEN_BENCH_SMOKE_SLOW")),
                    reason="set FDIGEN_FULL_SWEEP=1 (a cold build and Dask clusters)")
def test_smoke_build_and_monte_carlo(tmp_path):
    pytest.importorskip("distributed")
    results, _ = _run(tmp_path, ["build", "mc"])
    assert results["build"]["cold_s"] > results["build"]["unchanged_s"] > 0
    assert results["mc"]["identical_results"]

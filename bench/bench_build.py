"""`fdigen build` wall times (cold and unchanged) and a profile of the cold build
(item 4 of bench/run.py). Never touches generated/: every build writes a fresh --out."""

from __future__ import annotations

import os
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import median, spread


def _build(out: Path, cache: Path, force: bool) -> float:
    env = dict(os.environ, FDIGEN_CACHE=str(cache))
    cmd = [sys.executable, "-m", "fdigen.cli", "build", "--out", str(out)]
    if force:
        cmd.append("--force")
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stdout}\n{proc.stderr}")
    return dt


PROFILE_SCRIPT = """
import cProfile, sys
from fdigen.pipeline import build
cProfile.run("build(None, sys.argv[1], force=True)", sys.argv[2])
"""

#: Stages of a cold build: (label, function key in the profile).
STAGES = [
    ("load the model file", "model_file.py", "load_model"),
    ("derive the design (fdi_design)", "fdi_design.py", "fdi_design"),
    ("render the C (double and float)", "emit.py", "render_c_sources"),
    ("CasADi sources (functions + codegen)", "compiled.py", "casadi_sources"),
    ("  of which: build the CasADi functions", "compiled.py", "build_functions"),
    ("describe the design (design.json)", "describe.py", "describe_design"),
    ("strict compile check (gcc, 2 cores)", "pipeline.py", "compile_check"),
    ("compile the CasADi library (cached)", "compiled.py", "compile_library"),
]


def _stage_times(stats: pstats.Stats) -> list[dict]:
    rows = []
    for label, fname, func in STAGES:
        total, calls = 0.0, 0
        for (f, _line, name), (cc, nc, tt, ct, callers) in stats.stats.items():
            if name == func and f.endswith(fname):
                total += ct
                calls += nc
        rows.append({"stage": label, "function": func, "cumulative_s": total, "calls": calls})
    return rows


def _top(stats: pstats.Stats, key: str, n: int) -> list[dict]:
    idx = {"cumulative": 3, "tottime": 2}[key]
    items = sorted(stats.stats.items(), key=lambda kv: -kv[1][idx])
    out = []
    for (f, line, name), (cc, nc, tt, ct, callers) in items:
        short = f
        for marker in ("site-packages/", "/src/", "lib/python3"):
            if marker in f:
                short = f.split(marker, 1)[1]
                break
        out.append({"function": f"{short}:{line}({name})", "calls": nc,
                    "tottime_s": tt, "cumtime_s": ct})
        if len(out) >= n:
            break
    return out


def build_times(cold_repeats: int, warm_repeats: int, log=print) -> dict:
    res = {"command": "python -m fdigen.cli build --out <fresh dir> --force "
                      "(FDIGEN_CACHE=<empty dir>)"}
    from common import GENERATED
    res["casadi_c_bytes"] = sum(f.stat().st_size for f in (GENERATED / "casadi").glob("*.c"))
    with tempfile.TemporaryDirectory(prefix="fdigen-bench-build-") as tmp:
        tmp = Path(tmp)
        cold = []
        for i in range(cold_repeats):
            log(f"  cold build {i + 1}/{cold_repeats} ...")
            cold.append(_build(tmp / f"out{i}", tmp / f"cache{i}", force=True))
        res["cold_s"] = median(cold)
        res["cold_range"] = spread(cold)
        res["cold_all"] = cold
        warm = []
        for i in range(warm_repeats):
            warm.append(_build(tmp / "out0", tmp / "cache0", force=False))
        res["unchanged_s"] = median(warm)
        res["unchanged_range"] = spread(warm)
        # what an unchanged build costs without fdigen: interpreter start + CLI import
        t = []
        for _ in range(warm_repeats):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-c", "import fdigen.cli"], check=True)
            t.append(time.perf_counter() - t0)
        res["python_start_and_cli_import_s"] = median(t)
        t = []
        for _ in range(warm_repeats):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-c", "pass"], check=True)
            t.append(time.perf_counter() - t0)
        res["python_start_s"] = median(t)

        log("  profiling a cold build (cProfile) ...")
        prof = tmp / "build.prof"
        env = dict(os.environ, FDIGEN_CACHE=str(tmp / "cache-prof"))
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", PROFILE_SCRIPT, str(tmp / "out-prof"), str(prof)],
                       env=env, check=True, capture_output=True)
        res["profiled_cold_s"] = time.perf_counter() - t0
        stats = pstats.Stats(str(prof))
        res["profile_total_s"] = stats.total_tt
        res["stages"] = _stage_times(stats)
        res["top_cumulative"] = _top(stats, "cumulative", 25)
        res["top_tottime"] = _top(stats, "tottime", 15)
    return res

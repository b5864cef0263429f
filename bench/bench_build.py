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


def _build(out: Path, cache: Path, force: bool, full: bool = False):
    env = dict(os.environ, FDIGEN_CACHE=str(cache))
    cmd = [sys.executable, "-m", "fdigen.cli", "build", "--out", str(out)]
    if force:
        cmd.append("--force")
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stdout}\n{proc.stderr}")
    return (dt, proc.stdout) if full else dt


def _cache_files(cache: Path) -> set:
    return {str(p.relative_to(cache)) for p in cache.rglob("*") if p.is_file()} \
        if cache.is_dir() else set()


def _repeat_clean(fn, repeats: int, log, what: str):
    """``repeats`` timings from ``fn() -> (seconds, clean)``, discarding the unclean ones
    (the sources changed under the run -- another engineer's work on src/ invalidates the
    stamp or the design cache), at most ``3 * repeats`` attempts."""
    times, discarded = [], 0
    for _ in range(3 * repeats):
        dt, clean = fn()
        if clean:
            times.append(dt)
            if len(times) == repeats:
                break
        else:
            discarded += 1
            log(f"  {what}: sources changed during the run, attempt discarded")
    if not times:
        raise RuntimeError(f"{what}: no clean measurement ({discarded} attempts discarded)")
    return times, discarded


#: The modules a rendering build imports (pipeline.render_all), in a fresh interpreter.
IMPORTS = ("import fdigen.cli, fdigen.pipeline, fdigen.backends.c.emit, "
           "fdigen.backends.casadi_backend.compiled, fdigen.design.fdi_design, "
           "fdigen.design.cache, fdigen.design.describe, fdigen.model.model_file")

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
    ("strict compile check (gcc, c/ and c_float/ in parallel)", "pipeline.py",
     "compile_check"),
    ("start the CasADi library compile (background)", "compiled.py",
     "start_library_compile"),
    ("wait for the CasADi library compile", "compiled.py", "finish"),
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
        # a fresh --out with the design cache (and the CasADi library) of a cold build:
        # no derivation, no simplification, no library compile; sympy still imported
        count = iter(range(1000))

        def warm_cache_build():
            before = _cache_files(tmp / "cache0")
            dt = _build(tmp / f"outw{next(count)}", tmp / "cache0", force=True)
            return dt, _cache_files(tmp / "cache0") == before   # nothing re-derived
        log(f"  fresh --out, warm design cache x {cold_repeats} ...")
        warm_cache, res["warm_cache_discarded"] = _repeat_clean(
            warm_cache_build, cold_repeats, log, "warm-cache build")
        res["warm_cache_s"] = median(warm_cache)
        res["warm_cache_range"] = spread(warm_cache)
        res["warm_cache_all"] = warm_cache
        # what any build that renders pays before it starts: the imports of the
        # derivation and rendering modules (sympy, scipy, casadi, ...)
        t = []
        for _ in range(cold_repeats):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-c", IMPORTS], check=True)
            t.append(time.perf_counter() - t0)
        res["render_imports_s"] = median(t)
        def unchanged_build():
            dt, out = _build(tmp / "out0", tmp / "cache0", force=False, full=True)
            return dt, "up to date" in out
        warm, res["unchanged_discarded"] = _repeat_clean(unchanged_build, warm_repeats, log,
                                                         "unchanged build")
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

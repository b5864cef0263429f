#!/usr/bin/env python
"""fdigen's performance benchmarks: one command, one results table.

    python bench/run.py            # the full suite, a few minutes on 2 cores
    python bench/run.py --quick    # smaller sizes and fewer repeats

writes ``bench/results.md`` (the table and its analysis) and ``bench/results.json``
(every number); a full run of every section also rewrites the ``## Performance`` section
of README.md (the machine, the table's key rows, a link to results.md). Needs gcc (clang, valgrind, arm-none-eabi-gcc are used when present)
and the bench extra: ``pip install -e '.[bench]'`` (filterpy, dask.distributed).
``tests/test_bench_smoke.py`` runs it with tiny sizes in the test suite.

What is measured (every figure is the median of repeated runs, every ratio is measured in
the same run on the same machine; CPU times are primary because the machine is shared):

1. the generated C step vs a hand-written C step of the same computation
   (bench/handwritten/fdi_hand.c), both ``-std=c99 -O2 -ffp-contract=off``: checked equal
   on the seven fdi_* rig logs, then ns per sample (a C driver looping over a 20000-sample
   log, clock_gettime, interleaved repeats) and instructions per sample (callgrind);
2. whole-log processing from Python: CFdi.run and CasadiFdi(compiled).run on 1e6 samples
   in one call, against per-sample loops (ReferenceFdi.step, a filterpy peer);
3. the six-leg platform step vs one leg;
4. ``fdigen build`` cold and unchanged, and a cProfile of the cold build;
5. Monte Carlo throughput (simulate + CFdi.run), one vs two Dask workers;
6. the Cortex-M4F float build: .text and stack.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import BENCH, load, machine, use_generated, write_json  # noqa: E402

SECTIONS = ("hand", "python", "platform", "build", "mc", "m4")

SIZES = {
    "full": dict(c_repeats=41, platform_repeats=21, casadi_native_repeats=5,
                 samples=1_000_000, repeats=5, casadi_samples=1_000_000, casadi_repeats=3,
                 loop_samples=3000, loop_repeats=3, cold_builds=3, unchanged_builds=7,
                 mc_runs=24, mc_duration=20.0, mc_repeats=3, timing_samples=None),
    "quick": dict(c_repeats=11, platform_repeats=7, casadi_native_repeats=3,
                  samples=200_000, repeats=3, casadi_samples=20_000, casadi_repeats=2,
                  loop_samples=500, loop_repeats=2, cold_builds=2, unchanged_builds=3,
                  mc_runs=8, mc_duration=10.0, mc_repeats=2, timing_samples=None),
    "smoke": dict(c_repeats=3, platform_repeats=3, casadi_native_repeats=1,
                  samples=20_000, repeats=2, casadi_samples=2048, casadi_repeats=1,
                  loop_samples=40, loop_repeats=2, cold_builds=1, unchanged_builds=2,
                  mc_runs=2, mc_duration=0.3, mc_repeats=1, timing_samples=2000),
}


def log(msg):
    print(msg, flush=True)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description="fdigen performance benchmarks")
    ap.add_argument("--quick", action="store_true", help="smaller sizes, fewer repeats")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes (a test, not a result)")
    ap.add_argument("--out", default=str(BENCH), help="folder of results.md/.json "
                    "(default bench/)")
    ap.add_argument("--only", default=",".join(SECTIONS),
                    help=f"comma-separated sections of {','.join(SECTIONS)}")
    ap.add_argument("--build-dir", default=str(BENCH / "build"),
                    help="scratch folder for compiled drivers (default bench/build/)")
    args = ap.parse_args(argv)
    mode = "smoke" if args.smoke else "quick" if args.quick else "full"
    sizes = SIZES[mode]
    only = [s.strip() for s in args.only.split(",") if s.strip()]
    unknown = set(only) - set(SECTIONS)
    if unknown:
        ap.error(f"unknown section(s) {sorted(unknown)}")
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    build = Path(args.build_dir)
    build.mkdir(parents=True, exist_ok=True)

    import bench_c
    bench_c.TIMING_SAMPLES = sizes["timing_samples"]   # the C timings' and callgrind's log

    t_start = time.perf_counter()
    # the generated code of the current sources and model, built into the scratch folder
    # (generated/ in the repository is stale whenever src/ or the model changed)
    gen_root = build / "generated"
    proc = subprocess.run([sys.executable, "-m", "fdigen.cli", "build", "--out",
                           str(gen_root)], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"fdigen build --out {gen_root} failed:\n{proc.stdout}{proc.stderr}")
    use_generated(gen_root / "pneumatic_cylinder")
    results = {"mode": mode, "sizes": sizes, "machine": machine(), "load_before": load(),
               "started": time.strftime("%Y-%m-%d %H:%M:%S %Z")}
    log(f"fdigen benchmarks ({mode}) on {results['machine']['cpu_model']}, "
        f"{results['machine']['cpus']} CPUs, load {results['load_before']}")
    design = model = consts = None
    try:
        design, model = bench_c.design_and_model()
        results["model_hash"] = bench_c.json.loads(
            (bench_c.GENERATED / "design.json").read_text())["model_hash"]
        results["residuals"] = list(design.residual_names)
        consts = bench_c.design_constants(design)
    except Exception as exc:
        results["design_error"] = f"{type(exc).__name__}: {exc}"
        log(f"design: {results['design_error']}")

    def section(name, title, fn):
        if name not in only:
            return
        log(f"[{name}] {title}")
        t0 = time.perf_counter()
        try:
            results[name] = fn()
        except Exception as exc:  # one broken section must not hide the others
            results[name] = {"error": f"{type(exc).__name__}: {exc}",
                             "traceback": traceback.format_exc()[-3000:]}
            log(f"  FAILED: {results[name]['error']}")
        results.setdefault("section_seconds", {})[name] = round(time.perf_counter() - t0, 1)

    section("hand", "generated vs hand-written C step",
            lambda: bench_c.handwritten(build, model, design, sizes["c_repeats"], log))
    if "hand" in only and "error" not in results.get("hand", {}):
        try:
            results["hand"]["casadi_native"] = bench_c.casadi_native(
                build, model, design, sizes["casadi_native_repeats"])
        except Exception as exc:
            results["hand"]["casadi_native"] = {"error": f"{type(exc).__name__}: {exc}"}

    def python_section():
        import bench_py
        return bench_py.whole_log(model, design, sizes["samples"], sizes["repeats"],
                                  sizes["casadi_samples"], sizes["casadi_repeats"],
                                  sizes["loop_samples"], sizes["loop_repeats"], consts, log)
    section("python", "whole-log processing from Python", python_section)
    section("platform", "six-leg platform step vs one leg",
            lambda: bench_c.platform(build, model, design, sizes["platform_repeats"], log))

    def build_section():
        import bench_build
        return bench_build.build_times(sizes["cold_builds"], sizes["unchanged_builds"], log)
    section("build", "fdigen build: cold, unchanged, profile", build_section)

    def mc_section():
        import bench_mc
        return bench_mc.monte_carlo(sizes["mc_runs"], sizes["mc_duration"],
                                    sizes["mc_repeats"], log)
    section("mc", "Monte Carlo throughput", mc_section)
    section("m4", "Cortex-M4F float build", lambda: bench_c.cortex_m4(build))

    results["load_after"] = load()
    results["total_seconds"] = round(time.perf_counter() - t_start, 1)
    import report
    write_json(out_dir / "results.json", results)
    (out_dir / "results.md").write_text(report.render(results))
    log(f"wrote {out_dir / 'results.md'} and {out_dir / 'results.json'} "
        f"({results['total_seconds']} s)")
    # a full run of every section into bench/ is the latest result: README's table too
    if (mode == "full" and out_dir.resolve() == BENCH.resolve() and set(only) == set(SECTIONS)
            and report.update_readme(results, BENCH.parent / "README.md")):
        log("updated the Performance section of README.md")
    return results


if __name__ == "__main__":
    main()

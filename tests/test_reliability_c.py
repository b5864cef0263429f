"""Reliability of the generated C core (generated/pneumatic_cylinder/c).

(a) 1e6-step fuzz of pneumatic_cylinder_fdi_step under AddressSanitizer + UBSan with
    NaN, +-Inf, huge, tiny, denormal and plausible inputs: every r, rms, aux and state z
    stays finite; flags, class, action and the state's counters stay in range.
(b) the same driver under valgrind memcheck (2000 steps).
(c) cppcheck (warning, style, portability) on c/ and c_float/.
(d) constant time: callgrind instruction counts per step, healthy vs NaN/Inf,
    randomly mixed and finite faulty inputs: equal.
(e) parameters outside their bounds (or not finite) are rejected by init with
    PNEUMATIC_CYLINDER_FDI_ERR_PARAM(i); the bounds themselves are accepted.

Each check is skipped with a reason only if its tool is missing. With
``FDIGEN_RELIABILITY_REPORT`` set, every test appends a JSON line to that file.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from reliability_log import reporter

from fdigen.model.model_file import load_model

ROOT = Path(__file__).resolve().parents[1]
GEN = ROOT / "generated" / "pneumatic_cylinder"
CDIR = GEN / "c"
SRC = CDIR / "pneumatic_cylinder_fdi.c"
FUZZ_STEPS = 1_000_000
CHUNK = 4000          # reset every CHUNK steps
VALGRIND_STEPS = 2000
CALLGRIND_STEPS = 5000


report = reporter("generated C core")


def _cc():
    for cc in ("clang", "gcc"):
        if shutil.which(cc):
            return cc
    pytest.skip("no C compiler (clang or gcc) found")


DRIVER = r"""
#include "pneumatic_cylinder_fdi.h"
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define NZ PNEUMATIC_CYLINDER_FDI_NZ
#define NU PNEUMATIC_CYLINDER_FDI_NU
#define NY PNEUMATIC_CYLINDER_FDI_NY
#define NR PNEUMATIC_CYLINDER_FDI_NR
#define NAUX PNEUMATIC_CYLINDER_FDI_NAUX

static uint64_t rng = 0x9E3779B97F4A7C15ULL;   /* fixed seed */
static uint64_t xorshift(void) { rng ^= rng << 13; rng ^= rng >> 7; rng ^= rng << 17; return rng; }
static double unif(void) { return (double)(xorshift() >> 11) * (1.0 / 9007199254740992.0); }

/* plausible ranges: u in [-5, 5] V; x3, x2 in [0.02, 0.18] m; pp, pn in [2e5, 5e5] Pa */
static const double LO[1 + NY] = {-5.0, 0.02, 0.02, 2.0e5, 2.0e5};
static const double HI[1 + NY] = {5.0, 0.18, 0.18, 5.0e5, 5.0e5};
static long n_bad_values = 0;

static double special(void) {
    static volatile double zero = 0.0;
    switch (xorshift() % 14) {
    case 0: return zero / zero;                 /* NaN */
    case 1: return 1.0 / zero;                  /* +Inf */
    case 2: return -1.0 / zero;                 /* -Inf */
    case 3: return DBL_MAX;
    case 4: return -DBL_MAX;
    case 5: return 1e300;
    case 6: return -1e300;
    case 7: return 1e-300;
    case 8: return DBL_MIN / 4.0;               /* denormal */
    case 9: return -4.9e-324;                   /* smallest denormal */
    case 10: return 0.0;
    case 11: return -0.0;
    case 12: return 1e30;
    default: return (unif() - 0.5) * 1e6;       /* absurd but finite */
    }
}

/* chunk kinds: 0 plausible only, 1 rare bad values (1 %), 2 frequent (30 %), 3 all bad */
static double sample(int col, int kind, double *walk) {
    double p = kind == 0 ? 0.0 : kind == 1 ? 0.01 : kind == 2 ? 0.3 : 1.0;
    double span = HI[col] - LO[col];
    walk[col] += (unif() - 0.5) * 0.02 * span;
    if (walk[col] < LO[col]) walk[col] = LO[col];
    if (walk[col] > HI[col]) walk[col] = HI[col];
    if (unif() < p) { n_bad_values++; return special(); }
    return walk[col];
}

static int finite_all(const double *a, int n) {
    int i;
    for (i = 0; i < n; i++) if (!isfinite(a[i])) return 0;
    return 1;
}

static long failures = 0;
static void fail(long k, const char *what) {
    if (failures < 10) fprintf(stderr, "step %ld: %s\n", k, what);
    failures++;
}

static int fuzz(long steps, long chunk) {
    pneumatic_cylinder_fdi_params p;
    pneumatic_cylinder_fdi_state s;
    pneumatic_cylinder_fdi_output o;
    double u[NU], y[NY], walk[1 + NY];
    long k;
    int kind = 0, c, st;
    long warn = 0;
    if (pneumatic_cylinder_fdi_default_params(&p) != PNEUMATIC_CYLINDER_FDI_OK) return 2;
    if (pneumatic_cylinder_fdi_init(&s, &p) != PNEUMATIC_CYLINDER_FDI_OK) return 2;
    for (k = 0; k < steps; k++) {
        if (k % chunk == 0) {
            kind = (int)(xorshift() % 4);
            for (c = 0; c < 1 + NY; c++) walk[c] = LO[c] + unif() * (HI[c] - LO[c]);
            if (k > 0 && pneumatic_cylinder_fdi_reset(&s) != PNEUMATIC_CYLINDER_FDI_OK)
                fail(k, "reset failed");
        }
        u[0] = sample(0, kind, walk);
        for (c = 0; c < NY; c++) y[c] = sample(1 + c, kind, walk);
        st = pneumatic_cylinder_fdi_step(&s, &p, u, y, &o);
        if (st == PNEUMATIC_CYLINDER_FDI_WARN_NONFINITE) warn++;
        else if (st != PNEUMATIC_CYLINDER_FDI_OK) fail(k, "step returned an error");
        if (!finite_all(o.r, NR)) fail(k, "r not finite");
        if (!finite_all(o.rms, NR)) fail(k, "rms not finite");
        if (!finite_all(o.aux, NAUX)) fail(k, "aux not finite");
        if (!finite_all(s.z, NZ)) fail(k, "state z not finite");
        if (!finite_all(s.sums, NR)) fail(k, "state sums not finite");
        for (c = 0; c < NR; c++) if (o.rms[c] < 0.0) { fail(k, "negative rms"); break; }
        if (o.flags >= (1u << NR)) fail(k, "flags out of range");
        if (o.fault_class < 0 || o.fault_class >= PNEUMATIC_CYLINDER_FDI_NCLASSES) fail(k, "class out of range");
        if (o.action < 0 || o.action >= PNEUMATIC_CYLINDER_FDI_NACTIONS) fail(k, "action out of range");
        if (s.index < 0 || s.index >= PNEUMATIC_CYLINDER_FDI_WINDOW) fail(k, "ring index out of range");
        if (s.decision < 0 || s.decision >= PNEUMATIC_CYLINDER_FDI_NCLASSES) fail(k, "decision out of range");
        if (s.candidate < 0 || s.candidate >= PNEUMATIC_CYLINDER_FDI_NCLASSES) fail(k, "candidate out of range");
        if (s.count < 0) fail(k, "negative confirmation count");
    }
    printf("{\"steps\": %ld, \"bad_values\": %ld, \"warn_nonfinite\": %ld, \"failures\": %ld}\n",
           steps, n_bad_values, warn, failures);
    return failures ? 1 : 0;
}

/* constant time: only the steps are measured (callgrind --toggle-collect=run_steps) */
static double U[20000][NU], Y[20000][NY];
__attribute__((noinline)) int run_steps(pneumatic_cylinder_fdi_state *s,
        const pneumatic_cylinder_fdi_params *p, long n, pneumatic_cylinder_fdi_output *o) {
    long k;
    int acc = 0;
    for (k = 0; k < n; k++) acc |= pneumatic_cylinder_fdi_step(s, p, U[k], Y[k], o);
    return acc;
}

/* kind 0 healthy; 1 NaN/Inf/absurd on every channel from the second sample; 2 each
   channel of each sample healthy or NaN/Inf/absurd at random (alternating paths); 3 finite
   faults: a pressure sensor offset and a position sensor stuck, which raise flags and
   isolate a class */
static int timing(long n, int faulty) {
    pneumatic_cylinder_fdi_params p;
    pneumatic_cylinder_fdi_state s;
    pneumatic_cylinder_fdi_output o;
    static volatile double zero = 0.0;
    long k;
    int c;
    if (n > 20000) return 2;
    pneumatic_cylinder_fdi_default_params(&p);
    if (pneumatic_cylinder_fdi_init(&s, &p) != PNEUMATIC_CYLINDER_FDI_OK) return 2;
    for (k = 0; k < n; k++) {
        double t = (double)k * PNEUMATIC_CYLINDER_FDI_SAMPLE_TIME;
        /* healthy: at rest at the operating point (an equilibrium: no flag), plus a
           small position ripple */
        U[k][0] = 0.0;
        Y[k][0] = 0.1 + 1e-6 * sin(2.0 * 3.141592653589793 * 0.5 * t);
        Y[k][1] = Y[k][0];
        Y[k][2] = 3.5e5;
        Y[k][3] = 3.5e5;
        if (faulty == 1) {
            /* NaN / Inf on every sensor from the second sample on, absurd input */
            for (c = 0; c < NY; c++) Y[k][c] = (k > 0) ? ((k + c) % 3 == 0 ? zero / zero
                                                : (k + c) % 3 == 1 ? 1.0 / zero : 1e30) : Y[k][c];
            if (k > 0) U[k][0] = (k % 2) ? zero / zero : 1e300;
        } else if (faulty == 2 && k > 0) {
            for (c = 0; c < NY; c++) if (xorshift() % 2) Y[k][c] = special();
            if (xorshift() % 2) U[k][0] = special();
        } else if (faulty == 3 && k > 50) {
            Y[k][2] += 2.0e4;                     /* pressure sensor p offset */
            Y[k][1] = Y[50][1];                   /* redundant position sensor stuck */
        }
    }
    c = run_steps(&s, &p, n, &o);
    printf("{\"status\": %d, \"flags\": %u, \"class\": %d}\n", c, o.flags, o.fault_class);
    return 0;
}

int main(int argc, char **argv) {
    if (argc >= 4 && strcmp(argv[1], "fuzz") == 0) return fuzz(atol(argv[2]), atol(argv[3]));
    if (argc >= 3 && strcmp(argv[1], "healthy") == 0) return timing(atol(argv[2]), 0);
    if (argc >= 3 && strcmp(argv[1], "faulty") == 0) return timing(atol(argv[2]), 1);
    if (argc >= 3 && strcmp(argv[1], "mixed") == 0) return timing(atol(argv[2]), 2);
    if (argc >= 3 && strcmp(argv[1], "finite_faults") == 0) return timing(atol(argv[2]), 3);
    fprintf(stderr, "usage: fuzz N CHUNK | healthy N | faulty N | mixed N | finite_faults N\n");
    return 2;
}
"""


def _build(tmp_path, name, flags, cc=None):
    cc = cc or _cc()
    driver = tmp_path / "driver.c"
    driver.write_text(DRIVER)
    exe = tmp_path / name
    cmd = [cc, "-std=c99", "-D_POSIX_C_SOURCE=200809L", "-g", *flags, f"-I{CDIR}",
           str(driver), str(SRC), "-o", str(exe), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, f"{' '.join(cmd)}\n{proc.stderr}"
    return exe


def test_fuzz_step_asan_ubsan_1e6(tmp_path):
    cc = _cc()
    exe = _build(tmp_path, "fuzz_asan", ["-O1", "-fno-omit-frame-pointer",
                                         "-fsanitize=address,undefined",
                                         "-fno-sanitize-recover=all"], cc)
    env = dict(os.environ, ASAN_OPTIONS="detect_leaks=1:abort_on_error=0",
               UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1")
    proc = subprocess.run([str(exe), "fuzz", str(FUZZ_STEPS), str(CHUNK)], capture_output=True,
                          text=True, timeout=110, env=env)
    stats = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.stdout.strip() else {}
    ok = proc.returncode == 0
    report("test_fuzz_step_asan_ubsan_1e6",
           "fuzzed step inputs (NaN, +-Inf, huge, tiny, denormal, plausible) under "
           f"ASan+UBSan ({cc})", FUZZ_STEPS, "pass" if ok else "FAIL",
           f"{stats.get('bad_values', '?')} non-plausible values injected, "
           f"{stats.get('warn_nonfinite', '?')} steps returned WARN_NONFINITE, resets every "
           f"{CHUNK} steps; all r/rms/aux/z finite, flags/class/action in range"
           if ok else (proc.stderr[-600:] + proc.stdout[-300:]))
    assert ok, f"rc={proc.returncode}\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    assert stats["steps"] == FUZZ_STEPS and stats["failures"] == 0


def test_fuzz_step_valgrind_memcheck(tmp_path):
    if not shutil.which("valgrind"):
        pytest.skip("valgrind not installed")
    exe = _build(tmp_path, "fuzz_plain", ["-O1"], "gcc" if shutil.which("gcc") else None)
    cmd = ["valgrind", "--tool=memcheck", "--error-exitcode=1", "--leak-check=full",
           "--track-origins=yes", "-q", str(exe), "fuzz", str(VALGRIND_STEPS), "500"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=110)
    ok = proc.returncode == 0
    report("test_fuzz_step_valgrind_memcheck", "fuzzed step inputs under valgrind memcheck",
           VALGRIND_STEPS, "pass" if ok else "FAIL",
           "no invalid access, no uninitialised read, no leak" if ok else proc.stderr[-600:])
    assert ok, proc.stderr[-4000:]


def test_cppcheck_generated_c():
    if not shutil.which("cppcheck"):
        pytest.skip("cppcheck not installed")
    dirs = [GEN / "c", GEN / "c_float"]
    # missingIncludeSystem only: cppcheck is not given the system include path (<stdint.h>,
    # <math.h>); unusedFunction is not enabled (it needs --enable=unusedFunction and the
    # library's API functions are meant to be unused inside the library).
    cmd = ["cppcheck", "--enable=warning,style,portability", "--error-exitcode=1",
           "--std=c99", "--suppress=missingIncludeSystem", "--inline-suppr",
           "--template={file}:{line}: {severity} ({id}) {message}", "--quiet",
           *map(str, dirs)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=110)
    ok = proc.returncode == 0 and not proc.stderr.strip()
    files = sorted(p.name for d in dirs for p in d.glob("*.[ch]"))
    version = subprocess.run(["cppcheck", "--version"], capture_output=True,
                             text=True).stdout.strip()
    report("test_cppcheck_generated_c", f"static analysis ({version}, "
           "--enable=warning,style,portability --std=c99) of c/ and c_float/",
           len(files), "pass" if ok else "FAIL",
           "0 findings (suppressed: missingIncludeSystem only)" if ok else proc.stderr[-600:])
    assert ok, proc.stderr


def _callgrind(exe, mode, tmp_path):
    out = tmp_path / f"callgrind.{mode}.out"
    cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
           "--toggle-collect=run_steps", str(exe), mode, str(CALLGRIND_STEPS)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=110)
    assert proc.returncode == 0, proc.stderr[-3000:]
    m = re.search(r"^(?:summary|totals):\s*(\d+)", out.read_text(), re.M)
    assert m, "no callgrind summary"
    return int(m.group(1)), proc.stdout.strip()


#: Largest difference of instructions per step between any input kind and healthy input
#: (callgrind, averaged over CALLGRIND_STEPS): the generated step has no data-dependent
#: branch, so the counts are equal; the slack covers nothing but rounding of the average.
CONSTANT_TIME_LIMIT = 0.5
TIMING_KINDS = ("faulty", "mixed", "finite_faults")


def test_step_is_constant_time_healthy_vs_faulty(tmp_path):
    """Per-step instruction counts (callgrind, gcc -O2 -fno-math-errno as the generated
    Makefile, and plain -O2) of 5000 healthy steps against 5000 steps with NaN/Inf/absurd
    inputs on every channel, with each channel healthy or bad at random, and with finite
    sensor faults that raise flags and isolate a class: at most CONSTANT_TIME_LIMIT
    instructions per step apart (in practice identical)."""
    if not shutil.which("valgrind"):
        pytest.skip("valgrind not installed")
    cc = "gcc" if shutil.which("gcc") else None
    rows = []
    worst = 0.0
    for label, flags in (("-O2", ["-O2"]), ("-O2 -fno-math-errno", ["-O2", "-fno-math-errno"])):
        exe = _build(tmp_path, "timing" + str(len(rows)), flags, cc)
        healthy, h_out = _callgrind(exe, "healthy", tmp_path)
        assert json.loads(h_out)["flags"] == 0, "the healthy run raised a flag"
        per_h = healthy / CALLGRIND_STEPS
        for kind in TIMING_KINDS:
            count, out = _callgrind(exe, kind, tmp_path)
            result = json.loads(out)
            assert result["flags"] != 0, f"the {kind} run raised no flag"
            if kind == "finite_faults":
                assert result["class"] != 0, "the finite faults were not isolated"
            per = count / CALLGRIND_STEPS
            worst = max(worst, abs(per - per_h))
            rows.append(f"{label}: healthy {per_h:.2f}, {kind} {per:.2f} instr/step "
                        f"(difference {per - per_h:+.2f})")
    details = "; ".join(rows)
    print("callgrind:", details)
    ok = worst <= CONSTANT_TIME_LIMIT
    report("test_step_is_constant_time_healthy_vs_faulty",
           "instruction count per step, healthy vs NaN/Inf/absurd, random mix, finite "
           "faults (callgrind, gcc)", (1 + len(TIMING_KINDS)) * 2 * CALLGRIND_STEPS,
           "pass" if ok else "FAIL",
           details + f" (limit {CONSTANT_TIME_LIMIT} instructions per step)")
    assert ok, details


def _param_driver(model):
    lines = ["#include \"pneumatic_cylinder_fdi.h\"", "#include <math.h>", "#include <stdio.h>",
             "int main(void) {", "  pneumatic_cylinder_fdi_params p; pneumatic_cylinder_fdi_state s;",
             "  int st, bad = 0, cases = 0; static volatile double zero = 0.0;"]
    for i, q in enumerate(model.parameters):
        err = -100 - i
        values = ["zero / zero", "1.0 / zero", "-1.0 / zero"]
        ok_values = []
        if q.bounds:
            lo, hi = q.bounds
            values += [f"nextafter({lo!r}, -HUGE_VAL)", f"nextafter({hi!r}, HUGE_VAL)",
                       f"{lo!r} - 1.0 - fabs({lo!r})", f"{hi!r} * 10.0 + 1.0"]
            ok_values += [repr(lo), repr(hi)]
        for v in values:
            lines += [f"  pneumatic_cylinder_fdi_default_params(&p); p.{q.name} = {v};",
                      f"  st = pneumatic_cylinder_fdi_init(&s, &p); cases++;",
                      f"  if (st != {err}) {{ bad++; printf(\"{q.name} = %g: status %d, "
                      f"expected {err}\\n\", (double)p.{q.name}, st); }}"]
        for v in ok_values:
            lines += [f"  pneumatic_cylinder_fdi_default_params(&p); p.{q.name} = {v};",
                      f"  st = pneumatic_cylinder_fdi_init(&s, &p); cases++;",
                      f"  if (st != 0) {{ bad++; printf(\"{q.name} = %g (bound): status %d\\n\","
                      f" (double)p.{q.name}, st); }}"]
    lines += ["  st = pneumatic_cylinder_fdi_init(NULL, &p); cases++;",
              "  if (st != PNEUMATIC_CYLINDER_FDI_ERR_NULL) { bad++; puts(\"NULL state\"); }",
              "  st = pneumatic_cylinder_fdi_init(&s, NULL); cases++;",
              "  if (st != PNEUMATIC_CYLINDER_FDI_ERR_NULL) { bad++; puts(\"NULL params\"); }",
              "  printf(\"{\\\"cases\\\": %d, \\\"bad\\\": %d}\\n\", cases, bad);",
              "  return bad != 0;", "}"]
    return "\n".join(lines) + "\n"


def test_out_of_bounds_parameters_rejected_by_init(tmp_path):
    cc = _cc()
    model = load_model()
    driver = tmp_path / "params.c"
    driver.write_text(_param_driver(model))
    exe = tmp_path / "params"
    cmd = [cc, "-std=c99", "-D_POSIX_C_SOURCE=200809L", "-O1", "-g",
           "-fsanitize=address,undefined", "-fno-sanitize-recover=all", f"-I{CDIR}",
           str(driver), str(SRC), "-o", str(exe), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60)
    stats = json.loads(run.stdout.strip().splitlines()[-1])
    ok = run.returncode == 0
    report("test_out_of_bounds_parameters_rejected_by_init",
           "parameters NaN, +-Inf, one ulp / far outside bounds, exactly at bounds, NULL "
           "pointers (init)", stats["cases"], "pass" if ok else "FAIL",
           "every bad parameter i -> PNEUMATIC_CYLINDER_FDI_ERR_PARAM(i) = -100-i; bounds "
           "accepted; NULL -> ERR_NULL" if ok else run.stdout[-600:])
    assert ok, run.stdout + run.stderr
    assert math.isfinite(stats["cases"]) and stats["cases"] > 5 * len(model.parameters)


def _conditional_jumps_by_line(obj: Path) -> dict[int, int]:
    """Conditional jumps of an object file (``objdump -d -l``), counted by the source line
    objdump attributes them to (inlined code counts in its own lines)."""
    out = subprocess.run(["objdump", "-d", "-l", "--no-show-raw-insn", str(obj)],
                         capture_output=True, text=True, check=True).stdout
    line, jumps = None, {}
    for text in out.splitlines():
        m = re.match(r"^/.*\.c:(\d+)", text)
        if m:
            line = int(m.group(1))
            continue
        m = re.match(r"^\s+[0-9a-f]+:\s+(j[a-z]+)\s", text)
        if m and m.group(1) != "jmp" and line is not None:
            jumps[line] = jumps.get(line, 0) + 1
    return jumps


def _branch_free_lines(source: str, prefix: str) -> list[range]:
    """Line ranges that must compile without a conditional branch: the helpers (from the
    select helper to ``_default_params``) and the residual generator's body."""
    lines = source.splitlines()

    def first(text, start=0):
        return next(i for i in range(start, len(lines)) if lines[i].startswith(text))

    helpers = first(f"static {prefix}_real {prefix}_fdi_select(")
    params = first(f"int {prefix}_fdi_default_params(")
    body = first(f"static int {prefix}_fdi_residuals(")
    end = first("}", body)
    return [range(helpers + 1, params + 1), range(body + 1, end + 2)]


@pytest.mark.parametrize("model", ["pneumatic_cylinder", "three_tank", "dc_motor",
                                   "heat_exchanger"])
def test_residuals_and_selects_compile_without_branches(model, tmp_path):
    """The residual generator and the select, clamp and finiteness helpers of every
    shipped model, double and float, compiled by gcc -O2 with the generated Makefile's
    -fno-math-errno (without it, sqrt of a possibly negative argument keeps a call for
    errno behind a branch): not one conditional jump in their lines. The callgrind test
    above counts instructions of the whole step on one model; this checks the code every
    clamp and select compiles to, where gcc, given a plain ?: on reals, branches as soon
    as it knows one operand (a constant bound, threaded through the next clamp)."""
    if not (shutil.which("gcc") and shutil.which("objdump")):
        pytest.skip("gcc or objdump not installed")
    found = {}
    for variant in ("c", "c_float"):
        src = ROOT / "generated" / model / variant / f"{model}_fdi.c"
        obj = tmp_path / f"{variant}.o"
        subprocess.run(["gcc", "-std=c99", "-O2", "-fno-math-errno", "-g", "-c", str(src),
                        "-o", str(obj)], check=True, capture_output=True)
        ranges = _branch_free_lines(src.read_text(), model)
        jumps = _conditional_jumps_by_line(obj)
        assert jumps, "no conditional jump found at all: the objdump parsing is broken"
        found[variant] = {ln: n for ln, n in jumps.items() if any(ln in r for r in ranges)}
    assert not any(found.values()), f"{model}: conditional jumps at lines {found}"

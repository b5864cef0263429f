"""C-level benchmarks: generated vs hand-written step, the platform bank, the CasADi C
called natively, and the Cortex-M4F build. Used by bench/run.py."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from common import (BENCH, CFLAGS, FDI_LOGS, GENERATED, TIMING_LOG, compile_c, have, median,
                    rig_log, run, spread)

# the hand-written step's constants (hand_consts.py); re-exported here for run.py and the
# filterpy peer, which know them as bench_c.design_constants
from hand_consts import (HAND_EXTRAS, HAND_GUARDS, HAND_RESIDUALS, HAND_STATES,  # noqa: F401
                         design_constants, write_gains_header)
from hand_schedule import schedule_constants  # noqa: F401

HAND = BENCH / "handwritten"
GEN_C = GENERATED / "c"


# -- inputs -------------------------------------------------------------------------------
def design_and_model():
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model

    model = load_model()
    return cached_design(model), model


def write_log_bin(model, name: str, path: Path, limit: int | None = None) -> int:
    """A rig log (its first ``limit`` samples) as the drivers' binary: int64 K, u[K],
    y[K][4]."""
    log = rig_log(model, name)
    u = np.ascontiguousarray(log.u[:limit, 0], dtype=float)
    y = np.ascontiguousarray(log.y[:limit], dtype=float)
    with open(path, "wb") as fh:
        fh.write(np.int64(len(u)).tobytes())
        fh.write(u.tobytes())
        fh.write(y.tobytes())
    return len(u)


# -- 1. generated vs hand-written ---------------------------------------------------------
#: Samples of the timing log (common.TIMING_LOG) the timings and callgrind runs step over:
#: None, all of them (20000); ``run.py --smoke`` sets fewer (a test, not a result). The
#: equivalence checks always run on the whole of every log.
TIMING_SAMPLES: int | None = None


def timing_log_bin(build: Path, model) -> tuple[Path, int]:
    """The timing log (its first :data:`TIMING_SAMPLES` samples) as ``build/timing.bin``,
    and its number of samples."""
    path = build / "timing.bin"
    return path, write_log_bin(model, TIMING_LOG, path, limit=TIMING_SAMPLES)


#: States of the FDI step (the hand-written step has the generated layout).
NZ = len(HAND_STATES)


def _read_dump(path: Path, K: int, nr: int) -> dict:
    rec = np.dtype([("d", "<f8", 2 * nr + 2 + NZ), ("i", "<i4", 4)])
    a = np.fromfile(path, dtype=rec, count=K)
    assert len(a) == K, (path, len(a), K)
    return {"r": a["d"][:, :nr], "rms": a["d"][:, nr:2 * nr],
            "aux": a["d"][:, 2 * nr:2 * nr + 2], "z": a["d"][:, 2 * nr + 2:],
            "flags": a["i"][:, 0], "fault_class": a["i"][:, 1], "action": a["i"][:, 2],
            "faults": a["i"][:, 3]}


def _scaled_diff(a, b, floor=None):
    """max |a - b| / scale per column; scale = max |a| on the log, or the column's
    threshold if larger (the voter residuals 1 - 3 w/sum are near 0 on healthy logs,
    where one rounding of the 1 is 1e-16 absolute but 1e-12 of their largest value)."""
    scale = np.abs(a).max(axis=0)
    if floor is not None:
        scale = np.maximum(scale, floor)
    return np.abs(a - b).max(axis=0) / np.maximum(scale, 1e-300)


def build_drivers(build: Path, design) -> dict:
    gains = write_gains_header(design, build / "fdi_hand_gains.h")
    inc = [GEN_C, HAND, build]
    srcs = [HAND / "driver.c", HAND / "fdi_hand.c", GEN_C / "pneumatic_cylinder_fdi.c"]
    exes = {"gcc": compile_c(build / "driver_gcc", srcs, inc, cc="gcc", extra=["-g"])}
    if have("clang"):
        exes["clang"] = compile_c(build / "driver_clang", srcs, inc, cc="clang", extra=["-g"])
    # objects for the static instruction counts
    for name, src in (("gen", GEN_C / "pneumatic_cylinder_fdi.c"), ("hand", HAND / "fdi_hand.c")):
        run(["gcc", *CFLAGS, *(f"-I{i}" for i in inc), "-c", "-o", build / f"{name}.o", src])
    return {"exes": exes, "gains": gains}


def check_equivalence(build: Path, exe: Path, model, nr: int, thresholds=None) -> dict:
    """Both steps on every fdi_* rig log.

    * one step: the hand-written step started at every sample from the generated step's
      state -- residuals, RMS and the next state (parallel models, filter predictions)
      within ``ONE_STEP_TOL`` of each quantity's scale on the log (max |difference| /
      max |value|): the same operations, up to rounding;
    * free running (each on its own state over the whole log): flags, class and action
      identical at every sample, residuals within ``FREE_TOL`` of their scale (rounding
      differences are carried along by the filters' and parallel models' recursions).
    """
    out = {}
    for name in FDI_LOGS:
        logbin = build / f"{name}.bin"
        K = write_log_bin(model, name, logbin)
        res = {}
        for impl in ("gen", "hand", "sync"):
            run([exe, "dump", impl, logbin, build / f"{name}.{impl}.out"])
            res[impl] = _read_dump(build / f"{name}.{impl}.out", K, nr)
        g, h, s = res["gen"], res["hand"], res["sync"]
        out[name] = {
            "samples": K,
            "one_step_r": float(_scaled_diff(g["r"], s["r"], thresholds).max()),
            "one_step_rms": float(_scaled_diff(g["rms"], s["rms"], thresholds).max()),
            "one_step_z": float(_scaled_diff(g["z"], s["z"]).max()),
            "one_step_z_per_state": [float(x) for x in _scaled_diff(g["z"], s["z"])],
            "one_step_discrete_identical": bool(
                (g["flags"] == s["flags"]).all() and (g["fault_class"] == s["fault_class"]).all()
                and (g["action"] == s["action"]).all() and (g["faults"] == s["faults"]).all()),
            "free_r": float(_scaled_diff(g["r"], h["r"], thresholds).max()),
            "free_rms": float(_scaled_diff(g["rms"], h["rms"], thresholds).max()),
            "free_aux": float(_scaled_diff(g["aux"], h["aux"]).max()),
            "flags_identical": bool((g["flags"] == h["flags"]).all()),
            "class_identical": bool((g["fault_class"] == h["fault_class"]).all()),
            "action_identical": bool((g["action"] == h["action"]).all()),
            "faults_identical": bool((g["faults"] == h["faults"]).all()),
            "final_class": int(g["fault_class"][-1]),
        }
    worst = {k: max(v[k] for v in out.values())
             for k in ("one_step_r", "one_step_rms", "one_step_z", "free_r", "free_rms",
                       "free_aux")}
    discrete = all(v["flags_identical"] and v["class_identical"] and v["action_identical"]
                   and v["faults_identical"] and v["one_step_discrete_identical"]
                   for v in out.values())
    ok = (discrete and worst["one_step_r"] <= ONE_STEP_TOL
          and worst["one_step_rms"] <= ONE_STEP_TOL and worst["one_step_z"] <= ONE_STEP_TOL
          and worst["free_r"] <= FREE_TOL)
    return {"logs": out, "worst": worst, "discrete_identical": discrete,
            "one_step_tolerance": ONE_STEP_TOL, "free_running_tolerance": FREE_TOL,
            "passed": bool(ok)}


ONE_STEP_TOL = 1e-12
FREE_TOL = 1e-10


def time_gen_vs_hand(exe: Path, logbin: Path, repeats: int) -> dict:
    proc = run([exe, "time", logbin, repeats])
    body = proc.stdout.split("--\n", 1)[1]
    rows = {"gen": {"wall": [], "cpu": []}, "hand": {"wall": [], "cpu": []}}
    for line in body.splitlines():
        impl, wall, cpu = line.split()
        rows[impl]["wall"].append(float(wall))
        rows[impl]["cpu"].append(float(cpu))
    res = {}
    for impl, r in rows.items():
        res[impl] = {"ns_per_sample_wall": median(r["wall"]), "wall_range": spread(r["wall"]),
                     "ns_per_sample_cpu": median(r["cpu"]), "cpu_range": spread(r["cpu"])}
    # per-pair ratios (gen and hand of the same repeat ran back to back)
    pair = [g / h for g, h in zip(rows["gen"]["cpu"], rows["hand"]["cpu"])]
    res["ratio_wall"] = res["gen"]["ns_per_sample_wall"] / res["hand"]["ns_per_sample_wall"]
    res["ratio_cpu"] = res["gen"]["ns_per_sample_cpu"] / res["hand"]["ns_per_sample_cpu"]
    res["ratio_cpu_median_of_pairs"] = median(pair)
    res["repeats"] = repeats
    return res


def callgrind(exe: Path, args, build: Path, tag: str, toggles) -> dict:
    """Instructions (Ir) inclusive of each toggle function, and the top self-cost
    functions under them, from one callgrind run."""
    if not have("valgrind"):
        return {"error": "valgrind not available"}
    out = build / f"callgrind.{tag}.out"
    run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
         "--collect-atstart=no", *(f"--toggle-collect={t}" for t in toggles), exe, *args])
    incl = run(["callgrind_annotate", "--auto=no", "--inclusive=yes", "--threshold=100",
                out]).stdout
    excl = run(["callgrind_annotate", "--auto=no", "--inclusive=no", "--threshold=100",
                out]).stdout

    def table(text):
        rows = {}
        body = text.split("file:function", 1)[-1]    # the function table only
        for line in body.splitlines():
            m = re.match(r"\s*([\d,]+)\s+(?:\([^)]*\)\s+)?(\S.*?)\s*(?:\[.*\])?$", line)
            if m and ":" in m.group(2):
                fn = m.group(2).split(":", 1)[1].strip()
                fn = re.sub(r"\s*\([\d,]+x\)$", "", fn)   # call counts of newer versions
                rows[fn] = rows.get(fn, 0) + int(m.group(1).replace(",", ""))
        return rows

    return {"inclusive": table(incl), "self": table(excl)}


def static_counts(obj: Path, functions) -> dict:
    """Instructions of interest in the disassembly of each function."""
    text = run(["objdump", "-d", "--no-show-raw-insn", obj]).stdout
    res = {}
    current = None
    for line in text.splitlines():
        m = re.match(r"^[0-9a-f]+ <(.+)>:$", line)
        if m:
            current = m.group(1).split(".", 1)[0]    # gcc clones: f.isra.0, f.constprop.0
            continue
        if current in functions and "\t" in line:
            ins = line.split("\t")[-1].split()[0] if line.split("\t")[-1].split() else ""
            d = res.setdefault(current, {"instructions": 0, "divsd": 0, "sqrtsd": 0,
                                         "mulsd": 0, "addsd_subsd": 0, "call": 0,
                                         "branches": 0})
            d["instructions"] += 1
            if ins.startswith("divsd"):
                d["divsd"] += 1
            elif ins.startswith("sqrtsd"):
                d["sqrtsd"] += 1
            elif ins.startswith("mulsd"):
                d["mulsd"] += 1
            elif ins.startswith(("addsd", "subsd")):
                d["addsd_subsd"] += 1
            elif ins.startswith("call"):
                d["call"] += 1
            elif ins.startswith("j"):
                d["branches"] += 1
    return res


#: Blocks of the two steps, by the source line that opens them (first match after the
#: previous block's; a tuple: the first alternative present), for the per-block
#: instruction counts of callgrind_annotate. Inlined helpers count in their own lines.
GEN_BLOCKS = [
    ("constant-time selects (select helper)",
     "static pneumatic_cylinder_real pneumatic_cylinder_fdi_select("),
    ("outputs, state copy, finiteness test",
     "static pneumatic_cylinder_real pneumatic_cylinder_fdi_zero("),
    ("clamps (max/min helpers)", "static pneumatic_cylinder_real pneumatic_cylinder_fdi_max_a("),
    ("(other)", "int pneumatic_cylinder_fdi_default_params("),
    ("entry, loads, validity guards", "static int pneumatic_cylinder_fdi_initial_state("),
    ("entry, loads, validity guards", "static int pneumatic_cylinder_fdi_residuals("),
    ("parallel model: realignment, RK4, clamping", "realign_gate = "),
    ("R7 parallel model", "r_R7 = "),
    ("R8, R9 reduced parallel models", "r_R8 = "),
    ("Kalman residuals and voter", "yhat_R4 = "),
    ("Kalman updates and (scheduled) predictions", ("sched_Pp = ", "eu_R4 = ")),
    ("outputs, state copy, finiteness test", ("(void)R70_", "/* one finiteness test")),
    ("(other)", "int pneumatic_cylinder_fdi_core("),
    ("entry, loads, validity guards", "int pneumatic_cylinder_fdi_step("),
    ("moving RMS and flags", "/* moving RMS"),
    ("frozen horizon (late flags)", "/* late flags"),
    ("isolation", ("/* isolation", "/* the evidence")),
    ("action policy and contradiction", "/* the action the consistent classes"),
    ("consistent faults", "/* the faults consistent with the evidence"),
    ("(other)", "int pneumatic_cylinder_fdi_run("),
]
HAND_BLOCKS = [
    ("(other)", "void fdi_hand_init("),
    ("parallel model: realignment, RK4, clamping", "#define PAR_RHS("),
    ("entry, loads, validity guards", "int fdi_hand_step("),
    ("parallel model: realignment, RK4, clamping", "/* -- R1-R3"),
    ("R7 parallel model", "/* -- R7"),
    ("R8, R9 reduced parallel models", "/* -- R8, R9"),
    ("Kalman residuals and voter", "/* -- Kalman residuals"),
    ("Kalman updates and (scheduled) predictions", "/* -- prediction matrices"),
    ("Kalman updates and (scheduled) predictions", "/* -- filter updates"),
    ("outputs, state copy, finiteness test", "out->r[0] = r1"),
    ("moving RMS and flags", "/* -- moving RMS"),
    ("frozen horizon (late flags)", "/* -- frozen horizon"),
    ("isolation", "/* -- isolation"),
    ("action policy and contradiction", "/* -- action policy"),
    ("consistent faults", "/* -- consistent faults"),
]


def _line_blocks(source: Path, blocks) -> dict:
    lines = source.read_text().splitlines()
    starts, pos = [], 0
    for label, marker in blocks:
        for alt in (marker if isinstance(marker, tuple) else (marker,)):
            i = next((i for i in range(pos, len(lines)) if alt in lines[i]), None)
            if i is not None:
                starts.append((i + 1, label))
                pos = i + 1
                break
    out = {}
    for k, (start, label) in enumerate(starts):
        end = starts[k + 1][0] if k + 1 < len(starts) else len(lines) + 1
        for n in range(start, end):
            out[n] = label
    return out


def block_profile(cg_out: Path, K: int) -> dict:
    """Instructions per sample by block of each step (callgrind_annotate per source line;
    the drivers are built with -g, which does not change gcc's code)."""
    gen_src, hand_src = GEN_C / "pneumatic_cylinder_fdi.c", HAND / "fdi_hand.c"
    text = run(["callgrind_annotate", "--auto=no", "--inclusive=no", Path(cg_out).resolve(),
                gen_src, hand_src], cwd="/").stdout    # cwd /: paths are shown absolute
    res = {"generated": {}, "hand": {}}
    current, maps, line = None, {"generated": _line_blocks(gen_src, GEN_BLOCKS),
                                 "hand": _line_blocks(hand_src, HAND_BLOCKS)}, 0
    for row in text.splitlines():
        if row.startswith("-- User-annotated source:"):
            path = row.split(":", 1)[1].strip()
            current = "generated" if path.endswith("pneumatic_cylinder_fdi.c") else \
                "hand" if path.endswith("fdi_hand.c") else None
            continue
        m = re.match(r"^-- line (\d+) -+$", row)
        if m:
            line = int(m.group(1))
            continue
        if (current is None or row.startswith("--") or not row.strip()
                or row.startswith("Ir") or "events annotated" in row):
            continue
        if re.match(r"^\s*[\d,]+ \(\s*[\d.]+%\)\s+=> ", row):
            continue    # a call's inclusive cost, shown under the calling line
        m = re.match(r"^\s*([\d,]+|\.)(?: \(\s*[\d.]+%\))?\s", row)
        if not m:
            continue
        if m.group(1) != ".":
            label = maps[current].get(line, "(other)")
            res[current][label] = res[current].get(label, 0) + int(m.group(1).replace(",", "")) / K
        line += 1
    return res


def generated_source_facts() -> dict:
    """What the generated residual generator does per sample, counted in its source."""
    text = (GEN_C / "pneumatic_cylinder_fdi.c").read_text()
    start = text.index("static int pneumatic_cylinder_fdi_residuals(")
    core = text[start:text.index("\n}\n", start)]
    body = [line for line in core.splitlines()
            if "const pneumatic_cylinder_real" in line and " = " in line]
    rhs = "\n".join(line.split(" = ", 1)[1] for line in body)
    names = [line.split(" = ", 1)[0].split()[-1] for line in body]
    step = text[text.index("int pneumatic_cylinder_fdi_step("):
                text.index("int pneumatic_cylinder_fdi_run(")]
    return {
        "assignments": len(body),
        "divisions": rhs.count("/"),
        "pow_calls": rhs.count("pow("),
        "select_calls": rhs.count("pneumatic_cylinder_fdi_select(")
        + step.count("pneumatic_cylinder_fdi_select("),
        "max_min_helper_calls": rhs.count("pneumatic_cylinder_fdi_max_a(")
        + rhs.count("pneumatic_cylinder_fdi_min_a("),
        "derived_parameters_per_call": sum(1 for n in names if re.fullmatch(r"dp\d+", n)),
        "parameter_loads_per_call": sum(1 for line in body if "= params->" in line),
        "schedule_assignments": sum(1 for n in names if n.startswith("sched_")
                                    or re.fullmatch(r"R\d+_(Ar|Br|Ad|Bd)\d\d", n)),
        # divisions by a common subexpression of the scheduled signals (Vp Vn)
        "schedule_divisions": sum(rhs.count(f"/{n}") for n, line in zip(names, body)
                                  if n.startswith("cse") and "sched_" in line),
        "dead R7 stage states computed": text.count("(void)R70_"),
        "residuals_static": "static int pneumatic_cylinder_fdi_residuals(" in text,
        "array_select": "return v[c != 0];" in text,
        "rms_divides_by_N": "/ (pneumatic_cylinder_real)PNEUMATIC_CYLINDER_FDI_WINDOW" in step,
    }


#: What would close the gap, applied to a copy of the generated C by text substitution
#: (bench only; the real fixes belong in fdigen's printer and templates). Each fix is a
#: function text -> (text, number of substitutions); see :func:`make_variant`.
REAL = "pneumatic_cylinder_real"
SELECT_HEAD = f"static {REAL} pneumatic_cylinder_fdi_select(int c, {REAL} a, {REAL} b)\n{{\n"


def _fix_rms_reciprocal(text):
    """The RMS multiplies each running sum by 1/N (a constant) instead of dividing by N."""
    old = f"/ ({REAL})PNEUMATIC_CYLINDER_FDI_WINDOW"
    return text.replace(old, f"* (({REAL})1 / PNEUMATIC_CYLINDER_FDI_WINDOW)"), text.count(old)


def _fix_derived_at_init(text):
    """Parameter-only assignments of the residual generator (dp0..dp5 and the products
    they use) computed once in ``_init`` into a derived-parameter array, read per call.
    (The array is file-static here -- one instance, enough for the what-if; the real fix
    is a derived-parameter struct filled by ``_init``.)"""
    start = text.index("static int pneumatic_cylinder_fdi_residuals(")
    end = text.index("\n}\n", start)
    body = text[start:end]
    params = dict(re.findall(rf"const {REAL} (\w+) = params->(\w+);", body))
    lifted, derived = [], set()
    for m in re.finditer(rf"^    const {REAL} (\w+) = ([^;]*);$", body, re.M):
        name, expr = m.groups()
        if "params->" in expr:
            continue
        idents = set(re.findall(r"[A-Za-z_]\w*", re.sub(r"\d+\.\d*(e[-+]?\d+)?", "", expr)))
        if idents and idents <= set(params) | derived:
            lifted.append((m.group(0), name, expr))
            derived.add(name)
    if not lifted:
        return text, 0
    for i, (line, name, _) in enumerate(lifted):
        body = body.replace(
            line, f"    const {REAL} {name} = pneumatic_cylinder_fdi_derived[{i}];", 1)
    decl = (f"/* bench what-if: parameter-only assignments, computed once by _init */\n"
            f"static {REAL} pneumatic_cylinder_fdi_derived[{len(lifted)}];\n\n")
    text = text[:start] + body + text[end:]
    first = text.index("int pneumatic_cylinder_fdi_default_params(")
    text = text[:first] + decl + text[first:]
    init_ret = "    return pneumatic_cylinder_fdi_reset(state);\n}"
    i0 = text.index("int pneumatic_cylinder_fdi_init(")
    pos = text.index(init_ret, i0)
    loads = "".join(f"        const {REAL} {k} = params->{v};\n" for k, v in params.items())
    comp = "".join(f"        const {REAL} {n} = {e};\n        pneumatic_cylinder_fdi_derived[{i}] "
                   f"= {n};\n" for i, (_, n, e) in enumerate(lifted))
    text = text[:pos] + "    {\n" + loads + comp + "    }\n" + text[pos:]
    return text, len(lifted)


def _fix_shared_denominator(text):
    """A denominator divided by more than once (the scheduled Jacobian entries' Vp Vn)
    inverted once and multiplied by."""
    start = text.index("static int pneumatic_cylinder_fdi_residuals(")
    end = text.index("\n}\n", start)
    body = text[start:end]
    n = 0
    for den in sorted(set(re.findall(r"/(cse\d+)\b", body))):
        if len(re.findall(rf"/{den}\b", body)) < 2:
            continue
        m = re.search(rf"^    const {REAL} {den} = [^;]*;$", body, re.M)
        body = re.sub(rf"/{den}\b", f"*inv_{den}", body)
        body = (body[:m.end()] + f"\n    const {REAL} inv_{den} = 1.0/{den};"
                + body[m.end():])
        n += 1
    return text[:start] + body + text[end:], n


def _fix_inline_core(text):
    """The residual generator inlined into ``_step`` (no call, no argument passing)."""
    old = "static int pneumatic_cylinder_fdi_residuals("
    new = "static inline __attribute__((always_inline)) int pneumatic_cylinder_fdi_residuals("
    return text.replace(old, new), text.count(old)


def _fix_plain_selects(text):
    """``c ? a : b`` instead of the select helper: gives up the constant-time property
    the reliability requirements ask for (the compiler may branch on the data)."""
    i = text.index(SELECT_HEAD) + len(SELECT_HEAD)
    j = text.index("\n}\n", i)
    return text[:i] + "    return c ? a : b;" + text[j:], 1


VARIANT_FIXES = {
    "RMS by 1/N": _fix_rms_reciprocal,
    "parameter-only assignments at init": _fix_derived_at_init,
    "one division for a shared denominator": _fix_shared_denominator,
    "residual generator inlined": _fix_inline_core,
    "plain ?: selects (not constant time)": _fix_plain_selects,
}
#: The what-if variants: the fixes that keep the generated step constant time, then also
#: the plain selects.
VARIANTS = {
    "variant": ("RMS by 1/N", "parameter-only assignments at init",
                "one division for a shared denominator", "residual generator inlined"),
    "variant_all": ("RMS by 1/N", "parameter-only assignments at init",
                    "one division for a shared denominator", "residual generator inlined",
                    "plain ?: selects (not constant time)"),
}


def make_variant(build: Path, name: str) -> dict:
    """The generated C with the fixes of :data:`VARIANTS` ``[name]`` applied by text
    substitution, in ``build/<name>/``."""
    text = (GEN_C / "pneumatic_cylinder_fdi.c").read_text()
    counts = {}
    for label in VARIANTS[name]:
        text, n = VARIANT_FIXES[label](text)
        counts[label] = n
    vdir = build / name
    vdir.mkdir(exist_ok=True)
    (vdir / "pneumatic_cylinder_fdi.c").write_text(text)
    (vdir / "pneumatic_cylinder_fdi.h").write_text((GEN_C / "pneumatic_cylinder_fdi.h").read_text())
    return {"substitutions": counts, "folder": str(vdir)}


def _sum_static(st: dict) -> dict:
    out = {}
    for v in st.values():
        for k, n in v.items():
            out[k] = out.get(k, 0) + n
    return out


def variant(build: Path, model, nr: int, thresholds, repeats: int,
            name: str = "variant") -> dict:
    info = make_variant(build, name)
    vdir = Path(info["folder"])
    exe = compile_c(build / f"driver_{name}",
                    [HAND / "driver.c", HAND / "fdi_hand.c", vdir / "pneumatic_cylinder_fdi.c"],
                    [vdir, HAND, build])
    res = {"substitutions": info["substitutions"], "fixes": list(VARIANTS[name])}
    # same results as the generated core (free-running, its own state)?
    diffs, same = [], True
    for log in FDI_LOGS:
        K = write_log_bin(model, log, build / f"{log}.bin")
        run([exe, "dump", "gen", build / f"{log}.bin", build / f"{log}.{name}.out"])
        a = _read_dump(build / f"{log}.{name}.out", K, nr)
        g = _read_dump(build / f"{log}.gen.out", K, nr)
        diffs.append(float(_scaled_diff(g["r"], a["r"], thresholds).max()))
        same &= bool((a["flags"] == g["flags"]).all()
                     and (a["fault_class"] == g["fault_class"]).all()
                     and (a["action"] == g["action"]).all())
    res["free_r_vs_generated"] = max(diffs)
    res["discrete_identical"] = same
    logbin, K = timing_log_bin(build, model)
    t = time_gen_vs_hand(exe, logbin, repeats)
    res["ns_per_sample_cpu"] = t["gen"]["ns_per_sample_cpu"]
    res["hand_ns_per_sample_cpu"] = t["hand"]["ns_per_sample_cpu"]
    res["ratio_cpu"] = t["ratio_cpu"]
    cg = callgrind(exe, ["count", logbin], build, name, ["loop_gen", "loop_hand"])
    if "inclusive" in cg:
        inc = cg["inclusive"]
        gen = next(v for k, v in inc.items() if k.endswith("loop_gen"))
        hand = next(v for k, v in inc.items() if k.endswith("loop_hand"))
        res["instr_per_sample"] = gen / K
        res["instr_ratio"] = gen / hand
    run(["gcc", *CFLAGS, f"-I{vdir}", "-c", "-o", build / f"{name}.o",
         vdir / "pneumatic_cylinder_fdi.c"])
    res["static"] = static_counts(build / f"{name}.o", STEP_FUNCTIONS)
    res["static_step_total"] = _sum_static(res["static"])
    return res


#: The functions one generated step executes (``_residuals`` when gcc does not inline it).
STEP_FUNCTIONS = {"pneumatic_cylinder_fdi_step", "pneumatic_cylinder_fdi_residuals"}


def handwritten(build: Path, model, design, repeats: int, log=print) -> dict:
    drv = build_drivers(build, design)
    res = {"gains_not_in_design_json": drv["gains"], "flags": " ".join(CFLAGS)}
    log("  equivalence on the rig logs ...")
    res["equivalence"] = check_equivalence(build, drv["exes"]["gcc"], model,
                                           len(design.residual_names),
                                           np.asarray(design.evaluation.thresholds))
    logbin, K = timing_log_bin(build, model)
    res["timing_log"] = {"name": TIMING_LOG, "samples": K}
    for cc, exe in drv["exes"].items():
        log(f"  timing ({cc}, {repeats} interleaved repeats) ...")
        res[f"time_{cc}"] = time_gen_vs_hand(exe, logbin, repeats)
    log("  callgrind ...")
    cg = callgrind(drv["exes"]["gcc"], ["count", logbin], build, "gen_hand",
                   ["loop_gen", "loop_hand"])
    if "inclusive" in cg:
        inc = cg["inclusive"]
        gen = next(v for k, v in inc.items() if k.endswith("loop_gen"))
        hand = next(v for k, v in inc.items() if k.endswith("loop_hand"))
        res["callgrind"] = {"gen_instr_per_sample": gen / K, "hand_instr_per_sample": hand / K,
                            "ratio": gen / hand,
                            "self_per_sample": {k: v / K for k, v in sorted(
                                cg["self"].items(), key=lambda kv: -kv[1])[:12]}}
        try:
            res["callgrind"]["blocks"] = block_profile(build / "callgrind.gen_hand.out", K)
        except Exception as exc:
            res["callgrind"]["blocks_error"] = f"{type(exc).__name__}: {exc}"
    else:
        res["callgrind"] = cg
    res["static"] = {**static_counts(build / "gen.o", STEP_FUNCTIONS),
                     **static_counts(build / "hand.o", {"fdi_hand_step"})}
    res["static_gen_step_total"] = _sum_static(static_counts(build / "gen.o", STEP_FUNCTIONS))
    res["generated_source"] = generated_source_facts()
    log("  the generated C with the fixes of the analysis applied (bench/build/variant*) ...")
    for name in VARIANTS:
        try:
            res[name] = variant(build, model, len(design.residual_names),
                                np.asarray(design.evaluation.thresholds), repeats, name=name)
        except Exception as exc:
            res[name] = {"error": f"{type(exc).__name__}: {exc}"}
    return res


# -- 3. the platform bank vs one leg -------------------------------------------------------
PLATFORM_DRIVER = BENCH / "platform_driver.c"


def platform(build: Path, model, design, repeats: int, log=print) -> dict:
    try:
        from fdigen.platform.codegen import render_platform_sources
        files = render_platform_sources(design)
    except Exception as exc:  # the platform code is another engineer's work in progress
        log(f"  platform code not usable ({type(exc).__name__}: {exc}); six sequential legs")
        files = None
    pdir = build / "platform"
    pdir.mkdir(exist_ok=True)
    logbin = build / "fdi_healthy.bin"
    K = write_log_bin(model, "fdi_healthy", logbin)
    if files is not None:
        for name, text in files.items():
            (pdir / name).write_text(text)
        srcs = [PLATFORM_DRIVER] + [pdir / n for n in files if n.endswith(".c")]
        exe = compile_c(build / "platform_driver", srcs, [pdir], extra=["-DHAVE_PLATFORM=1"])
        mode = "generated platform step (pneumatic_cylinder_platform_step)"
    else:
        srcs = [PLATFORM_DRIVER, GEN_C / "pneumatic_cylinder_fdi.c"]
        exe = compile_c(build / "platform_driver", srcs, [GEN_C])
        mode = "platform code not available: 6 sequential single-leg steps"
    proc = run([exe, "time", logbin, repeats])
    rows = {"leg": {"wall": [], "cpu": []}, "platform": {"wall": [], "cpu": []}}
    for line in proc.stdout.split("--\n", 1)[1].splitlines():
        impl, wall, cpu = line.split()
        rows[impl]["wall"].append(float(wall))
        rows[impl]["cpu"].append(float(cpu))
    res = {"mode": mode, "samples": K, "repeats": repeats}
    for k, r in rows.items():
        res[k] = {"ns_per_sample_wall": median(r["wall"]), "ns_per_sample_cpu": median(r["cpu"]),
                  "cpu_range": spread(r["cpu"])}
    res["ratio_wall"] = res["platform"]["ns_per_sample_wall"] / res["leg"]["ns_per_sample_wall"]
    res["ratio_cpu"] = res["platform"]["ns_per_sample_cpu"] / res["leg"]["ns_per_sample_cpu"]
    cg = callgrind(exe, ["count", logbin], build, "platform", ["loop_leg", "loop_platform"])
    if "inclusive" in cg:
        inc = cg["inclusive"]
        leg = next(v for k, v in inc.items() if k.endswith("loop_leg"))
        plat = next(v for k, v in inc.items() if k.endswith("loop_platform"))
        res["callgrind"] = {"leg_instr_per_sample": leg / K,
                            "platform_instr_per_sample": plat / K, "ratio": plat / leg,
                            "self_per_sample": {k: v / K for k, v in sorted(
                                cg["self"].items(), key=lambda kv: -kv[1])[:8]}}
    return res


# -- 2b. the CasADi-generated C called natively -------------------------------------------
CASADI_DRIVER = BENCH / "casadi_driver.c"


def casadi_native(build: Path, model, design, repeats: int) -> dict:
    """ns/sample of the compiled CasADi chunk function called from C (no Python): how much
    of CasadiFdi.run is the generated arithmetic and how much the calling layer. The
    driver keeps the squared-residual history and supplies the squares leaving the
    window (``oldest``), as CasadiFdi.run does; its last sample is checked against the C
    core's on the same log."""
    src = GENERATED / "casadi" / "pneumatic_cylinder_casadi.c"
    exe = compile_c(build / "casadi_driver", [CASADI_DRIVER, src], [GENERATED / "casadi"])
    logbin, K = timing_log_bin(build, model)
    window = str(int(design.evaluation.window))
    params = [repr(float(q.value)) for q in model.parameters]
    proc = run([exe, logbin, repeats, window, *params])
    wall, cpu, check = [], [], None
    for line in proc.stdout.split("--\n", 1)[1].splitlines():
        if line.startswith("check "):
            check = line.split()[1:]
            continue
        w, c = line.split()
        wall.append(float(w))
        cpu.append(float(c))
    res = {"ns_per_sample_wall": median(wall), "ns_per_sample_cpu": median(cpu),
           "cpu_range": spread(cpu), "repeats": repeats}
    # the last sample processed against the generated C core on the same log
    nr = len(design.residual_names)
    gen = build / f"{TIMING_LOG}.gen.out"
    if check is not None and gen.exists():
        n = int(check[0])
        g = _read_dump(gen, K, nr)
        r_c = np.array([float(x) for x in check[3:]])
        r_g = g["r"][n - 1]
        scale = np.maximum(np.abs(g["r"]).max(axis=0), np.asarray(design.evaluation.thresholds))
        res["check"] = {
            "sample": n - 1,
            "flags_equal": int(float(check[1])) == int(g["flags"][n - 1]),
            "class_equal": int(float(check[2])) == int(g["fault_class"][n - 1]),
            "r_max_scaled_diff": float((np.abs(r_c - r_g) / np.maximum(scale, 1e-300)).max())}
    # instructions per sample, and where they go, on the first 4096 samples
    small = build / "casadi_small.bin"
    n = write_log_bin(model, TIMING_LOG, small, limit=4096)
    L = design_chunk_length(design)
    n = n - n % L
    cg = callgrind(exe, [small, 0, window, *params], build, "casadi",
                   ["pneumatic_cylinder_chunk"])
    if "inclusive" in cg:
        tot = next(v for k, v in cg["inclusive"].items() if k.endswith("pneumatic_cylinder_chunk"))
        res["instr_per_sample"] = tot / n
        res["self_per_sample"] = {k: v / n for k, v in sorted(
            cg["self"].items(), key=lambda kv: -kv[1])[:8]}
    res["chunk_length"] = L
    return res


def design_chunk_length(design) -> int:
    """Samples per call of the chunk function (``B * blocks`` of chunk_geometry)."""
    from fdigen.backends.casadi_backend.log_functions import chunk_geometry
    B, blocks = chunk_geometry(design)
    return B * blocks


# -- 6. Cortex-M4F ------------------------------------------------------------------------
M4_FLAGS = ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-Os",
            "-std=c99", "-ffunction-sections", "-fdata-sections"]


def _su(path: Path) -> dict:
    out = {}
    for line in path.read_text().splitlines():
        parts = line.split("\t")
        if len(parts) >= 3:
            fn = parts[0].rsplit(":", 1)[-1]
            out[fn] = {"bytes": int(parts[1]), "kind": parts[2]}
    return out


def _callgraph(ci: Path) -> dict:
    """Edges caller -> callees from gcc's -fcallgraph-info (VCG)."""
    text = ci.read_text()
    titles = {}
    for m in re.finditer(r'node:\s*\{\s*title:\s*"([^"]+)"\s*label:\s*"([^"\\]+)', text):
        titles[m.group(1)] = m.group(2).split()[0]
    edges = {}
    for m in re.finditer(r'edge:\s*\{\s*sourcename:\s*"([^"]+)"\s*targetname:\s*"([^"]+)"',
                         text):
        a = titles.get(m.group(1), m.group(1).rsplit(":", 1)[-1])
        b = titles.get(m.group(2), m.group(2).rsplit(":", 1)[-1])
        edges.setdefault(a, set()).add(b)
    return edges


def _state_bytes(header: Path, real_size: int) -> int:
    """sizeof(<m>_fdi_state) from the header's sizes (z, buf, sums real; 6 x 32-bit)."""
    text = header.read_text()

    def define(name):
        return int(re.search(rf"#define PNEUMATIC_CYLINDER_FDI_{name} (\d+)", text).group(1))
    nz, nr, w = define("NZ"), define("NR"), define("WINDOW")
    return real_size * (nz + w * nr + nr) + 4 * 6


def cortex_m4(build: Path) -> dict:
    if not have("arm-none-eabi-gcc"):
        return {"error": "arm-none-eabi-gcc not available"}
    mdir = build / "m4"
    mdir.mkdir(exist_ok=True)
    res = {"flags": " ".join(M4_FLAGS)}
    for tag, src, inc in (("generated_float", GENERATED / "c_float" / "pneumatic_cylinder_fdi.c",
                           GENERATED / "c_float"),):
        obj = mdir / f"{tag}.o"
        run(["arm-none-eabi-gcc", *M4_FLAGS, "-fstack-usage", "-fcallgraph-info=su",
             f"-I{inc}", "-c", "-o", obj, src], cwd=mdir)
        size = run(["arm-none-eabi-size", "-A", obj]).stdout
        sec = {}
        for line in size.splitlines():
            parts = line.split()
            if len(parts) >= 2 and parts[0].startswith("."):
                name = parts[0]
                key = (".text" if name.startswith(".text") else ".data" if name.startswith(".data")
                       else ".bss" if name.startswith(".bss") else ".rodata"
                       if name.startswith(".rodata") else None)
                if key:
                    sec[key] = sec.get(key, 0) + int(parts[1])
        su = _su(obj.with_suffix(".su"))
        edges = _callgraph(obj.with_suffix(".ci")) if obj.with_suffix(".ci").exists() else {}

        def worst(fn, seen=()):
            own = su.get(fn, {}).get("bytes", 0)
            best, path = 0, []
            for callee in edges.get(fn, ()):
                if callee in seen or callee not in su:
                    continue
                b, p = worst(callee, seen + (fn,))
                if b > best:
                    best, path = b, p
            return own + best, [fn] + path

        stack = {}
        for entry in ("pneumatic_cylinder_fdi_step", "pneumatic_cylinder_fdi_run"):
            if entry in su:
                b, p = worst(entry)
                stack[entry] = {"bytes": b, "path": " -> ".join(p)}
        res[tag] = {"sections": sec, "text_bytes": sec.get(".text", 0),
                    "stack_per_function": {k: v["bytes"] for k, v in su.items()},
                    "worst_stack": stack,
                    "state_struct_bytes": _state_bytes(inc / "pneumatic_cylinder_fdi.h", 4)}
    return res

"""C-level benchmarks: generated vs hand-written step, the platform bank, the CasADi C
called natively, and the Cortex-M4F build. Used by bench/run.py."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np

from common import (BENCH, CFLAGS, FDI_LOGS, GENERATED, LOGS, TIMING_LOG, compile_c, have,
                    median, run, spread)

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
    from fdigen.sim.log import read_log

    log = read_log(LOGS / f"{name}.csv", model)
    u = np.ascontiguousarray(log.u[:limit, 0], dtype=float)
    y = np.ascontiguousarray(log.y[:limit], dtype=float)
    with open(path, "wb") as fh:
        fh.write(np.int64(len(u)).tobytes())
        fh.write(u.tobytes())
        fh.write(y.tobytes())
    return len(u)


def _lit(x: float) -> str:
    return repr(float(x))


def _guards(design) -> dict:
    """Bounds and substitutes of the measurement-validity guards, read from the design's
    step and init programs (``x = Piecewise((x_raw, Abs(x_raw) <= b), (fallback, True))``)."""
    import sympy as sp

    def guards(program):
        out = {}
        for s, e in program.assignments:
            if isinstance(e, sp.Piecewise) and str(s) in ("v", "x3", "x2", "pp", "pn"):
                (raw, cond), (fallback, _) = e.args
                assert str(raw) == f"{s}_raw" and isinstance(cond, sp.core.relational.Le)
                out[str(s)] = (float(cond.rhs), fallback)
        return out

    step, init = guards(design.step), guards(design.init)
    assert set(step) == {"v", "x3", "x2", "pp", "pn"} and set(init) == {"x3", "x2", "pp", "pn"}
    assert step["x3"][0] == step["x2"][0] and step["pp"][0] == step["pn"][0]
    assert [str(step[k][1]) for k in ("x3", "x2", "pp", "pn")] == ["par_x", "par_x",
                                                                 "par_Pp", "par_Pn"]
    assert float(init["pp"][1]) == float(init["pn"][1])
    return {"v": step["v"][0], "v_fallback": float(step["v"][1]), "x": step["x3"][0],
            "p": step["pp"][0], "x_init": float(init["x3"][1]), "p_init": float(init["pp"][1])}


def design_constants(design) -> dict:
    """Every constant of the hand-written step (and of the filterpy peer): gains and
    matrices from design.json, the R7 gain, voter tolerance and validity bounds from the
    design object. Checks the structural assumptions the hand-written code makes (which
    entries are 0 or 1); a design that breaks them fails here, loudly."""
    desc = json.loads((GENERATED / "design.json").read_text())
    kal = {k["residual"]: k for k in desc["kalman"]}
    iso = desc["isolation"]
    names = desc["residuals"]
    base = ["R1", "R2", "R3", "R4", "R5", "w1", "w2", "w3", "R6", "R7"]
    guards = names == base + ["nf_x3", "nf_x2", "nf_pp", "nf_pn"]
    assert names == base or guards, f"residuals {names}: the hand-written step knows " \
        f"{base} (+ nf_x3, nf_x2, nf_pp, nf_pn)"
    assert tuple(names) == tuple(design.residual_names), \
        "generated/ and the current design differ: run `fdigen build` first"
    assert desc["sample_time"] == design.config.sample_time and design.config.substeps == 1
    c = {"model_hash": desc["model_hash"], "names": names, "guards": guards,
         "window": iso["window"], "confirm": iso["confirm"], "dt": desc["sample_time"],
         "realign": np.array(desc["realignment_gain"], dtype=float)}
    asg = {str(s): e for s, e in design.step.assignments}
    r7 = asg["R7c_m_valve"]
    syms = {str(s): s for s in r7.free_symbols}
    c["R7_gain"] = float(r7.subs({syms["R7_m_valve"]: 0, syms["r_R7"]: 1,
                                  syms["realign_gate"]: 1}))
    c["voter_tolerance"] = float(design.config.voter.tolerance)
    if guards:
        c["bounds"] = _guards(design)
    for res, coords in (("R4", ["Pd", "x", "xdot"]), ("R5", ["Pd", "xdot"]),
                        ("R6", ["x", "xdot"])):
        k = kal[res]
        assert k["coordinates"] == coords, (res, k["coordinates"])
        c[res] = {"A": np.array(k["A_discrete"], dtype=float),
                  "B": np.array(k["B_discrete"], dtype=float),
                  "M": np.array(k["gain_discrete_filter_M"], dtype=float)[:, 0],
                  "C": np.array(k["C_reduced"], dtype=float)}
    A, C = c["R4"]["A"], c["R4"]["C"]
    assert kal["R4"]["update"] == "voter" and kal["R4"]["measurement"] == ["x3"]
    assert list(C[0]) == [0, 1, 0] and A[0, 1] == 0 and A[1, 1] == 1 and A[2, 1] == 0
    assert list(c["R5"]["C"][0]) == [1, 0] and kal["R5"]["measurement"] == ["pp - pn"]
    A, B = c["R6"]["A"], c["R6"]["B"]
    assert list(c["R6"]["C"][0]) == [1, 0] and kal["R6"]["measurement"] == ["x3"]
    assert A[0, 0] == 1 and A[1, 0] == 0 and not B[:, 0].any() and (B[:, 1] == -B[:, 2]).all()
    ev = design.evaluation
    assert ev.window == iso["window"] and tuple(ev.residuals) == tuple(names)
    c["thresholds"] = [float(iso["thresholds"].get(n, 0.0)) for n in names]
    assert np.array_equal(np.array(c["thresholds"]), np.asarray(ev.thresholds))
    bits = {n: i for i, n in enumerate(names)}
    classes = iso["classes"]
    c["patterns"] = [(sum(1 << bits[r] for r in p["residuals"]), classes.index(p["class"]))
                     for p in iso["patterns"]]
    codes = {"none": 0, "accommodate": 1, "safety_stop": 2}
    c["action_codes"] = [codes[iso["actions"][k]] for k in classes]
    assert tuple(c["patterns"]) == tuple(ev.patterns), "pattern order differs"
    assert tuple(c["action_codes"]) == tuple(ev.action_codes)
    c["parameters"] = [float(q.value) for q in design.model.parameters]
    return c


def write_gains_header(design, path: Path) -> dict:
    """fdi_hand_gains.h: the constants of :func:`design_constants` as C."""
    c = design_constants(design)
    names = c["names"]
    lines = ["/* Written by bench/run.py from generated/pneumatic_cylinder/design.json "
             f"(model hash {c['model_hash'][:16]}). Do not edit. */",
             "#ifndef FDI_HAND_GAINS_H", "#define FDI_HAND_GAINS_H", "#include <stdint.h>",
             f"#define FH_NR {len(names)}", f"#define FH_WINDOW {c['window']}",
             f"#define FH_GUARDS {int(c['guards'])}", f"#define FH_DT {_lit(c['dt'])}"]
    if c["guards"]:
        b = c["bounds"]
        lines += [f"#define FH_BOUND_V {_lit(b['v'])}",
                  f"#define FH_FALLBACK_V {_lit(b['v_fallback'])}",
                  f"#define FH_BOUND_X {_lit(b['x'])}", f"#define FH_BOUND_P {_lit(b['p'])}",
                  f"#define FH_INIT_X {_lit(b['x_init'])}",
                  f"#define FH_INIT_P {_lit(b['p_init'])}"]
    for i in range(4):
        for j in range(3):
            lines.append(f"#define FH_RA_{i}{j} {_lit(c['realign'][i][j])}")
    lines.append(f"#define FH_R7_G {_lit(c['R7_gain'])}")
    lines.append(f"#define FH_VINV {_lit(1.0 / c['voter_tolerance'])}")
    A, B, M = c["R4"]["A"], c["R4"]["B"], c["R4"]["M"]
    for (i, j) in ((0, 0), (0, 2), (1, 0), (1, 2), (2, 0), (2, 2)):
        lines.append(f"#define FH_R4_A{i}{j} {_lit(A[i, j])}")
    for i in range(3):
        lines.append(f"#define FH_R4_B{i} {_lit(B[i, 0])}")
        lines.append(f"#define FH_R4_M{i} {_lit(M[i])}")
    A, B, M = c["R5"]["A"], c["R5"]["B"], c["R5"]["M"]
    for i in range(2):
        for j in range(2):
            lines.append(f"#define FH_R5_A{i}{j} {_lit(A[i, j])}")
        lines.append(f"#define FH_R5_B{i} {_lit(B[i, 0])}")
        lines.append(f"#define FH_R5_M{i} {_lit(M[i])}")
    A, B, M = c["R6"]["A"], c["R6"]["B"], c["R6"]["M"]
    lines += [f"#define FH_R6_A01 {_lit(A[0, 1])}", f"#define FH_R6_A11 {_lit(A[1, 1])}",
              f"#define FH_R6_BP0 {_lit(B[0, 1])}", f"#define FH_R6_BP1 {_lit(B[1, 1])}",
              f"#define FH_R6_M0 {_lit(M[0])}", f"#define FH_R6_M1 {_lit(M[1])}"]
    thr = ", ".join(_lit(x) for x in c["thresholds"])
    masks = [m for m, _ in c["patterns"]]
    pcls = [k for _, k in c["patterns"]]
    acts = c["action_codes"]
    lines += [f"#define FH_CONFIRM {c['confirm']}",
              f"#define FH_NPATTERNS {len(masks)}",
              f"static const double FH_THRESHOLD[{len(names)}] = {{{thr}}};",
              f"static const uint32_t FH_PATTERN_MASK[{len(masks)}] = "
              f"{{{', '.join(f'{m}u' for m in masks)}}};",
              f"static const int32_t FH_PATTERN_CLASS[{len(masks)}] = "
              f"{{{', '.join(map(str, pcls))}}};",
              f"static const int32_t FH_ACTION_CODE[{len(acts)}] = "
              f"{{{', '.join(map(str, acts))}}};",
              "#endif", ""]
    path.write_text("\n".join(lines))
    return {"R7_gain": c["R7_gain"], "voter_tolerance": c["voter_tolerance"],
            "validity_bounds": c.get("bounds")}


# -- 1. generated vs hand-written ---------------------------------------------------------
def _read_dump(path: Path, K: int, nr: int) -> dict:
    rec = np.dtype([("d", "<f8", 2 * nr + 2), ("i", "<i4", 3)])
    a = np.fromfile(path, dtype=rec, count=K)
    return {"r": a["d"][:, :nr], "rms": a["d"][:, nr:2 * nr], "aux": a["d"][:, 2 * nr:],
            "flags": a["i"][:, 0], "fault_class": a["i"][:, 1], "action": a["i"][:, 2]}


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
      state -- residuals and RMS within ``ONE_STEP_TOL`` of each residual's scale on the
      log (max |difference| / max |value|): the same operations, up to rounding;
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
            "one_step_discrete_identical": bool(
                (g["flags"] == s["flags"]).all() and (g["fault_class"] == s["fault_class"]).all()
                and (g["action"] == s["action"]).all()),
            "free_r": float(_scaled_diff(g["r"], h["r"], thresholds).max()),
            "free_rms": float(_scaled_diff(g["rms"], h["rms"], thresholds).max()),
            "free_aux": float(_scaled_diff(g["aux"], h["aux"]).max()),
            "flags_identical": bool((g["flags"] == h["flags"]).all()),
            "class_identical": bool((g["fault_class"] == h["fault_class"]).all()),
            "action_identical": bool((g["action"] == h["action"]).all()),
            "final_class": int(g["fault_class"][-1]),
        }
    worst = {k: max(v[k] for v in out.values())
             for k in ("one_step_r", "one_step_rms", "free_r", "free_rms", "free_aux")}
    discrete = all(v["flags_identical"] and v["class_identical"] and v["action_identical"]
                   and v["one_step_discrete_identical"] for v in out.values())
    ok = (discrete and worst["one_step_r"] <= ONE_STEP_TOL
          and worst["one_step_rms"] <= ONE_STEP_TOL and worst["free_r"] <= FREE_TOL)
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
    incl = run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", out]).stdout
    excl = run(["callgrind_annotate", "--inclusive=no", "--threshold=100", out]).stdout

    def table(text):
        rows = {}
        for line in text.splitlines():
            m = re.match(r"\s*([\d,]+)\s+(?:\([^)]*\)\s+)?(\S.*?)\s*(?:\[.*\])?$", line)
            if m and ":" in m.group(2):
                fn = m.group(2).split(":", 1)[1].strip()
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
            current = m.group(1)
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
#: previous block's), for the per-block instruction counts of callgrind_annotate.
GEN_BLOCKS = [
    ("NaN-aware min/max helpers", "static pneumatic_cylinder_real pneumatic_cylinder_fdi_max("),
    ("(other)", "int pneumatic_cylinder_fdi_default_params("),
    ("entry, loads, validity guards", "int pneumatic_cylinder_fdi_core("),
    ("parallel model: realignment, RK4, clamping", "realign_gate = "),
    ("R7 parallel model", "r_R7 = "),
    ("Kalman residuals and voter", "yhat_R4 = "),
    ("Kalman updates and predictions", "eu_R4 = "),
    ("outputs, state copy, finiteness tests", "z_next[0] = "),
    ("outputs, state copy, finiteness tests", "int pneumatic_cylinder_fdi_step("),
    ("moving RMS and flags", "/* moving RMS"),
    ("isolation", "/* isolation"),
    ("(other)", "int pneumatic_cylinder_fdi_run("),
]
HAND_BLOCKS = [
    ("(other)", "void fdi_hand_init("),
    ("parallel model: realignment, RK4, clamping", "#define PAR_RHS("),
    ("entry, loads, validity guards", "int fdi_hand_step("),
    ("parallel model: realignment, RK4, clamping", "/* -- R1-R3"),
    ("R7 parallel model", "/* -- R7"),
    ("Kalman residuals and voter", "/* -- Kalman residuals"),
    ("Kalman updates and predictions", "/* -- filter updates"),
    ("outputs, state copy, finiteness tests", "out->r[0] = r1"),
    ("moving RMS and flags", "/* -- moving RMS"),
    ("isolation", "/* -- isolation"),
]


def _line_blocks(source: Path, blocks) -> dict:
    lines = source.read_text().splitlines()
    starts, pos = [], 0
    for label, marker in blocks:
        for i in range(pos, len(lines)):
            if marker in lines[i]:
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
    """What the generated core does per sample, counted in its source text."""
    text = (GEN_C / "pneumatic_cylinder_fdi.c").read_text()
    core = text[text.index("int pneumatic_cylinder_fdi_core("):
                text.index("int pneumatic_cylinder_fdi_step(")]
    body = "\n".join(line for line in core.splitlines() if "const pneumatic_cylinder_real"
                     in line and "=" in line)
    rhs = "\n".join(line.split("=", 1)[1] for line in body.splitlines())
    return {
        "assignments": len(body.splitlines()),
        "divisions": rhs.count("/"),
        "pow_calls": rhs.count("pow("),
        "max_min_helper_calls": rhs.count("pneumatic_cylinder_fdi_max(")
        + rhs.count("pneumatic_cylinder_fdi_min("),
        "K*R*Ts*gamma (parameter-only product, per stage)": rhs.count("K*R*Ts*gamma"),
        "A*gamma (parameter-only product)": rhs.count("A*gamma"),
        "/M (division by a parameter)": rhs.count("/M"),
        "dead R7 stage states computed": text.count("(void)R70_"),
    }


#: What would close the gap, applied to a copy of the generated C by text substitution
#: (bench only; the real fix belongs in fdigen's printer and templates).
VARIANT_RULES = [
    ("one division per pressure derivative",
     r"-A\*gamma\*(\w+)\*(\w+)/(cse\d+) \+ K\*R\*Ts\*gamma\*v/\3", r"(KRTgv - gA*\1*\2)/\3"),
    ("one division per pressure derivative",
     r"A\*gamma\*(\w+)\*(\w+)/(cse\d+) - K\*R\*Ts\*gamma\*v/\3", r"(gA*\1*\2 - KRTgv)/\3"),
    ("parameter-only quotients once per call", r"A\*\(([^()]*)\)/M", r"A_M*(\1)"),
    ("parameter-only quotients once per call", r"Ff\*(\w+)/M", r"Ff_M*\1"),
]


#: Further fixes (the "all" variant): factored sums, plain clamps, one finiteness test.
VARIANT_RULES_MORE = [
    ("RK4 combination factored",
     r"(0\.0001666+\d*)\*(\w+) \+ (0\.0003333+\d*)\*(\w+) \+ \3\*(\w+) \+ \1\*(\w+) \+ (\w+);",
     r"\7 + \1*(\2 + 2.0*(\4 + \5) + \6);"),
    ("R7 derivative factored",
     r"A\*(\w+)\*gamma\*pn - A\*\1\*gamma\*pp - A\*\1\*pn \+ A\*\1\*pp", r"cm7*\1"),
    ("clamps by plain comparisons",
     r"pneumatic_cylinder_fdi_min\((\w+), pneumatic_cylinder_fdi_max\(([\w.]+), (\w+)\)\)",
     r"(\3 < \2 ? \2 : (\3 > \1 ? \1 : \3))"),
]
FINITE_LOOP = """    for (i = 0; i < PNEUMATIC_CYLINDER_FDI_NZ; ++i) {
        if (!isfinite(z_next[i])) {
            status = PNEUMATIC_CYLINDER_FDI_WARN_NONFINITE;
        }
    }
    for (i = 0; i < PNEUMATIC_CYLINDER_FDI_NR; ++i) {
        if (!isfinite(r[i])) {
            status = PNEUMATIC_CYLINDER_FDI_WARN_NONFINITE;
        }
    }
"""
FINITE_ONCE = """    {
        pneumatic_cylinder_real acc = 0;
        for (i = 0; i < PNEUMATIC_CYLINDER_FDI_NZ; ++i) {
            acc += z_next[i] - z_next[i];
        }
        for (i = 0; i < PNEUMATIC_CYLINDER_FDI_NR; ++i) {
            acc += r[i] - r[i];
        }
        if (acc != 0) {
            status = PNEUMATIC_CYLINDER_FDI_WARN_NONFINITE;
        }
    }
"""


def make_variant(build: Path, name: str = "variant", more: bool = False) -> dict:
    """The generated C with the fixes of the analysis applied by text substitution:
    (1) one division per pressure derivative, (2) parameter-only products and quotients
    (K*R*Ts*gamma*v, A*gamma, A/M, Ff/M) computed once per call, (3) ``_core`` static so
    that it is inlined into ``_step``; with ``more`` also (4) factored RK4 sums and R7
    derivative, (5) clamps by plain comparisons, (6) one finiteness test."""
    text = (GEN_C / "pneumatic_cylinder_fdi.c").read_text()
    counts = {}
    for label, pat, rep in VARIANT_RULES + (VARIANT_RULES_MORE if more else []):
        text, n = re.subn(pat, rep, text)
        counts[label] = counts.get(label, 0) + n
    if more:
        r7 = re.search(r"\n(\s*)const pneumatic_cylinder_real r_R7 = [^\n]*\n", text)
        if r7:
            text = (text[:r7.end()] + f"{r7.group(1)}const pneumatic_cylinder_real cm7 = "
                    "A*(gamma - 1)*(pn - pp);\n" + text[r7.end():])
        counts["one finiteness test"] = text.count(FINITE_LOOP)
        text = text.replace(FINITE_LOOP, FINITE_ONCE)
    decl = "        const pneumatic_cylinder_real accommodate = mode[1];\n"
    if decl in text:
        text = text.replace(decl, decl + (
            "        const pneumatic_cylinder_real gA = A*gamma, KRTgv = K*R*Ts*gamma*v;\n"
            "        const pneumatic_cylinder_real A_M = A/M, Ff_M = Ff/M;\n"
            "        (void)gA; (void)KRTgv; (void)A_M; (void)Ff_M;\n"))
    # v is defined after mode when the design has measurement-validity guards
    m = re.search(r"        const pneumatic_cylinder_real v = .*?\n\)\);\n", text, re.S)
    if m and m.start() > text.index(decl):
        text = text.replace("KRTgv = K*R*Ts*gamma*v;", "KRTgv_unused = 0;")
        text = text.replace("(void)KRTgv;", "(void)KRTgv_unused;")
        text = text[:m.end()] + ("        const pneumatic_cylinder_real KRTgv = "
                                 "K*R*Ts*gamma*v;\n") + text[m.end():]
    n_static = text.count("int pneumatic_cylinder_fdi_core(")
    text = text.replace("int pneumatic_cylinder_fdi_core(",
                        "static int pneumatic_cylinder_fdi_core_impl(", 1)
    text = text.replace("status = pneumatic_cylinder_fdi_core(",
                        "status = pneumatic_cylinder_fdi_core_impl(")
    counts["_core static (inlined into _step)"] = n_static
    vdir = build / name
    vdir.mkdir(exist_ok=True)
    (vdir / "pneumatic_cylinder_fdi.c").write_text(text)
    (vdir / "pneumatic_cylinder_fdi.h").write_text((GEN_C / "pneumatic_cylinder_fdi.h").read_text())
    return {"substitutions": counts, "folder": str(vdir)}


def variant(build: Path, model, nr: int, thresholds, repeats: int, name: str = "variant",
            more: bool = False) -> dict:
    info = make_variant(build, name, more)
    vdir = Path(info["folder"])
    exe = compile_c(build / f"driver_{name}",
                    [HAND / "driver.c", HAND / "fdi_hand.c", vdir / "pneumatic_cylinder_fdi.c"],
                    [vdir, HAND, build])
    res = {"substitutions": info["substitutions"]}
    # same results as the generated core (free-running, its own state)?
    diffs, same = [], True
    for log in FDI_LOGS:
        K = write_log_bin(model, log, build / f"{log}.bin")
        run([exe, "dump", "gen", build / f"{log}.bin", build / f"{log}.{name}.out"])
        a = _read_dump(build / f"{log}.{name}.out", K, nr)
        g = _read_dump(build / f"{log}.gen.out", K, nr)
        diffs.append(float(_scaled_diff(g["r"], a["r"], thresholds).max()))
        same &= bool((a["flags"] == g["flags"]).all() and (a["fault_class"] == g["fault_class"]).all())
    res["free_r_vs_generated"] = max(diffs)
    res["discrete_identical"] = same
    logbin = build / f"{TIMING_LOG}.bin"
    write_log_bin(model, TIMING_LOG, logbin)
    t = time_gen_vs_hand(exe, logbin, repeats)
    res["ns_per_sample_cpu"] = t["gen"]["ns_per_sample_cpu"]
    res["hand_ns_per_sample_cpu"] = t["hand"]["ns_per_sample_cpu"]
    res["ratio_cpu"] = t["ratio_cpu"]
    cg = callgrind(exe, ["count", logbin], build, name, ["loop_gen", "loop_hand"])
    if "inclusive" in cg:
        inc = cg["inclusive"]
        K = write_log_bin(model, TIMING_LOG, logbin)
        gen = next(v for k, v in inc.items() if k.endswith("loop_gen"))
        hand = next(v for k, v in inc.items() if k.endswith("loop_hand"))
        res["instr_per_sample"] = gen / K
        res["instr_ratio"] = gen / hand
    run(["gcc", *CFLAGS, f"-I{vdir}", "-c", "-o", build / f"{name}.o",
         vdir / "pneumatic_cylinder_fdi.c"])
    res["static"] = static_counts(build / f"{name}.o", {"pneumatic_cylinder_fdi_step"})
    return res


def handwritten(build: Path, model, design, repeats: int, log=print) -> dict:
    drv = build_drivers(build, design)
    res = {"gains_not_in_design_json": drv["gains"], "flags": " ".join(CFLAGS)}
    log("  equivalence on the rig logs ...")
    res["equivalence"] = check_equivalence(build, drv["exes"]["gcc"], model,
                                           len(design.residual_names),
                                           np.asarray(design.evaluation.thresholds))
    logbin = build / f"{TIMING_LOG}.bin"
    K = write_log_bin(model, TIMING_LOG, logbin)
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
    res["static"] = {**static_counts(build / "gen.o", {"pneumatic_cylinder_fdi_core",
                                                       "pneumatic_cylinder_fdi_step"}),
                     **static_counts(build / "hand.o", {"fdi_hand_step"})}
    res["generated_source"] = generated_source_facts()
    log("  the generated C with the suggested fixes applied (bench/build/variant) ...")
    try:
        res["variant"] = variant(build, model, len(design.residual_names),
                                 np.asarray(design.evaluation.thresholds), repeats)
    except Exception as exc:
        res["variant"] = {"error": f"{type(exc).__name__}: {exc}"}
    try:
        res["variant_all"] = variant(build, model, len(design.residual_names),
                                     np.asarray(design.evaluation.thresholds), repeats,
                                     name="variant_all", more=True)
    except Exception as exc:
        res["variant_all"] = {"error": f"{type(exc).__name__}: {exc}"}
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


def casadi_native(build: Path, model, repeats: int) -> dict:
    """ns/sample of the compiled CasADi chunk function called from C (no Python): how much
    of CasadiFdi.run is the generated arithmetic and how much the calling layer."""
    src = GENERATED / "casadi" / "pneumatic_cylinder_casadi.c"
    exe = compile_c(build / "casadi_driver", [CASADI_DRIVER, src], [GENERATED / "casadi"])
    logbin = build / f"{TIMING_LOG}.bin"
    write_log_bin(model, TIMING_LOG, logbin)
    proc = run([exe, logbin, repeats, *(repr(float(q.value)) for q in model.parameters)])
    wall, cpu = [], []
    for line in proc.stdout.split("--\n", 1)[1].splitlines():
        w, c = line.split()
        wall.append(float(w))
        cpu.append(float(c))
    res = {"ns_per_sample_wall": median(wall), "ns_per_sample_cpu": median(cpu),
           "cpu_range": spread(cpu), "repeats": repeats}
    # instructions per sample, and where they go, on 4 chunks
    small = build / "casadi_small.bin"
    n = write_log_bin(model, TIMING_LOG, small, limit=4096)
    cg = callgrind(exe, [small, 0, *(repr(float(q.value)) for q in model.parameters)], build,
                   "casadi", ["pneumatic_cylinder_chunk"])
    if "inclusive" in cg:
        tot = next(v for k, v in cg["inclusive"].items() if k.endswith("pneumatic_cylinder_chunk"))
        res["instr_per_sample"] = tot / n
        res["self_per_sample"] = {k: v / n for k, v in sorted(
            cg["self"].items(), key=lambda kv: -kv[1])[:8]}
    return res


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

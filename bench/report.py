"""bench/results.md from the results dict of bench/run.py: the table, then the analysis."""

from __future__ import annotations

TARGETS = {"hand_ratio": 1.1, "whole_log_s": 0.15, "loop_ratio": 300.0,
           "platform_ratio": 6.5, "cold_build_s": 3.0, "unchanged_build_s": 0.5,
           "m4_text": 8192}


def _f(x, nd=3):
    if x is None:
        return "-"
    if isinstance(x, int):
        return f"{x:,}"
    ax = abs(x)
    if ax >= 1000:
        return f"{x:,.0f}"
    if ax >= 100:
        return f"{x:.0f}"
    if ax >= 10:
        return f"{x:.1f}"
    if ax >= 1:
        return f"{x:.{max(nd - 1, 0)}f}"
    return f"{x:.{nd}g}"


def _ok(measured, target, le=True):
    if measured is None:
        return "n/a"
    good = measured <= target if le else measured >= target
    if good:
        return "met"
    if le:
        return f"**missed** ({measured / target:.1f}x the target)"
    return f"**missed** ({target / measured:.1f}x short)"


def _err(sec):
    return isinstance(sec, dict) and "error" in sec


def render(R: dict) -> str:
    m = R["machine"]
    L = []
    w = L.append
    w("# fdigen performance results")
    w("")
    w(f"Produced by `python bench/run.py{' --quick' if R['mode'] == 'quick' else ''}"
      f"{' --smoke' if R['mode'] == 'smoke' else ''}` ({R['mode']} sizes) on "
      f"{R['started']}, {R['total_seconds']:.0f} s; every number is in `bench/results.json`.")
    if R["mode"] == "smoke":
        w("")
        w("**Smoke run: tiny sizes, the figures below are not results.**")
    w("")
    ghz = f"{m['ghz']} GHz" if m.get("ghz") else "clock not reported"
    if m.get("ghz_source"):
        ghz += f" ({m['ghz_source']})"
    w(f"**Machine**: {m['cpu_model']}"
      f"{' (' + m['cpu_id'] + ', ' + '/'.join(m.get('simd', [])) + ')' if m.get('cpu_id') else ''}"
      f", {m['cpus']} cores "
      f"({m.get('threads_per_core') or '?'} thread per core"
      f"{', ' + m['hypervisor'] + ' VM' if m.get('hypervisor') else ''}), {ghz}, "
      f"{m.get('memory_gib', '?')} GiB; caches {', '.join(f'{k} {v}' for k, v in m.get('caches', {}).items())}. "
      f"{m['gcc']}; {m['clang']}; Python {m['python']}, numpy {m['numpy']}, "
      f"CasADi {m.get('casadi', '-')}. Load average (1/5/15 min) before "
      f"{R['load_before']}, after {R['load_after']}: the machine is shared with other "
      "work, so wall times are noisy; **CPU times (thread or process CPU time) are the "
      "primary figures** and every ratio compares measurements taken back to back in "
      "the same run.")
    if R.get("design_error"):
        w("")
        w(f"Design could not be loaded: `{R['design_error']}`")
    w("")
    w("| # | measurement | result | target | status |")
    w("|---|---|---|---|---|")
    H, P, PL, B, MC, M4 = (R.get(k, {}) for k in ("hand", "python", "platform", "build",
                                                  "mc", "m4"))
    if H and not _err(H):
        g = H["time_gcc"]
        w(f"| 1 | generated / hand-written C step, gcc -O2 (CPU ns per sample, median of "
          f"{g['repeats']} interleaved passes over {H['timing_log']['samples']} samples) | "
          f"{_f(g['gen']['ns_per_sample_cpu'])} / {_f(g['hand']['ns_per_sample_cpu'])} ns = "
          f"**{g['ratio_cpu']:.2f}x** (wall {g['ratio_wall']:.2f}x) | <= 1.1x | "
          f"{_ok(g['ratio_cpu'], TARGETS['hand_ratio'])} |")
        if "time_clang" in H:
            c = H["time_clang"]
            w(f"| 1 | same, clang -O2 | {_f(c['gen']['ns_per_sample_cpu'])} / "
              f"{_f(c['hand']['ns_per_sample_cpu'])} ns = **{c['ratio_cpu']:.2f}x** | "
              f"<= 1.1x | {_ok(c['ratio_cpu'], TARGETS['hand_ratio'])} |")
        cg = H.get("callgrind", {})
        if "ratio" in cg:
            w(f"| 1 | instructions per sample (callgrind, gcc -O2) | "
              f"{_f(cg['gen_instr_per_sample'])} / {_f(cg['hand_instr_per_sample'])} = "
              f"**{cg['ratio']:.2f}x** | (<= 1.1x) | {_ok(cg['ratio'], TARGETS['hand_ratio'])} |")
        va = H.get("variant_all", {})
        if va and "ratio_cpu" in va:
            w(f"| 1 | what-if: the generated C with the fixes of section 1 applied (text "
              f"substitution on a copy, bench only) / hand-written | "
              f"{_f(va['ns_per_sample_cpu'])} / {_f(va['hand_ns_per_sample_cpu'])} ns = "
              f"{va['ratio_cpu']:.2f}x | (<= 1.1x) | "
              f"{_ok(va['ratio_cpu'], TARGETS['hand_ratio'])} |")
        e = H["equivalence"]
        w(f"| 1 | hand-written = generated on the 7 fdi_* rig logs | one step "
          f"<= {e['worst']['one_step_r']:.1g} (residuals), free-running <= "
          f"{e['worst']['free_r']:.1g} of scale; flags, class, action identical: "
          f"{'yes' if e['discrete_identical'] else 'NO'} | one step <= "
          f"{e['one_step_tolerance']:g} | {'met' if e['passed'] else '**FAILED**'} |")
    elif _err(H):
        w(f"| 1 | generated vs hand-written | error: {H['error']} | | |")
    if P and not _err(P):
        n = P["samples"]
        k = 1e6 / n
        sc = "" if n == 1_000_000 else f" (measured on {n:,}, scaled to 1e6)"
        w(f"| 2 | `CFdi.run`, 1e6 samples in one call (in-process){sc} | "
          f"**{P['cfdi_run_cpu_s'] * k:.3f} s** CPU ({P['cfdi_run_s'] * k:.3f} s wall; the C "
          f"call alone {P['cfdi_c_call_only_cpu_s'] * k:.3f} s) | <= 0.15 s | "
          f"{_ok(P['cfdi_run_cpu_s'] * k, TARGETS['whole_log_s'])} |")
        if "casadi_run_s" in P:
            sc = "" if P["casadi_samples"] == 1_000_000 else \
                f" (measured on {P['casadi_samples']:,}, scaled to 1e6)"
            w(f"| 2 | `CasadiFdi(compiled=True).run`, 1e6 samples{sc} | "
              f"**{P['casadi_run_cpu_s'] * k:.2f} s** CPU ({P['casadi_run_s'] * k:.2f} s wall) | "
              f"<= 0.15 s | {_ok(P['casadi_run_cpu_s'] * k, TARGETS['whole_log_s'])} |")
        for peer, label in (("reference", "`ReferenceFdi.step` loop (numpy)"),
                            ("filterpy", "filterpy + numpy loop")):
            if f"ratio_{peer}_vs_cfdi_cpu" not in P:
                continue
            line = (f"| 2 | {label} / `CFdi.run` ({_f(P[f'{peer}_us_per_sample_cpu'])} us per "
                    f"sample on {P['loop_samples']:,} samples, extrapolated) | "
                    f"**{_f(P[f'ratio_{peer}_vs_cfdi_cpu'])}x** (wall "
                    f"{_f(P[f'ratio_{peer}_vs_cfdi'])}x)")
            if f"ratio_{peer}_vs_casadi_cpu" in P:
                line += f"; vs CasadiFdi {_f(P[f'ratio_{peer}_vs_casadi_cpu'])}x"
            w(line + f" | >= 300x | {_ok(P[f'ratio_{peer}_vs_cfdi_cpu'], 300, le=False)}"
              + (f"; vs CasadiFdi {_ok(P[f'ratio_{peer}_vs_casadi_cpu'], 300, le=False)}"
                 if f"ratio_{peer}_vs_casadi_cpu" in P else "") + " |")
    elif _err(P):
        w(f"| 2 | whole-log processing | error: {P['error']} | | |")
    if PL and not _err(PL):
        cg = PL.get("callgrind", {})
        w(f"| 3 | platform step (6 legs + supervisor) / one leg step: {PL['mode']} | "
          f"{_f(PL['platform']['ns_per_sample_cpu'])} / {_f(PL['leg']['ns_per_sample_cpu'])} ns "
          f"= **{PL['ratio_cpu']:.2f}x** (instructions "
          f"{cg.get('ratio', float('nan')):.2f}x) | <= 6.5x | "
          f"{_ok(PL['ratio_cpu'], TARGETS['platform_ratio'])} |")
    elif _err(PL):
        w(f"| 3 | platform | error: {PL['error']} | | |")
    if B and not _err(B):
        w(f"| 4 | `fdigen build`, cold (empty FDIGEN_CACHE, fresh --out, --force; median of "
          f"{len(B['cold_all'])}) | **{B['cold_s']:.1f} s** wall | <= 3 s | "
          f"{_ok(B['cold_s'], TARGETS['cold_build_s'])} |")
        w(f"| 4 | `fdigen build`, unchanged | **{B['unchanged_s']:.2f} s** wall (Python start "
          f"+ CLI import alone {B['python_start_and_cli_import_s']:.2f} s) | <= 0.5 s | "
          f"{_ok(B['unchanged_s'], TARGETS['unchanged_build_s'])} |")
    elif _err(B):
        w(f"| 4 | fdigen build | error: {B['error']} | | |")
    if MC and not _err(MC):
        ip = MC["in_process"]
        w(f"| 5 | Monte Carlo: simulated samples per second per core (simulate + "
          f"CFdi.run, {MC['runs']} runs x {MC['duration_s']:g} s) | "
          f"**{_f(ip['samples_per_cpu_s'])}** per CPU second ({_f(ip['samples_per_s'])} per "
          f"wall second in-process) | - | - |")
        if "speed_up_1_to_2_workers" in MC:
            w(f"| 5 | speed-up 1 -> 2 Dask workers (LocalCluster, processes; wall) | "
              f"**{MC['speed_up_1_to_2_workers']:.2f}x** | (2 cores: <= 2) | - |")
    elif _err(MC):
        w(f"| 5 | Monte Carlo | error: {MC['error']} | | |")
    if M4 and not _err(M4) and "generated_float" in M4:
        g = M4["generated_float"]
        st = g["worst_stack"].get("pneumatic_cylinder_fdi_step", {})
        w(f"| 6 | Cortex-M4F float core `.text` (arm-none-eabi-gcc -Os) | "
          f"**{g['text_bytes']:,} B** (.rodata {g['sections'].get('.rodata', 0):,} B, .data "
          f"{g['sections'].get('.data', 0)}, .bss {g['sections'].get('.bss', 0)}) | <= 8 KiB | "
          f"{_ok(g['text_bytes'], TARGETS['m4_text'])} |")
        w(f"| 6 | worst stack from `_step` (-fstack-usage, call graph) | "
          f"**{st.get('bytes', '-')} B** ({st.get('path', '-')}); caller-owned state "
          f"{g['state_struct_bytes']:,} B | - | - |")
    elif _err(M4) or M4.get("error"):
        w(f"| 6 | Cortex-M4F | error: {M4.get('error')} | | |")
    w("")
    L += analysis(R)
    return "\n".join(L) + "\n"


def analysis(R) -> list[str]:
    L = []
    w = L.append
    H = R.get("hand", {})
    if H and not _err(H):
        g, cg, st, src = H["time_gcc"], H.get("callgrind", {}), H["static"], \
            H["generated_source"]
        core = st.get("pneumatic_cylinder_fdi_core", {})
        step = st.get("pneumatic_cylinder_fdi_step", {})
        hand = st.get("fdi_hand_step", {})
        selfc = cg.get("self_per_sample", {})
        w("## 1. Generated step vs the hand-written limit")
        w("")
        w("`bench/handwritten/fdi_hand.c` computes the same thing as the generated "
          "`pneumatic_cylinder_fdi_step` (same state layout, same outputs, constants from a "
          "header that `run.py` writes from `design.json`), written by hand: parameter-only "
          "subexpressions computed once at init, one division per chamber and RK4 stage, "
          "matrix-vector products over the non-zero entries, RMS over a ring buffer, one "
          "finiteness test for all outputs. Checked on all seven `fdi_*` rig logs: started "
          "from the generated state at every sample the residuals agree to "
          f"{H['equivalence']['worst']['one_step_r']:.1g} of their scale (max |value| or the "
          "threshold) and the RMS to "
          f"{H['equivalence']['worst']['one_step_rms']:.1g}; running free over a whole log "
          "(each on its own state) flags, class and action are identical at every sample and "
          f"the residuals drift apart by at most {H['equivalence']['worst']['free_r']:.1g} "
          "(rounding carried by the filters' recursions).")
        w("")
        miss = g["ratio_cpu"] - 1.0
        verdict = ("meets" if g["ratio_cpu"] <= 1.1 else
                   f"misses the 1.1x target by {100 * (g['ratio_cpu'] / 1.1 - 1):.0f} % "
                   f"(the generated step costs {100 * miss:.0f} % more than the hand-written)")
        w(f"The generated step {verdict}: gcc {g['ratio_cpu']:.2f}x in time"
          + (f", clang {H['time_clang']['ratio_cpu']:.2f}x" if "time_clang" in H else "")
          + (f", {cg['ratio']:.2f}x in instructions" if "ratio" in cg else "") + ". Where "
          "the difference is (gcc -O2 object code and callgrind, per sample):")
        w("")
        w("| | generated `_core` | generated `_step` (wrapper + RMS + isolation) | "
          "hand-written `fdi_hand_step` (everything) |")
        w("|---|---|---|---|")
        if selfc:
            w(f"| instructions executed (callgrind) | "
              f"{_f(selfc.get('pneumatic_cylinder_fdi_core'))} | "
              f"{_f(selfc.get('pneumatic_cylinder_fdi_step'))} | "
              f"{_f(selfc.get('fdi_hand_step'))} |")
        for key, label in (("divsd", "divisions (divsd)"), ("mulsd", "multiplications"),
                           ("addsd_subsd", "additions/subtractions"),
                           ("sqrtsd", "square roots (sqrtsd)"),
                           ("branches", "branch instructions"), ("call", "calls"),
                           ("instructions", "instructions in the function")):
            w(f"| {label} (static) | {core.get(key, '-')} | {step.get(key, '-')} | "
              f"{hand.get(key, '-')} |")
        w("")
        blocks = cg.get("blocks", {})
        if blocks:
            gb, hb = blocks.get("generated", {}), blocks.get("hand", {})
            w("Instructions per sample by block (callgrind, per source line; the drivers are "
              "built with `-g`, which does not change gcc's code):")
            w("")
            w("| block | generated | hand-written | difference |")
            w("|---|---|---|---|")
            labels = [k for k in gb if k != "(other)" and (gb.get(k) or hb.get(k))]
            labels += [k for k in hb if k not in labels and k != "(other)"]
            for k in sorted(labels, key=lambda k: -(gb.get(k, 0) - hb.get(k, 0))):
                w(f"| {k} | {_f(gb.get(k, 0))} | {_f(hb.get(k, 0))} | "
                  f"{gb.get(k, 0) - hb.get(k, 0):+.0f} |")
            w(f"| total | {_f(sum(gb.values()))} | {_f(sum(hb.values()))} | "
              f"{sum(gb.values()) - sum(hb.values()):+.0f} |")
            w("")
        w("What costs, in the generated C (`generated/pneumatic_cylinder/c/"
          "pneumatic_cylinder_fdi.c`):")
        w("")
        nres = len(R.get("residuals", [])) or 10
        dyn = core.get("divsd", 0) + nres * step.get("divsd", 0)
        w(f"* **Divisions: {dyn} per sample against {hand.get('divsd', '-')} in the whole "
          f"hand-written step** ({core.get('divsd', src['divisions'])} in the straight-line "
          f"core, and `_step`'s RMS loop divides each of the {nres} running sums by N where "
          "the hand-written step multiplies by 1/N). Each pressure "
          "derivative of each RK4 stage is printed as two quotients by the chamber volume "
          "(`-A*gamma*Pp*xdot/cse + K*R*Ts*gamma*v/cse`: 16 divisions where 8 suffice), the "
          f"force balance divides by the parameter `M` ({src['/M (division by a parameter)']} "
          "times in the source) instead of multiplying by `A/M`, `Ff/M`, and the voter "
          "divides three times by the weight sum. A double division has 13-15 cycles latency "
          "and issues every 4-5 cycles (a multiplication: 4 and 0.5); they weigh more in "
          "time than in the instruction count.")
        w("* **Outputs, state copy and finiteness tests**: `_core` stores `z_next`, `r`, "
          "`aux` through pointers, `_step` copies `z_next` back into the state, and both "
          f"test `isfinite` on each of the {len(R.get('residuals', [])) + 13} outputs with a "
          "branch each; `_step` also copies the 12 parameters into an array and builds "
          "`mode[2]` on every call, and `_core` (not `static`, 8 pointer arguments, 8 NULL "
          "tests) is not inlined.")
        w("* **Parallel model**: the clamps go through the NaN-propagating `_min`/`_max` "
          f"helpers ({src['max_min_helper_calls']} calls, inlined: a compare and an `isnan` "
          "branch each), the realignment multiplies by `realign_gate` instead of skipping "
          "the correction, and the RK4 sums are printed as four products "
          "(`dt/6*k1 + dt/3*k2 + dt/3*k3 + dt/6*k4`) where two suffice.")
        w("* **R7**: the derivative of `m` is printed expanded, "
          "`A*xd*gamma*pn - A*xd*gamma*pp - A*xd*pn + A*xd*pp` at each stage, where "
          "`(1-gamma)*A*(pp-pn)` is one factor per sample times `xd`.")
        w(f"* **Parameter-only subexpressions recomputed every sample**: `K*R*Ts*gamma` "
          f"({src['K*R*Ts*gamma (parameter-only product, per stage)']} times in the source), "
          f"`A*gamma` ({src['A*gamma (parameter-only product)']}), `A*L`, `A/M`, `Ff/M` "
          "(the compiler shares them inside a call, but cannot move them out of it).")
        w(f"* Not costs with gcc -O2: the {src['pow_calls']} `pow(x, 2)` calls are folded "
          f"into multiplications ({core.get('call', 0)} calls left in the core's object "
          f"code; another compiler or -O0 would call `pow`), and the "
          f"{src['dead R7 stage states computed']} dead R7 stage values are removed as dead "
          "code. The RK4 stage arithmetic and the Kalman products are the same in both.")
        w("")
        v, va = H.get("variant", {}), H.get("variant_all", {})
        if v and "ratio_cpu" in v:
            w("**Checked by experiment** (`bench/build/variant*/`: copies of the generated C "
              "with fixes applied by text substitution, bench only; each gives the generated "
              "core's flags and classes at every sample of the seven logs and its residuals to "
              f"{max(v['free_r_vs_generated'], va.get('free_r_vs_generated', 0)):.1g} of their "
              "scale):")
            w("")
            w("| variant | substitutions | ns per sample (CPU) | / hand-written | "
              "instructions / hand-written | divisions |")
            w("|---|---|---|---|---|---|")
            w(f"| generated as is | - | {_f(g['gen']['ns_per_sample_cpu'])} | "
              f"{g['ratio_cpu']:.2f}x | {cg.get('ratio', float('nan')):.2f}x | "
              f"{core.get('divsd', 0) + step.get('divsd', 0)} |")
            for label, x in (("(1) one division per derivative, (2) parameter quotients once "
                              "per call, `_core` static", v),
                             ("... and (3) factored RK4 sums and R7 derivative, (4) plain "
                              "clamps, (5) one finiteness test", va)):
                if not x or "ratio_cpu" not in x:
                    continue
                subs = ", ".join(f"{k} {n}x" for k, n in x["substitutions"].items())
                w(f"| {label} | {subs} | {_f(x['ns_per_sample_cpu'])} (hand "
                  f"{_f(x['hand_ns_per_sample_cpu'])}) | **{x['ratio_cpu']:.2f}x** | "
                  f"{x.get('instr_ratio', float('nan')):.2f}x | "
                  f"{x['static']['pneumatic_cylinder_fdi_step']['divsd']} |")
            w("Each row's ratio is against the hand-written step timed interleaved in the "
              "same process; the absolute times differ between rows because the shared "
              "machine's speed varied between them.")
            w("")
            if va and "ratio_cpu" in va:
                w(f"All the fixes together take the generated step from {g['ratio_cpu']:.2f}x to "
                  f"{va['ratio_cpu']:.2f}x of the hand-written one. What is left: "
                  f"{va['static']['pneumatic_cylinder_fdi_step']['divsd']} divisions in the "
                  f"code against {hand.get('divsd', '-')} (the voter divides by the weight sum "
                  "instead of multiplying by its reciprocal, `A/M` and `Ff/M` are still "
                  "computed per call rather than at init, the RMS divides by N instead of "
                  "multiplying by 1/N), the copy of the parameters into an array and of "
                  "`z_next` into the state, and the multiplications by `realign_gate`.")
                w("")
        w("What would close it (in the printer, the design program and the templates; "
          "`src/` is not this benchmark's to change): (1) print each state derivative over "
          "one common denominator (`(K*R*Ts*gamma*v - A*gamma*Pp*xdot)/V`); (2) lift "
          "parameter-only assignments (free symbols all parameters) into `_init`, kept in a "
          "derived-parameter struct -- (1) and (2) bring the divisions to the hand-written "
          "count; (3) factor the program's sums before printing (`collect`/`factor_terms` "
          "on the RK4 combinations and R7's derivative); (4) make `_core` `static` behind a "
          "public wrapper, pass the parameter struct instead of a copied array, and test "
          "finiteness once (`acc += x - x` over the outputs, one `isfinite(acc)` at the "
          "end); (5) clamp with plain comparisons (`x < lo ? lo : x > hi ? hi : x` "
          "propagates NaN as well). Changes to the step program are shared by every "
          "backend, so the reference and CasADi stay bit-identical to the C.")
        w("")
        cn = H.get("casadi_native", {})
        if cn and not _err(cn):
            w("")
            w(f"For comparison, the CasADi-generated whole-log function "
              f"(`pneumatic_cylinder_chunk`, 1024 samples per call) called from C with "
              f"preallocated work vectors: **{_f(cn['ns_per_sample_cpu'])} ns per sample** "
              f"(CPU), {_f(cn.get('instr_per_sample'))} instructions per sample "
              f"({cn['ns_per_sample_cpu'] / g['gen']['ns_per_sample_cpu']:.0f}x the fdigen C "
              "core); see item 2.")
        w("")
    P = R.get("python", {})
    if P and not _err(P):
        n = P["samples"]
        g = H.get("time_gcc") if H and not _err(H) else None
        w("## 2. Whole logs from Python")
        w("")
        per = P["cfdi_run_cpu_s"] / n * 1e9
        call = P["cfdi_c_call_only_cpu_s"] / n * 1e9
        w(f"`CFdi.run` costs {per:.0f} ns per sample (CPU) for {n:,} samples; the ctypes call "
          f"alone, into preallocated arrays, {call:.0f} ns"
          + (f", and the step itself in a C loop {g['gen']['ns_per_sample_cpu']:.0f} ns "
             f"(the hand-written limit {g['hand']['ns_per_sample_cpu']:.0f} ns)" if g else "")
          + ". 0.15 s for 1e6 samples means 150 ns per sample"
          + (", below even the hand-written step on this machine: the target cannot be met "
             "by the present computation here, whatever the packaging"
             if g and g["hand"]["ns_per_sample_cpu"] > 150 else "")
          + ". Between the C loop and `CFdi.run` the time goes to writing "
          f"{2 * len(R.get('residuals', [])) + 2} doubles and 3 ints of output per sample "
          "into freshly allocated arrays (page faults on first touch) and, in Python, to "
          "`astype(np.float64)` on every output, which copies arrays that are already "
          f"float64 (about {2 * len(R.get('residuals', [])) * 8 * n / 2**20:.0f} MB for "
          f"{n:,} samples): `astype(..., copy=False)` and an "
          "option to skip unwanted outputs (the C `_run` accepts NULL for any of them) "
          "would remove most of it.")
        if "casadi_run_cpu_s" in P:
            cn = H.get("casadi_native", {}) if H else {}
            w("")
            w(f"`CasadiFdi(compiled=True).run` costs {P['casadi_ns_per_sample_cpu'] / 1000:.1f} "
              f"us per sample (CPU), {P['casadi_run_cpu_s'] / P['cfdi_run_cpu_s']:.0f}x "
              "`CFdi.run`"
              + (f"; the generated CasADi C alone, called from C, "
                 f"{cn['ns_per_sample_cpu'] / 1000:.1f} us and {_f(cn.get('instr_per_sample'))} "
                 "instructions per sample" if cn and not _err(cn) else "")
              + ". The arithmetic is the same as the fdigen C core's ("
              + (f"{_f(H['callgrind']['gen_instr_per_sample'])} instructions per sample"
                 if H and "gen_instr_per_sample" in H.get("callgrind", {}) else "C core")
              + "); "
              "the rest is data movement: the moving-RMS window is a shift register of "
              "N x n_r doubles inside the extended state, and every sample the MX step "
              "shifts it and the nested `mapaccum` copies the whole state"
              + (" (callgrind: " + ", ".join(f"`{k}` {_f(v)}"
                                             for k, v in list(cn["self_per_sample"].items())[:3])
                 + " instructions per sample)" if cn and cn.get("self_per_sample") else "")
              + ". What would fix it: keep the window out of the recursion's state -- carry "
              "only the running sums and a ring index, and keep the buffer in the runner "
              "(or a small C external) -- or let `CasadiFdi.run` delegate whole logs to the "
              "C core, which computes the same numbers bit for bit.")
        w("")
        if "ratio_reference_vs_cfdi_cpu" in P:
            w(f"The per-sample loops: `ReferenceFdi.step` (numpy, lambdified sympy) "
              f"{_f(P['reference_us_per_sample_cpu'])} us per sample, the filterpy peer "
              f"(`bench/peers_filterpy.py`: three `filterpy.kalman.KalmanFilter` objects with "
              f"the design's steady-state gains, numpy for the rest; agrees with the C core "
              f"to {P.get('filterpy_r_max_scaled_diff', float('nan')):.1g} of the residuals' "
              f"scale, flags identical: {P.get('filterpy_flags_identical')}) "
              f"{_f(P.get('filterpy_us_per_sample_cpu'))} us per sample. Against `CFdi.run`: "
              f"{_f(P['ratio_reference_vs_cfdi_cpu'])}x and "
              f"{_f(P.get('ratio_filterpy_vs_cfdi_cpu'))}x"
              + (f"; against `CasadiFdi` only {_f(P.get('ratio_reference_vs_casadi_cpu'))}x "
                 f"and {_f(P.get('ratio_filterpy_vs_casadi_cpu'))}x"
                 if "ratio_reference_vs_casadi_cpu" in P else "")
              + ". The filterpy ratio is the tight one: a lean Python loop costs ~"
              f"{_f(P.get('filterpy_us_per_sample_cpu'))} us, so 300x needs the whole-log "
              f"call under {_f(P.get('filterpy_us_per_sample_cpu', 0) * 1000 / 300)} ns per "
              "sample; the `CFdi.run` overheads above are what separates it from the C "
              "step's own cost.")
        w("")
    PL = R.get("platform", {})
    if PL and not _err(PL):
        cg = PL.get("callgrind", {})
        selfp = cg.get("self_per_sample", {})
        sup = sum(v for k, v in selfp.items() if k.startswith("pneumatic_cylinder_platform"))
        w("## 3. The platform step")
        w("")
        w(f"{PL['mode']}: {_f(PL['platform']['ns_per_sample_cpu'])} ns against "
          f"{_f(PL['leg']['ns_per_sample_cpu'])} ns for one leg (CPU, median of "
          f"{PL['repeats']} interleaved passes; six different healthy trajectories, the "
          f"rig log shifted by K/6 per leg): **{PL['ratio_cpu']:.2f}x**; in instructions "
          f"{cg.get('ratio', float('nan')):.2f}x, of which the supervisor (decisions, "
          f"platform action, safety sequence, output copies) {_f(sup)} instructions per "
          "sample, the rest six unchanged leg steps. The platform adds "
          f"{100 * (PL['ratio_cpu'] / 6 - 1):.0f} % to six legs"
          + (", inside the 6.5x budget." if PL["ratio_cpu"] <= 6.5 else
             ", over the 6.5x budget: the supervisor's per-leg loops would have to shrink.")
          + " Any gain on the leg step (item 1) multiplies by six here.")
        w("")
    B = R.get("build", {})
    if B and not _err(B):
        w("## 4. `fdigen build`")
        w("")
        w(f"Cold: {B['cold_s']:.1f} s (range {B['cold_range'][0]:.1f}-{B['cold_range'][1]:.1f} "
          f"s), target 3 s. Unchanged: {B['unchanged_s']:.2f} s, of which "
          f"{B['python_start_s']:.2f} s start the interpreter and "
          f"{B['python_start_and_cli_import_s'] - B['python_start_s']:.2f} s import "
          "`fdigen.cli` (click and what it imports at module level); the stamp check itself "
          f"is the remaining {max(B['unchanged_s'] - B['python_start_and_cli_import_s'], 0):.2f} "
          "s.")
        w("")
        w(f"Where a cold build goes (cProfile of `fdigen.pipeline.build`, "
          f"{B['profile_total_s']:.0f} s under the profiler against {B['cold_s']:.0f} s "
          "without: the profiler inflates Python-heavy stages such as sympy about 2-3x, not "
          "the compilers):")
        w("")
        w("| stage | cumulative s (profiled) | calls |")
        w("|---|---|---|")
        imp = next((r for r in B["top_cumulative"] if "_find_and_load" in r["function"]), None)
        for row in B["stages"]:
            w(f"| {row['stage']} (`{row['function']}`) | {row['cumulative_s']:.1f} | "
              f"{row['calls']} |")
        if imp:
            w(f"| imports (sympy, scipy, control, casadi, ...) | {imp['cumtime_s']:.1f} | - |")
        w("")
        w("Top entries by cumulative time:")
        w("")
        w("| function | calls | tottime s | cumtime s |")
        w("|---|---|---|---|")
        for r in B["top_cumulative"][:18]:
            w(f"| `{r['function']}` | {r['calls']} | {r['tottime_s']:.2f} | "
              f"{r['cumtime_s']:.2f} |")
        w("")
        w("Top entries by own time:")
        w("")
        w("| function | calls | tottime s |")
        w("|---|---|---|")
        for r in B["top_tottime"][:10]:
            w(f"| `{r['function']}` | {r['calls']} | {r['tottime_s']:.2f} |")
        w("")
        stage = {r["function"]: r for r in B["stages"]}
        w("Suggestions (for `src/`, not changed here):")
        w("")
        w(f"* `build_functions` runs {stage.get('build_functions', {}).get('calls', '?')} "
          "times and `casadi_sources` "
          f"{stage.get('casadi_sources', {}).get('calls', '?')} times per build: "
          "`render_all` renders the CasADi sources and `compile_library(design)` renders "
          "them again; pass the rendered sources (or the functions) through.")
        w(f"* `render_c_sources` runs {stage.get('render_c_sources', {}).get('calls', '?')} "
          "times (double and float) and prints the same program through sympy twice: print "
          "once with the real type as a template variable.")
        w(f"* The CasADi library ({B.get('casadi_c_bytes', 150000) / 1000:.0f} KB of generated C, "
          "a few very long functions) is compiled with `-O2` during the build, serially after the strict compile check; it is only "
          "needed by `CasadiFdi(compiled=True)`: compile it lazily on first use, or in "
          "parallel with the strict checks (two cores), or at `-O1`.")
        w("* `fdi_design` is the symbolic derivation (sympy): `build` calls it directly; "
          "`cached_design` (already used by detect/verify) would make a build with a fresh "
          "`--out` but a warm design cache a matter of rendering. A truly cold build cannot "
          "reach 3 s while it derives with sympy (the imports alone take "
          + (f"{imp['cumtime_s']:.0f} s profiled" if imp else "seconds") + "); the target is "
          "realistic for a warm design cache.")
        w("* Unchanged build: import nothing but the stamp code before the check "
          "(`rich` and friends lazily), or check the stamp in a console-script shim.")
        w("")
    MC = R.get("mc", {})
    if MC and not _err(MC):
        ip = MC["in_process"]
        w("## 5. Monte Carlo throughput")
        w("")
        sim_share = ip["task_simulate_s"] / max(ip["task_simulate_s"] + ip["task_fdi_s"], 1e-12)
        w(f"One run = `fdigen.sim.plant.simulate` (healthy, own noise seed) + `CFdi.run`. "
          f"In-process, {MC['runs']} runs of {MC['duration_s']:g} s: "
          f"{_f(ip['samples_per_cpu_s'])} simulated samples per CPU second "
          f"({_f(ip['samples_per_s'])} per wall second); the simulation takes "
          f"{100 * sim_share:.1f} % of a run, the FDI core the rest. "
          + (lambda sp: f"Inside one `simulate` call of {sp['samples']:,} samples (profiled, "
             f"{sp['total_s']:.2f} s): building the CasADi `mapaccum` over all K samples "
             f"{sp.get('mapaccum_construction_s', 0):.2f} s "
             f"({100 * sp.get('mapaccum_construction_s', 0) / sp['total_s']:.0f} %), "
             f"evaluating it {sp.get('casadi_evaluation_s', 0):.2f} s "
             f"({100 * sp.get('casadi_evaluation_s', 0) / sp['total_s']:.0f} %); the rest is "
             "sympy-to-CasADi conversion and noise/reference generation. `simulate` rebuilds "
             "the plant functions and a `mapaccum` of length K on every call, and that "
             "construction grows with K: a fixed-length chunk function built once per "
             "(model, effects, substeps, dt) and chained over the run, as `CasadiFdi.run` "
             "does, would leave only the evaluation and multiply the Monte Carlo "
             "throughput accordingly. ")(MC["simulate_profile"])
          + "(`src/fdigen/tune.py` has no throughput function, so this is timed directly; "
          "`bench/tune_throughput.py` measures the tune campaigns themselves.)")
        if "speed_up_1_to_2_workers" in MC:
            d1, d2 = MC["dask_1"], MC["dask_2"]
            w("")
            w(f"Dask `LocalCluster` (worker processes, one thread each, warmed up first): 1 "
              f"worker {d1['wall_s']:.2f} s, 2 workers {d2['wall_s']:.2f} s for the same "
              f"campaign: **{MC['speed_up_1_to_2_workers']:.2f}x**; results identical across "
              f"schedulers: {MC['identical_results']}. With two workers the tasks' wall time "
              f"summed to {d2['task_simulate_s'] + d2['task_fdi_s']:.1f} s for "
              f"{d2['task_cpu_s']:.1f} s of CPU (one worker: "
              f"{d1['task_simulate_s'] + d1['task_fdi_s']:.1f} s for {d1['task_cpu_s']:.1f} s): "
              "each worker got "
              f"{100 * d2['task_cpu_s'] / max(d2['task_simulate_s'] + d2['task_fdi_s'], 1e-9):.0f} "
              "% of a core. The machine has 2 cores shared with other work (load "
              f"{MC['loadavg_before'][0]:.1f} before, {MC['loadavg_after'][0]:.1f} after): "
              "the speed-up is bounded by 2 and falls towards 1 when the other core is busy; "
              "a campaign of few runs also pays the scheduler's per-task latency.")
        w("")
    M4 = R.get("m4", {})
    if M4 and "generated_float" in M4:
        g = M4["generated_float"]
        w("## 6. Cortex-M4F")
        w("")
        w(f"`{M4['flags']}` on `generated/pneumatic_cylinder/c_float/pneumatic_cylinder_fdi.c`: "
          f".text {g['text_bytes']:,} B, .rodata {g['sections'].get('.rodata', 0):,} B "
          f"(names, thresholds, patterns), .data {g['sections'].get('.data', 0)} B, .bss "
          f"{g['sections'].get('.bss', 0)} B. Stack (`-fstack-usage`, worst path over the "
          "call graph of `-fcallgraph-info=su`): "
          + "; ".join(f"`{k}` {v['bytes']} B ({v['path']})" for k, v in g["worst_stack"].items())
          + f". The state struct the caller owns is {g['state_struct_bytes']:,} B (the RMS "
          "window dominates).")
        w("")
    return L


def readme_section(R: dict) -> str:
    """The `## Performance` section of README.md: how to run, machine, table, misses."""
    full = render(R)
    lines = full.splitlines()
    table_start = next(i for i, line in enumerate(lines) if line.startswith("| # |"))
    table_end = next(i for i in range(table_start, len(lines)) if not lines[i].startswith("|"))
    table = lines[table_start:table_end]
    m = R["machine"]
    H, P, PL, B, MC = (R.get(k, {}) for k in ("hand", "python", "platform", "build", "mc"))
    out = ["## Performance", "",
           "```bash",
           "pip install -e '.[bench]'      # filterpy and dask.distributed, for the peers and Monte Carlo",
           "python bench/run.py [--quick]  # writes bench/results.md (table + analysis) and bench/results.json",
           "```", "",
           "Never part of the test suite; `python -m pytest bench/test_smoke.py` runs it with tiny "
           "sizes. Every figure is a median of repeated runs and every ratio is measured in the "
           "same run on the same machine; CPU times are primary because the machine is shared. "
           f"Latest full run ({R['started']}): {m['cpu_model']}"
           f"{' (' + m['cpu_id'] + ')' if m.get('cpu_id') else ''}, {m['cpus']} cores, "
           f"{m.get('ghz')} GHz ({m.get('ghz_source', 'lscpu')}), {m.get('memory_gib')} GiB, "
           f"{m['gcc']}, load average {R['load_before'][0]}-{R['load_after'][0]} during the run.",
           ""] + table + ["", "Misses, in short (the analysis is in `bench/results.md`):", ""]
    if H and "time_gcc" in H:
        g, v = H["time_gcc"], H.get("variant_all", {})
        st = H.get("static", {})
        ndiv = (st.get("pneumatic_cylinder_fdi_core", {}).get("divsd", 0)
                + len(R.get("residuals", [])) * st.get("pneumatic_cylinder_fdi_step", {}).get(
                    "divsd", 0))
        out.append(f"* **Generated vs hand-written C, {g['ratio_cpu']:.2f}x (target 1.1x)**: the "
                   f"generated step divides {ndiv} times per sample where the hand-written "
                   f"step divides {st.get('fdi_hand_step', {}).get('divsd', '?')} "
                   "(two quotients per pressure derivative and RK4 stage, divisions by the "
                   "parameter `M`, by N in the RMS loop), recomputes parameter-only products every sample, prints "
                   "sums expanded (RK4 combinations, R7's derivative), clamps through NaN-aware "
                   "helpers and wraps the core in a non-inlined call with per-output `isfinite` "
                   "branches and copies."
                   + (f" With these fixed on a copy of the generated C (bench only) the ratio "
                      f"is {v['ratio_cpu']:.2f}x; the rest is hoisting the remaining "
                      "parameter quotients into init and reciprocals instead of divisions."
                      if v.get("ratio_cpu") else ""))
    if P and "cfdi_run_cpu_s" in P:
        k = 1e6 / P["samples"]
        out.append(f"* **Whole log of 1e6 samples, `CFdi.run` {P['cfdi_run_cpu_s'] * k:.2f} s "
                   "(target 0.15 s)**: the C step alone costs "
                   + ((f"{H['time_gcc']['gen']['ns_per_sample_cpu']:.0f} ns per sample and the "
                       f"hand-written limit {H['time_gcc']['hand']['ns_per_sample_cpu']:.0f} ns "
                       "in this run, "
                       + ("so 150 ns is out of reach here; "
                          if H["time_gcc"]["hand"]["ns_per_sample_cpu"] > 150 else
                          "so 150 ns per sample needs a step near the hand-written limit and "
                          "almost no overhead around it; "))
                      if H and "time_gcc" in H else "")
                   + "`CFdi.run` adds output allocation and `astype` copies of arrays that "
                   "are already float64.")
        if "casadi_run_cpu_s" in P:
            out.append(f"* **`CasadiFdi` compiled, {P['casadi_run_cpu_s'] * k:.1f} s per 1e6 "
                       "samples**: the moving-RMS window is a shift register inside the "
                       "mapaccum state, so every sample copies thousands of doubles "
                       + (f"({_f(H['casadi_native']['instr_per_sample'])} instructions per "
                          f"sample against {_f(H['callgrind']['gen_instr_per_sample'])} for the "
                          "C core)" if H and "instr_per_sample" in H.get("casadi_native", {})
                          and "gen_instr_per_sample" in H.get("callgrind", {}) else "")
                       + (f"; the per-sample loops are only "
                          f"{P.get('ratio_filterpy_vs_casadi_cpu', float('nan')):.0f}x "
                          f"(filterpy) and {P.get('ratio_reference_vs_casadi_cpu', float('nan')):.0f}x "
                          "(reference) slower than it, not 300x."))
    if PL and "ratio_cpu" in PL and PL["ratio_cpu"] > 6.5:
        out.append(f"* **Platform {PL['ratio_cpu']:.2f}x one leg (target 6.5x)**: six leg steps "
                   "plus the supervisor; any gain on the leg step multiplies by six.")
    if B and "cold_s" in B:
        out.append(f"* **Cold `fdigen build` {B['cold_s']:.0f} s (target 3 s)**: symbolic "
                   "derivation with sympy, the imports of sympy/scipy/control/CasADi, C "
                   "printing twice (double and float), the CasADi sources built twice and "
                   f"their {B.get('casadi_c_bytes', 150000) / 1000:.0f} KB of C compiled with "
                   "-O2 serially. A design cache, lazy CasADi "
                   "compilation and parallel compiles would help; 3 s is realistic only with "
                   "a warm design cache."
                   + (f" Unchanged build {B['unchanged_s']:.2f} s: mostly interpreter start "
                      "and CLI imports." if B.get("unchanged_s") else ""))
    if MC and "speed_up_1_to_2_workers" in MC:
        d2 = MC["dask_2"]
        share = d2["task_cpu_s"] / max(d2["task_simulate_s"] + d2["task_fdi_s"], 1e-9)
        out.append(f"* Monte Carlo: {MC['in_process']['samples_per_cpu_s']:,.0f} simulated samples "
                   f"per CPU second, 1 -> 2 Dask workers {MC['speed_up_1_to_2_workers']:.2f}x "
                   f"(2 cores shared with other work: each worker got {100 * share:.0f} % of a "
                   "core in this run); `simulate` spends most of its time building a CasADi "
                   "`mapaccum` of the run's length on every call; the FDI core is "
                   f"{100 * MC['in_process']['task_fdi_s'] / max(MC['in_process']['task_simulate_s'] + MC['in_process']['task_fdi_s'], 1e-9):.1f} "
                   "% of a run.")
    return "\n".join(out) + "\n"

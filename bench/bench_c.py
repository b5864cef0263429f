"""C-level benchmarks: generated vs hand-written step, the platform bank, the CasADi C
called natively, and the Cortex-M4F build. Used by bench/run.py."""

from __future__ import annotations

import json
import re
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


#: What the hand-written step computes: its residuals (in flag-bit order), the
#: measurement-validity residuals of a design with guards, its FDI state layout and the
#: structure of the extra parallel-model residuals. design_constants() fails, naming what
#: differs, the day the design outgrows it (tests/test_bench_smoke.py is that alarm).
HAND_RESIDUALS = ["R1", "R2", "R3", "R4", "R5", "w1", "w2", "w3", "R6", "R7", "R8", "R9"]
HAND_GUARDS = ["nf_x3", "nf_x2", "nf_pp", "nf_pn"]
HAND_STATES = ["par_Pp", "par_Pn", "par_x", "par_xdot", "R7_m_valve", "R7_xdot",
               "R8_Pp", "R8_x", "R8_xdot", "R9_Pn", "R9_x", "R9_xdot",
               "R4_Pd", "R4_x", "R4_xdot", "R5_Pd", "R5_xdot", "R6_x", "R6_xdot"]
HAND_EXTRAS = {
    "R6": {"equations": ["x", "xdot"], "drivers": {"Pp": "pp", "Pn": "pn"}, "check": "x3"},
    "R7": {"equations": ["m_valve", "xdot"], "drivers": {"Pp": "pp", "Pn": "pn", "x": "x3"},
           "blind_to": "valve"},
    "R8": {"equations": ["Pp", "x", "xdot"], "drivers": {"Pn": "pn"}, "check": "x3"},
    "R9": {"equations": ["Pn", "x", "xdot"], "drivers": {"Pp": "pp"}, "check": "x3"},
}


def _realign_gain(asg: dict, res: str, state: str) -> float:
    """g of the design's ``<res>c_<state> = <res>_<state> + g r_<res> realign_gate``."""
    e = asg[f"{res}c_{state}"]
    syms = {str(s): s for s in e.free_symbols}
    assert set(syms) == {f"{res}_{state}", f"r_{res}", "realign_gate"}, \
        f"{res}c_{state} = {e}: the hand-written step realigns by a constant gain"
    return float(e.subs({syms[f"{res}_{state}"]: 0, syms[f"r_{res}"]: 1,
                         syms["realign_gate"]: 1}))


def design_constants(design) -> dict:
    """Every constant of the hand-written step (and of the filterpy peer): gains and
    matrices from design.json, the R7 gain, voter tolerance and validity bounds from the
    design object. Checks the structural assumptions the hand-written code makes (which
    entries are 0 or 1); a design that breaks them fails here, loudly."""
    desc = json.loads((GENERATED / "design.json").read_text())
    kal = {k["residual"]: k for k in desc["kalman"]}
    iso = desc["isolation"]
    names = desc["residuals"]
    guards = names == HAND_RESIDUALS + HAND_GUARDS
    assert names == HAND_RESIDUALS or guards, \
        f"the design outgrew the hand-written step: residuals {names}, the hand-written " \
        f"step knows {HAND_RESIDUALS} (+ {HAND_GUARDS}); extend bench/handwritten/ " \
        f"(new: {[n for n in names if n not in HAND_RESIDUALS + HAND_GUARDS]}, " \
        f"gone: {[n for n in HAND_RESIDUALS if n not in names]})"
    assert list(design.state_names) == HAND_STATES, \
        f"the design outgrew the hand-written step: FDI state {list(design.state_names)}, " \
        f"the hand-written step's layout is {HAND_STATES}"
    from fdigen.model.model_file import model_hash
    assert desc["model_hash"] == model_hash(design.model), \
        "generated/ was not built from the current model (model hash differs): run " \
        "`fdigen build` first"
    assert tuple(names) == tuple(design.residual_names), \
        "generated/ and the current design differ: run `fdigen build` first"
    assert desc["sample_time"] == design.config.sample_time and design.config.substeps == 1
    extras = {e["residual"]: e for e in desc["extra_residuals"]}
    for res, want in HAND_EXTRAS.items():
        got = {k: extras.get(res, {}).get(k) for k in want}
        assert got == want, f"the design outgrew the hand-written step: {res} is {got}, " \
            f"the hand-written step computes {want}"
    c = {"model_hash": desc["model_hash"], "names": names, "guards": guards,
         "window": iso["window"], "confirm": iso["confirm"], "dt": desc["sample_time"],
         "realign": np.array(desc["realignment_gain"], dtype=float)}
    asg = {str(s): e for s, e in design.step.assignments}
    c["R7_gain"] = _realign_gain(asg, "R7", "m_valve")
    # R8, R9: reduced parallel models realigned on x3 with one gain per state
    c["R8_gain"] = [_realign_gain(asg, "R8", s) for s in ("Pp", "x", "xdot")]
    c["R9_gain"] = [_realign_gain(asg, "R9", s) for s in ("Pn", "x", "xdot")]
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
    c["sched"] = schedule_constants(design, desc, kal, c)
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
    # the evaluation's parts the hand-written step computes (NaN-safe RMS, frozen horizon,
    # class-level flags, consistent faults): a new field is a new part, so it fails here
    known = {"residuals", "window", "thresholds", "confirm", "classes", "actions",
             "patterns", "action_codes", "fault_names", "fault_masks", "class_flags",
             "sq_max", "horizons"}
    import dataclasses
    fields = {f.name for f in dataclasses.fields(ev)}
    assert fields == known, "the design outgrew the hand-written step: the evaluation " \
        f"has {sorted(fields - known)} the hand-written step does not compute" \
        + (f" (and lost {sorted(known - fields)})" if known - fields else "")
    c["sq_max"] = float(ev.sq_max)
    c["horizons"] = [int(h) for h in ev.horizons]
    c["class_flags"] = int(ev.class_flags) & ((1 << len(names)) - 1)
    c["fault_masks"] = [int(m) for m in ev.fault_masks]
    c["parameters"] = [float(q.value) for q in design.model.parameters]
    return c


def _exact(x):
    from fractions import Fraction
    return Fraction(float(x))


def schedule_constants(design, desc: dict, kal: dict, c: dict) -> dict | None:
    """Constants of the scheduled predictions of R4 and R5 (``schedule = "measured"``).

    The reduced Jacobians of both filters have one state-dependent entry each (checked
    against ``A_reduced_symbolic``, ``B_reduced_symbolic`` of design.json):

    * ``a = dPd'/dxdot = -A gamma (Pp/Vp + Pn/Vn)`` (R4: entry 0,2; R5: 0,1),
    * ``b = dPd'/dv = K R Ts gamma (1/Vp + 1/Vn) = K R Ts gamma (A L + 2 V0)/(Vp Vn)``,

    with ``Vp = A x + V0``, ``Vn = A (L - x) + V0``, evaluated at the clamped voted
    position and either the clamped measured pressures or the operating point's (per
    filter: which ``sched_*`` signals the design's program reads, e.g. R4 only the voted
    position, so that scheduling adds no pressure-sensor fault to its signature). The
    hand-written formulas are checked numerically against the design's program here.
    With ``E`` the unit matrix of the scheduled entry, the design's prediction matrices
    (:func:`fdigen.design.scheduled_prediction.scheduled_transition`)

        A_d(s) = A_d0 + h (A_r(s) - A_r0) + h^2/2 (A_r(s)^2 - A_r0^2)
               = A_d0 + (a - a0) (h E + h^2/2 (A_r0 E + E A_r0))        (E^2 = 0),
        B_d(s) = B_d0 + (b - b0) (h e_0 + h^2/2 A_r0 e_0)               (E B_r0 = 0),

    are affine in ``a`` and ``b``: entry = ``C + G a`` (or ``C + H b``), ``C`` folded once
    here (exact rational arithmetic on the design's doubles, rounded once). R5's reduced
    model is R4's without ``x`` (asserted), so both filters share ``C``, ``G``, ``H`` and
    ``b``, and every scheduled entry shares one division, ``1/(Vp Vn)``. ``None`` when
    neither filter is scheduled."""
    import sympy as sp

    specs = {k.residual: getattr(k, "schedule", "operating_point")
             for k in design.config.kalman}
    sched = {r: specs.get(r) == "measured" for r in ("R4", "R5", "R6")}
    assert not sched["R6"], "the hand-written step does not schedule R6"
    assert sched["R4"] == sched["R5"], \
        "the hand-written step schedules R4 and R5 together or neither"
    if not sched["R4"]:
        return None
    asg = {str(s): e for s, e in design.step.assignments}
    # the design divides once per distinct denominator (sched_inv<k> = 1/den): expand
    # those reciprocals so the entries below read in the scheduled signals only
    inv = {s: e for s, e in design.step.assignments if str(s).startswith("sched_inv")}
    asg = {n: e.xreplace(inv) if n.startswith(("R4_", "R5_")) else e for n, e in asg.items()}
    # R5's valve-gain entry and its B_d equal R4's: the design computes them once (R4's)
    expect = {"R4_Ar02", "R4_Br00", "R5_Ar01",
              "R4_Ad00", "R4_Ad02", "R4_Ad22", "R4_Bd00", "R4_Bd20",
              "R5_Ad00", "R5_Ad01", "R5_Ad11"}
    got = {n for n in asg if re.match(r"R[456]_(Ar|Br|Ad|Bd)\d\d$", n)}
    assert got == expect, f"scheduled entries of the design {sorted(got)}: the " \
        f"hand-written step computes {sorted(expect)}"
    st = {s.name: s for s in design.model.states}
    assert [tuple(map(str, st[n].limits)) for n in ("Pp", "Pn", "x")] == \
        [("Patm", "Psup"), ("Patm", "Psup"), ("0.0", "L")], "state limits changed"
    sig = {"sched_Pp": ("pp", "Patm", "Psup"), "sched_Pn": ("pn", "Patm", "Psup"),
           "sched_x": ("voter_out", "0.0", "L")}
    for name, (v, lo, hi) in sig.items():    # min(hi, max(lo, v)), as the hand-written
        if name in asg:
            assert str(asg[name]) == f"Min({hi}, Max({lo}, {v}))", (name, asg[name])
    op = desc["operating_point"]   # A_d (z+ - z0) + B_d (u - u0): only x0 != 0, column e1
    assert op["Pp"] == op["Pn"] and op["xdot"] == 0 and op["v"] == 0, op
    # the physics the hand-written step uses, against the design's symbolic Jacobian
    Patm, Psup, L = (sp.Symbol(n) for n in ("Patm", "Psup", "L"))
    A, g, K, R, Ts, V0, Pp, Pn, x = sp.symbols("A gamma K R Ts V0 Pp Pn x")
    Vp, Vn = A * x + V0, A * (L - x) + V0
    a_s = -A * g * (Pp / Vp + Pn / Vn)
    b_s = K * R * Ts * g * (A * L + 2 * V0) / (Vp * Vn)
    loc = {str(v): v for v in (A, g, K, R, Ts, V0, Pp, Pn, x, L)}
    for res, (i, j), n in (("R4", (0, 2), 3), ("R5", (0, 1), 2)):
        As = [[sp.sympify(e, locals=loc) for e in row] for row in kal[res]["A_reduced_symbolic"]]
        Bs = [[sp.sympify(e, locals=loc) for e in row] for row in kal[res]["B_reduced_symbolic"]]
        states = {Pp, Pn, x, sp.Symbol("xdot")}
        dep = [(r, q) for r in range(n) for q in range(n) if As[r][q].free_symbols & states]
        assert dep == [(i, j)], f"{res}: state-dependent A_r entries {dep}"
        assert sp.simplify(As[i][j] - a_s) == 0, f"{res}: A_r[{i},{j}] = {As[i][j]}"
        depb = [r for r in range(n) if Bs[r][0].free_symbols & states]
        assert depb == [0] and sp.simplify(Bs[0][0] - b_s) == 0, f"{res}: B_r = {Bs}"
    # which measured signals each filter's schedule reads, and the formulas in floats
    par = {q.name: float(q.value) for q in design.model.parameters}
    pv = {A: par["A"], g: par["gamma"], K: par["K"], R: par["R"], Ts: par["Ts"],
          V0: par["V0"], L: par["L"]}
    measured = {}
    for res, an in (("R4", "R4_Ar02"), ("R5", "R5_Ar01")):
        fa = {str(q) for q in asg[an].free_symbols}
        fb = {str(q) for q in asg["R4_Br00"].free_symbols}
        assert fa in ({"sched_x"}, {"sched_x", "sched_Pp", "sched_Pn"}) and \
            fb == {"sched_x"}, f"{res} scheduled on {sorted(fa)}, {sorted(fb)}: the " \
            "hand-written step knows the voted position, with or without the pressures"
        measured[res] = "sched_Pp" in fa
        for xs, pps, pns in ((0.0, 2.0e5, 4.5e5), (0.031, 6.0e5, 1.01325e5),
                             (0.1, 3.5e5, 3.5e5), (0.2, 1.2e5, 5.5e5)):
            at = {sp.Symbol("sched_x", real=True): xs, sp.Symbol("sched_Pp", real=True): pps,
                  sp.Symbol("sched_Pn", real=True): pns}
            at = {q: at[sp.Symbol(str(q), real=True)] for q in asg[an].free_symbols}
            pe = (pps, pns) if measured[res] else (op["Pp"], op["Pn"])
            want_a = float(a_s.subs(pv).subs({x: xs, Pp: pe[0], Pn: pe[1]}))
            want_b = float(b_s.subs(pv).subs({x: xs}))
            got_a = float(asg[an].xreplace(at))
            got_b = float(asg["R4_Br00"].xreplace(
                {q: xs for q in asg["R4_Br00"].free_symbols}))
            assert abs(got_a - want_a) <= 1e-12 * abs(want_a), (res, xs, got_a, want_a)
            assert abs(got_b - want_b) <= 1e-12 * abs(want_b), (res, xs, got_b, want_b)
    h = _exact(desc["sample_time"])
    A0 = [[_exact(v) for v in row] for row in kal["R4"]["A_reduced"]]
    B0 = [_exact(row[0]) for row in kal["R4"]["B_reduced"]]
    Ad0 = [[_exact(v) for v in row] for row in kal["R4"]["A_discrete"]]
    Bd0 = [_exact(row[0]) for row in kal["R4"]["B_discrete"]]
    # R5 = R4 without x (coordinates Pd, xdot): the same numbers, rows/columns 0 and 2
    for key in ("A_reduced", "A_discrete", "B_reduced", "B_discrete"):
        r4 = np.array(kal["R4"][key], dtype=float)
        r5 = np.array(kal["R5"][key], dtype=float)
        sub = r4[np.ix_([0, 2], [0, 2])] if key.startswith("A") else r4[[0, 2]]
        assert np.allclose(sub, r5, rtol=1e-12, atol=0), (key, sub, r5)
    a0, b0 = A0[0][2], B0[0]
    # E = e0 e2^T: A_r0 E has column 2 = A_r0[:, 0]; E A_r0 has row 0 = A_r0[2, :]
    G = [[(h if (r, q) == (0, 2) else 0) + h * h / 2 * ((A0[r][0] if q == 2 else 0)
                                                        + (A0[2][q] if r == 0 else 0))
          for q in range(3)] for r in range(3)]
    Hb = [h * (1 if r == 0 else 0) + h * h / 2 * A0[r][0] for r in range(3)]
    assert B0[2] == 0, "E B_r0 != 0: the hand-written B_d(s) omits that term"
    nzA = {(r, q) for r in range(3) for q in range(3) if G[r][q] != 0}
    assert nzA == {(0, 0), (0, 2), (2, 2)} and G[0][0] == G[2][2], G
    assert {r for r in range(3) if Hb[r] != 0} == {0, 2}, Hb
    lit = float     # rounded once
    return {
        "a0": float(a0), "b0": float(b0), "op_P": float(op["Pp"]),
        "R4_measured_pressures": measured["R4"], "R5_measured_pressures": measured["R5"],
        "A00": lit(Ad0[0][0] - G[0][0] * a0), "A02": lit(Ad0[0][2] - G[0][2] * a0),
        "A22": lit(Ad0[2][2] - G[2][2] * a0), "GA0": lit(G[0][0]), "GA02": lit(G[0][2]),
        "B0": lit(Bd0[0] - Hb[0] * b0), "B2": lit(Bd0[2] - Hb[2] * b0),
        "HB0": lit(Hb[0]), "HB2": lit(Hb[2]),
    }


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
    for res in ("R8", "R9"):
        for i, g in enumerate(c[f"{res}_gain"]):
            lines.append(f"#define FH_{res}_G{i} {_lit(g)}")
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
    sc = c["sched"]
    lines.append(f"#define FH_SCHED {int(sc is not None)}")
    if sc is not None:   # scheduled R4/R5 predictions: entry = C + G a(s) (or + H b(s))
        for k in ("A00", "A02", "A22", "GA0", "GA02", "B0", "B2", "HB0", "HB2"):
            lines.append(f"#define FH_S_{k} {_lit(sc[k])}")
        lines += [f"#define FH_S_OP_P {_lit(sc['op_P'])}",
                  f"#define FH_R4_SCHED_P {int(sc['R4_measured_pressures'])}",
                  f"#define FH_R5_SCHED_P {int(sc['R5_measured_pressures'])}"]
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
              f"#define FH_SQ_MAX {_lit(c['sq_max'])}",
              f"#define FH_CLASS_FLAGS {c['class_flags']}u",
              f"static const int32_t FH_HORIZON[{len(names)}] = "
              f"{{{', '.join(map(str, c['horizons']))}}};",
              f"#define FH_NFAULTS {len(c['fault_masks'])}",
              f"static const uint32_t FH_FAULT_MASK[{len(c['fault_masks'])}] = "
              f"{{{', '.join(f'{m}u' for m in c['fault_masks'])}}};",
              "#endif", ""]
    path.write_text("\n".join(lines))
    return {"R7_gain": c["R7_gain"], "voter_tolerance": c["voter_tolerance"],
            "validity_bounds": c.get("bounds"), "schedule": sc}


# -- 1. generated vs hand-written ---------------------------------------------------------
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
    ("constant-time selects (bit-mask helper)",
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
    ("isolation", "/* isolation"),
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
    """``c ? a : b`` instead of the bit-mask select: gives up the constant-time property
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
    logbin = build / f"{TIMING_LOG}.bin"
    K = write_log_bin(model, TIMING_LOG, logbin)
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
    logbin = build / f"{TIMING_LOG}.bin"
    K = write_log_bin(model, TIMING_LOG, logbin)
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
    from fdigen.backends.casadi_backend.functions import chunk_geometry
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

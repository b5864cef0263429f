"""Constants of the hand-written C step (bench/handwritten/) read from the design:
:func:`design_constants` (which also checks, loudly, that the design still computes what
the hand-written step computes) and :func:`write_gains_header` (``fdi_hand_gains.h``).
Used by bench_c.py, run.py and the filterpy peer."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

import common
from hand_schedule import schedule_constants


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
    # an invalid sample is replaced by a state of a parallel model (dedicated realignment:
    # the position by the main model's, each pressure by its own parity model's)
    fallback = {k: str(step[k][1]) for k in ("x3", "x2", "pp", "pn")}
    assert fallback == {"x3": "par_x", "x2": "par_x", "pp": "par_R2_Pp",
                        "pn": "par_R3_Pn"}, f"substitutes of invalid samples {fallback}: " \
        "the hand-written step replaces x3, x2 by par_x, pp by par_R2_Pp, pn by par_R3_Pn"
    assert float(init["pp"][1]) == float(init["pn"][1])
    assert float(init["x3"][1]) == float(init["x2"][1])
    return {"v": step["v"][0], "v_fallback": float(step["v"][1]), "x": step["x3"][0],
            "p": step["pp"][0], "x_init": float(init["x3"][1]), "p_init": float(init["pp"][1])}


#: What the hand-written step computes: its residuals (in flag-bit order), the
#: measurement-validity residuals of a design with guards, its FDI state layout and the
#: structure of the extra parallel-model residuals. design_constants() fails, naming what
#: differs, the day the design outgrows it (tests/test_bench_smoke.py is that alarm).
HAND_RESIDUALS = ["R1", "R2", "R3", "R4", "R5", "w1", "w2", "w3", "R6", "R7", "R8", "R9"]
HAND_GUARDS = ["nf_x3", "nf_x2", "nf_pp", "nf_pn"]
HAND_STATES = ["par_Pp", "par_Pn", "par_x", "par_xdot",
               "par_R2_Pp", "par_R2_Pn", "par_R2_x", "par_R2_xdot",
               "par_R3_Pp", "par_R3_Pn", "par_R3_x", "par_R3_xdot", "R7_m_valve", "R7_xdot",
               "R8_Pp", "R8_x", "R8_xdot", "R9_Pn", "R9_x", "R9_xdot",
               "R4_Pd", "R4_x", "R4_xdot", "R5_Pd", "R5_xdot", "R6_x", "R6_xdot"]
HAND_EXTRAS = {
    "R6": {"equations": ["x", "xdot"], "drivers": {"Pp": "pp", "Pn": "pn"}, "check": "x3"},
    "R7": {"equations": ["m_valve", "xdot"], "drivers": {"Pp": "pp", "Pn": "pn", "x": "x3"},
           "blind_to": "valve"},
    "R8": {"equations": ["Pp", "x", "xdot"], "drivers": {"Pn": "pn"}, "check": "x3"},
    "R9": {"equations": ["Pn", "x", "xdot"], "drivers": {"Pp": "pp"}, "check": "x3"},
}


def _realign_gain(asg: dict, res: str, state: str, residual: str | None = None) -> float:
    """g of the design's ``<res>c_<state> = <res>_<state> + g r_<residual> realign_gate``
    (``residual`` defaults to ``res``)."""
    residual = residual or res
    e = asg[f"{res}c_{state}"]
    syms = {str(s): s for s in e.free_symbols}
    assert set(syms) == {f"{res}_{state}", f"r_{residual}", "realign_gate"}, \
        f"{res}c_{state} = {e}: the hand-written step realigns by a constant gain on " \
        f"r_{residual}"
    return float(e.subs({syms[f"{res}_{state}"]: 0, syms[f"r_{residual}"]: 1,
                         syms["realign_gate"]: 1}))


#: Dedicated parity realignment: the parallel model of each parity residual, the states
#: it realigns on that residual alone (the others are not corrected).
PARITY_MODELS = {"R1": ("par", ("Pp", "Pn", "x", "xdot")),
                 "R2": ("par_R2", ("Pp", "Pn", "xdot")),
                 "R3": ("par_R3", ("Pp", "Pn", "xdot"))}


def _parity_gains(asg: dict) -> dict:
    """Realignment gains of the three parity models, in the order of
    :data:`PARITY_MODELS`; fails if the design realigns another state or on another
    residual."""
    out = {}
    for res, (model, states) in PARITY_MODELS.items():
        realigned = sorted(n[len(model) + 2:] for n in asg if n.startswith(f"{model}c_"))
        assert realigned == sorted(states), f"the design outgrew the hand-written step: " \
            f"{model} realigns {realigned}, the hand-written step {sorted(states)}"
        out[res] = [_realign_gain(asg, model, s, res) for s in states]
    return out


def _class_tables(ev) -> dict:
    """Per mask of consistent classes (bit c = class c): the class isolated (the one
    class, else 0), the action candidate (the most severe action, or under the policy
    "wait" only a unanimous one) and the samples it must hold (``confirm``, or the
    ambiguity time when the classes' actions differ). Built once: the step looks them up
    with the mask it computes from the flag word."""
    nc = len(ev.classes)
    iso, acand, need = [], [], []
    for mask in range(1 << nc):
        cls = [k for k in range(nc) if mask >> k & 1]
        codes = [ev.action_codes[k] for k in cls]
        iso.append(cls[0] if len(cls) == 1 else 0)
        amax, amin = max(codes, default=0), min(codes, default=0)
        unanimous = amax == amin
        acand.append(amax if cls and (ev.most_severe or unanimous) else 0)
        need.append(ev.confirm if unanimous else ev.ambiguity_samples)
    return {"class_of_mask": iso, "acand_of_mask": acand, "need_of_mask": need}


_CONSTANTS: dict = {}


def design_constants(design) -> dict:
    """:func:`_design_constants`, computed once per design and generated folder (run.py
    and :func:`write_gains_header` both ask; the schedule's checks take a while)."""
    key = (id(design), str(common.GENERATED))
    if key not in _CONSTANTS:
        _CONSTANTS[key] = (design, _design_constants(design))
    return _CONSTANTS[key][1]


def _design_constants(design) -> dict:
    """Every constant of the hand-written step (and of the filterpy peer): gains and
    matrices from design.json, the R7 gain, voter tolerance and validity bounds from the
    design object. Checks the structural assumptions the hand-written code makes (which
    entries are 0 or 1); a design that breaks them fails here, loudly."""
    desc = json.loads((common.GENERATED / "design.json").read_text())
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
         "window": iso["window"], "confirm": iso["confirm"], "dt": desc["sample_time"]}
    asg = {str(s): e for s, e in design.step.assignments}
    # dedicated parity realignment: par on R1 (every state), par_R2 on R2 and par_R3 on
    # R3 (the pressures and the velocity)
    c["parity_gain"] = _parity_gains(asg)
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
    assert c["sched"] is not None or "sched_x" not in asg
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
             "sq_max", "horizons", "sum_min", "sum_max", "ambiguity", "escalate",
             "ambiguity_confirm", "class_unions", "startup"}
    # the start-up gate ([fdi] startup) is not in the hand-written step: a design with one
    # has outgrown it
    assert ev.startup == 0, "the design outgrew the hand-written step: [fdi] startup"
    fields = {f.name for f in dataclasses.fields(ev)}
    assert fields == known, "the design outgrew the hand-written step: the evaluation " \
        f"has {sorted(fields - known)} the hand-written step does not compute" \
        + (f" (and lost {sorted(known - fields)})" if known - fields else "")
    c["sq_max"] = float(ev.sq_max)
    c["horizons"] = [int(h) for h in ev.horizons]
    c["class_flags"] = int(ev.class_flags) & ((1 << len(names)) - 1)
    c["fault_masks"] = [int(m) for m in ev.fault_masks]
    # state validation: the valid ranges of a running sum and a ring-buffer entry
    c["sum_min"], c["sum_max"] = float(ev.sum_min), float(ev.sum_max)
    # the action policy under ambiguity and the contradiction after isolation
    assert ev.ambiguity in ("most_severe", "wait"), ev.ambiguity
    assert len(ev.classes) <= 8 and ev.unexplained == len(ev.classes) - 1
    c["most_severe"], c["escalate"] = int(ev.most_severe), int(ev.escalate)
    c["ambiguity_samples"] = int(ev.ambiguity_samples)
    c["class_unions"] = [int(m) for m in ev.class_unions]
    c.update(_class_tables(ev))
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
    for res, (_, states) in PARITY_MODELS.items():   # FH_R1_G_Pp, ..., FH_R3_G_xdot
        for s, g in zip(states, c["parity_gain"][res]):
            lines.append(f"#define FH_{res}_G_{s} {_lit(g)}")
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
              f"#define FH_HORIZON_MASK "
              f"{sum(1 << i for i, h in enumerate(c['horizons']) if h < 2 ** 31 - 1)}u",
              f"#define FH_SUM_MIN {_lit(c['sum_min'])}",
              f"#define FH_SUM_MAX {_lit(c['sum_max'])}",
              f"#define FH_ALL_FLAGS {(1 << len(names)) - 1}u",
              f"#define FH_NCLASSES {len(c['class_unions'])}",
              f"#define FH_ESCALATE {c['escalate']}",
              f"static const uint32_t FH_CLASS_UNION[{len(c['class_unions'])}] = "
              f"{{{', '.join(f'{m}u' for m in c['class_unions'])}}};",
              f"static const uint8_t FH_CLASS_OF_MASK[{len(c['class_of_mask'])}] = "
              f"{{{', '.join(map(str, c['class_of_mask']))}}};",
              f"static const uint8_t FH_ACAND_OF_MASK[{len(c['acand_of_mask'])}] = "
              f"{{{', '.join(map(str, c['acand_of_mask']))}}};",
              f"static const int32_t FH_NEED_OF_MASK[{len(c['need_of_mask'])}] = "
              f"{{{', '.join(map(str, c['need_of_mask']))}}};",
              f"#define FH_NFAULTS {len(c['fault_masks'])}",
              f"static const uint32_t FH_FAULT_MASK[{len(c['fault_masks'])}] = "
              f"{{{', '.join(f'{m}u' for m in c['fault_masks'])}}};",
              "#endif", ""]
    path.write_text("\n".join(lines))
    return {"parity_gain": c["parity_gain"], "R7_gain": c["R7_gain"],
            "R8_gain": c["R8_gain"], "R9_gain": c["R9_gain"],
            "voter_tolerance": c["voter_tolerance"],
            "validity_bounds": c.get("bounds"), "schedule": sc}

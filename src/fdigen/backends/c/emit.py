"""Render the standalone C sources of an FDI design (header, core, example, Makefile)."""

from __future__ import annotations

import re

import numpy as np
import sympy as sp

from fdigen.backends.c.config import CBackendConfig
from fdigen.backends.c.printer import FdiCPrinter, PrintedProgram, print_program
from fdigen.backends.escape import c_string, comment_text
from fdigen.backends.render import render
from fdigen.design.config import ACTIONS
from fdigen.design.evaluation import HORIZON_NONE, MAX_RESIDUALS, square_limit, sum_limits
from fdigen.design.fdi_design import FdiDesign

#: Argument names of the generated core and init functions (model symbols avoid them).
CORE_ARGS = ("z", "u", "y", "p", "mode", "z_next", "r", "aux", "z0", "i", "status",
             "params", "check")
#: Up to this many fault classes (with "none"), isolation is a lookup in a table of
#: 2**classes bytes; beyond, a loop over the patterns.
MAX_TABLE_CLASSES = 8


def _comment(text: str) -> str:
    """Text safe inside a C block comment, on one line (:func:`fdigen.backends.escape.
    comment_text`)."""
    return comment_text(text, "/*")


def _c_string(text: str) -> str:
    """A C string literal (:func:`fdigen.backends.escape.c_string`)."""
    return c_string(text)


def _statements(prog: PrintedProgram, real: str, fields: list[str]) -> list[str]:
    """C statements reading a program's inputs and evaluating its locals.

    The parameter vector ``p`` is read from the fields of the caller's parameter struct
    (``params->A``, no copy into an array); every other input vector is an array argument.
    """
    def source(vec, i):
        return f"params->{fields[i]}" if vec == "p" else f"{vec}[{i}]"

    lines = [f"const {real} {name} = {source(vec, i)};"
             for vec, elems in prog.inputs.items() for i, name in elems]
    lines += [f"(void){'params' if vec == 'p' else vec};" for vec in prog.unused_inputs]
    lines += [f"const {real} {name} = {expr};" for name, expr in prog.locals]
    lines += [f"(void){name};" for name in prog.unused_locals]
    return lines


def _balanced_check(exprs: list[str], prefix: str) -> str:
    """``zero(e0) + zero(e1) + ...`` (``zero(x) = x - x``) summed as a balanced tree: 0
    when every ``e`` is finite, NaN otherwise, with a dependency chain of log2(n)
    additions. Numeric literals are finite and left out."""
    terms = [f"{prefix}_zero({e})" for e in exprs
             if not re.fullmatch(r"-?[0-9.]+(e-?[0-9]+)?f?", e)] or ["0"]
    while len(terms) > 1:
        terms = [f"({terms[i]} + {terms[i + 1]})" if i + 1 < len(terms) else terms[i]
                 for i in range(0, len(terms), 2)]
    text = terms[0]
    return text[1:-1] if text.startswith("(") and text.endswith(")") and \
        not text.startswith(f"{prefix}_zero") else text


def _not_nan(design: FdiDesign) -> set:
    """The parameters (checked finite by ``init``) and the step's parameter-only
    assignments: symbols that are never NaN."""
    known = set(design.model.p)
    for sym, expr in design.step.assignments:
        if expr.free_symbols <= known and not expr.atoms(sp.Function, sp.Piecewise):
            known.add(sym)
    return known


def check_float_range(model) -> None:
    """Refuse (:class:`~fdigen.errors.ModelFileError`, naming the parameter) a parameter
    whose value or bound is beyond the range of a C ``float`` (about 3.4e38) or below its
    smallest normal number (1.2e-38, which it would read as 0 or a subnormal: a bound of
    1e-50 became ``>= 0.0f`` and let ``J = 0`` through, attack round 4), and such a
    threshold: the float variant of the core holds every parameter (a value of 1e39
    ended the build in an internal error: attack round 2)."""
    from fdigen.errors import ModelFileError

    limit = float(np.finfo(np.float32).max)
    tiny = float(np.finfo(np.float32).tiny)

    def check(v, field, symbol):
        v = abs(float(v))
        if v > limit or 0.0 < v < tiny:
            raise ModelFileError(
                f"{float(v):g} is {'beyond' if v > limit else 'below'} the range of a C "
                f"float ({limit if v > limit else tiny:.4g}): the float variant of the "
                "generated core cannot hold it (" + ("it would read 0 or lose its digits: "
                if v < tiny else "") + "rescale the unit)", source=model.source,
                field=field, symbol=symbol)

    for q in model.parameters:
        for what, v in (("value", q.value), *(("bounds", b) for b in (q.bounds or ()))):
            check(v, f"parameters.{q.name}.{what}", q.name)
    # a threshold of 5e-324 was printed 0.0f (security round 4): the flag then rises on
    # any residual, where the file says it never should below that value
    for name, v in dict(model.fdi.get("thresholds", {})).items():
        if isinstance(v, (int, float)):
            check(v, f"fdi.thresholds.{name}", name)
    # the equations' own constants and terms (attack round 8: `1e-300*Vnom**(20*Vnom)`
    # printed `0.0f*powf(...)`, and powf overflowed: the float core read NaN on a healthy
    # log while the double core was quiet)
    from fdigen.model.sanity import check_terms_in_range, equation_terms

    values = {q.symbol: sp.Float(q.value, 17) for q in model.parameters}
    values.update({v.symbol: sp.Float(model.operating_point[v.name], 17)
                   for v in (*model.states, *model.inputs) if v.name in model.operating_point})
    values.update({f.symbol: sp.Integer(0) for f in model.faults})
    for field, expr in equation_terms(model):
        for c in sp.sympify(expr).atoms(sp.Float):
            check(c, field, None)
        check_terms_in_range(model, expr, values, field, limit,
                             "a C float, in which the float variant computes it")


def c_context(design: FdiDesign, float_type: str = "double") -> dict:
    """The template context of the C backend (everything already printed as C text).

    Parameters
    ----------
    design : FdiDesign
    float_type : {"double", "float"}

    Returns
    -------
    dict
    """
    model, ev = design.model, design.evaluation
    n_res = len(ev.residuals)
    if not 1 <= n_res <= MAX_RESIDUALS:
        raise ValueError(f"the C backend supports 1..{MAX_RESIDUALS} residuals, got {n_res}")
    if not design.state_names:
        raise ValueError("the C backend needs an FDI state (no state in the design)")
    if float_type == "float":
        check_float_range(model)
    prefix = f"{model.name}_fdi"
    pr = FdiCPrinter(float_type, reserved=CORE_ARGS + (f"{model.name}_real",),
                     helper_prefix=prefix, not_nan=_not_nan(design))
    macro = prefix.upper()
    sizes = {"z": len(design.state_names), "u": len(model.inputs), "y": len(model.outputs),
             "p": len(model.parameters), "r": n_res, "aux": len(design.aux_names)}
    dim = {k: f"{macro}_N{k.upper()}" if n else "1" for k, n in sizes.items()}
    params = []
    for q in model.parameters:
        params.append({"field": pr.name(q.symbol), "name": q.name, "unit": _comment(q.unit),
                       "description": _comment(q.description), "default": pr.literal(q.value),
                       "bounds": None if q.bounds is None else
                       (pr.literal(q.bounds[0]), pr.literal(q.bounds[1])),
                       "range": "" if q.bounds is None else
                       f", in [{float(q.bounds[0])!r}, {float(q.bounds[1])!r}]"})
    real = f"{model.name}_real"
    fields = [q["field"] for q in params]
    core = print_program(design.step, pr, ("z_next", "r", "aux"))
    init = print_program(design.init, pr, ("z0",))
    columns = {"inputs": [(i, _comment(v.column or v.name)) for i, v in enumerate(model.inputs)],
               "outputs": [(i, _comment(o.column or o.name))
                           for i, o in enumerate(model.outputs)]}
    return {
        "prefix": prefix, "macro": macro, "real": real, "float_type": float_type,
        "header": f"{prefix}.h", "sizes": sizes, "dim": dim,
        "window": ev.window, "inv_window": pr.literal(1.0 / ev.window),
        "sq_max": pr.literal(square_limit(ev.window, np.float32 if float_type == "float"
                                          else np.float64)),
        **dict(zip(("sum_min", "sum_max"), (pr.literal(v) for v in sum_limits(
            ev.window, np.float32 if float_type == "float" else np.float64)))),
        "all_flags": (1 << n_res) - 1,
        "confirm": ev.confirm, "sample_time": pr.literal(
            design.config.sample_time),
        "sqrt": "sqrtf" if float_type == "float" else "sqrt",
        "params": params,
        "state_names": [_comment(n) for n in design.state_names],
        "aux_names": [_comment(n) for n in design.aux_names],
        "residuals": [_comment(n) for n in ev.residuals],
        "strings": {"residuals": [_c_string(n) for n in ev.residuals],
                    "classes": [_c_string(n) for n in ev.classes],
                    "faults": [_c_string(n) for n in ev.fault_names],
                    "actions": [_c_string(n) for n in ACTIONS],
                    "params": [_c_string(q.name) for q in model.parameters],
                    "inputs": [_c_string(c) for _, c in columns["inputs"]],
                    "outputs": [_c_string(c) for _, c in columns["outputs"]]},
        "n_classes": len(ev.classes), "n_actions": len(ACTIONS),
        "action_codes": list(ev.action_codes),
        "class_unions": [int(m) for m in ev.class_unions],
        "most_severe": ev.most_severe, "escalate": int(ev.escalate),
        "ambiguity_samples": int(ev.ambiguity_samples),
        "startup": int(ev.startup),
        "accommodate": ACTIONS.index("accommodate"),
        "thresholds": [pr.literal(t) for t in ev.thresholds],
        # (residual index, horizon) of the residuals with a frozen-residual horizon
        "horizon_bits": [(i, int(h)) for i, h in enumerate(ev.horizons)
                         if int(h) != HORIZON_NONE],
        "patterns": [{"mask": int(m), "cls": int(c)} for m, c in ev.patterns],
        "fault_masks": [int(m) for m in ev.fault_masks],
        "class_flags": int(ev.class_flags) & ((1 << len(ev.residuals)) - 1),
        "fault_names": [_comment(n) for n in ev.fault_names],
        # isolation by table lookup on the mask of consistent classes (up to 8 classes)
        "class_of": ([k.bit_length() - 1 if k and not k & (k - 1) else 0
                      for k in range(1 << len(ev.classes))]
                     if _isolates_by_tables(ev) else []),
        **_action_tables(ev),
        "core_check": _balanced_check(list(core.outputs["z_next"]) + list(core.outputs["r"]),
                                      prefix),
        "init_check": _balanced_check(list(init.outputs["z0"]), prefix),
        "core": core, "core_lines": _statements(core, real, fields),
        "init": init, "init_lines": _statements(init, real, fields),
        "columns": columns, "helpers": sorted(pr.helpers),
    }


def _isolates_by_tables(ev) -> bool:
    """The step isolates by lookup tables indexed by the mask of consistent classes (one
    entry per subset of the classes), when there are patterns and few enough classes."""
    return bool(ev.patterns) and len(ev.classes) <= MAX_TABLE_CLASSES


def _action_tables(ev) -> dict:
    """The most and the least severe action code of the classes of every class mask
    (bit ``c`` set: class ``c`` has a consistent fault), as the step's isolation reads them
    by one lookup: ``max_{c in k} action(c)`` (0 for the empty mask) and
    ``min_{c in k} action(c)`` (the number of actions for the empty mask)."""
    if not _isolates_by_tables(ev):
        return {"action_max_of": [], "action_min_of": []}
    codes = [int(a) for a in ev.action_codes]
    members = [[c for c in range(len(codes)) if k >> c & 1] for k in range(1 << len(codes))]
    return {"action_max_of": [max((codes[c] for c in m), default=0) for m in members],
            "action_min_of": [min((codes[c] for c in m), default=len(ACTIONS))
                              for m in members]}


def render_c_sources(design: FdiDesign, *, float_type: str = "double", model_source: str,
                     model_hash: str) -> dict[str, str]:
    """Render every file of the standalone C FDI library.

    Parameters
    ----------
    design : FdiDesign
    float_type : {"double", "float"}
        The C type of ``<model>_real``.
    model_source : str
        Model file name written into each preamble (a name, not a path).
    model_hash : str
        :func:`fdigen.model.model_file.model_hash` of the model.

    Returns
    -------
    dict of str to str
        File name (``<model>_fdi.h``, ``<model>_fdi.c``, ``main.c``, ``Makefile``) -> text.
    """
    cfg = CBackendConfig(float_type=float_type)
    ctx = c_context(design, float_type)
    return {fname: render(template, comment=comment, model_name=design.name,
                          model_source=model_source, model_hash=model_hash, **ctx)
            for fname, (template, comment) in cfg.files(design.name).items()}

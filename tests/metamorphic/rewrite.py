"""Meaning-preserving rewrites of a model file, as pure functions over its TOML document.

Each rewrite takes the parsed document (``tomllib.loads``) and returns a new one (the input
is never changed) together with what a comparison needs to map the rewritten plant back:
``Twin.output_scale[y] = (gain, offset)`` (the rewritten sensor reads ``gain*y + offset``),
``Twin.names`` (old name -> new name). :func:`dumps` writes a document back to TOML text.

Rewrites: :func:`rename`, :func:`inline_definitions`, :func:`extract_definitions`,
:func:`scale_state` (m <-> cm), :func:`scale_parameter` (Pa <-> bar),
:func:`scale_output` (a sensor in volts through a gain and an offset), :func:`reorder`
(states, outputs, faults, residual tables), :func:`guard_sqrt` / :func:`unguard_sqrt`
(``sqrt(max(x, 0))`` <-> ``sqrt(x)``), :func:`fault_on_equations` (an actuator fault as
terms on every equation its input reaches).
"""

from __future__ import annotations

import copy
import re
from fractions import Fraction
from dataclasses import dataclass, field

#: Keys whose text is not an expression (never rewritten).
_TEXT_KEYS = {"description", "unit", "column", "reference_column", "class", "name",
              "location", "mode", "update", "schedule", "type", "target"}


@dataclass
class Twin:
    """A rewritten document and how to read its results in the original's terms."""

    doc: dict
    names: dict = field(default_factory=dict)          # old -> new (states, faults, ...)
    output_scale: dict = field(default_factory=dict)   # new output name -> (gain, offset)
    input_scale: dict = field(default_factory=dict)    # new input name -> factor

    def then(self, rewrite, *args, **kw) -> "Twin":
        """Apply another rewrite to this twin (names and scales compose)."""
        nxt = rewrite(self.doc, *args, **kw)
        names = {old: nxt.names.get(new, new) for old, new in self.names.items()}
        names.update({k: v for k, v in nxt.names.items() if k not in self.names.values()})
        scale = {nxt.names.get(k, k): v for k, v in self.output_scale.items()}
        for k, (g, o) in nxt.output_scale.items():
            g0, o0 = scale.get(k, (1.0, 0.0))
            scale[k] = (g * g0, g * o0 + o)
        inputs = {nxt.names.get(k, k): v for k, v in self.input_scale.items()}
        for k, g in nxt.input_scale.items():
            inputs[k] = g * inputs.get(k, 1.0)
        return Twin(nxt.doc, names, scale, inputs)


def twin(doc: dict) -> Twin:
    return Twin(copy.deepcopy(doc))


# -- expression text -------------------------------------------------------------------------
def _sub_words(text: str, mapping: dict) -> str:
    if not mapping:
        return text
    pat = re.compile(r"\b(" + "|".join(map(re.escape, sorted(mapping, key=len,
                                                             reverse=True))) + r")\b")
    return pat.sub(lambda m: mapping[m.group(1)], text)


def _map_exprs(node, fn, key=None):
    """Apply ``fn`` to every expression string of the document (not names, units, text)."""
    if isinstance(node, dict):
        return {k: v if k == "residual_keys" else _map_exprs(v, fn, k)
                for k, v in node.items()}
    if isinstance(node, list):
        return [_map_exprs(v, fn, key) for v in node]
    if isinstance(node, str) and key not in _TEXT_KEYS:
        return fn(node)
    return node


def _walk(doc, fn):
    return {k: v if k == "model" else _map_exprs(v, fn, k) for k, v in doc.items()}


def _matching(text: str, start: int) -> int:
    """Index of the parenthesis closing the one at ``start``."""
    depth = 0
    for i in range(start, len(text)):
        depth += {"(": 1, ")": -1}.get(text[i], 0)
        if depth == 0:
            return i
    raise ValueError(f"unbalanced parentheses in {text!r}")


def _num(x: float) -> str:
    """An exact number in expression text: ``100``, ``(1/100)``, ``(1/2)`` (a float such as
    ``0.01`` is inexact, and ``100.0*0.01`` is not 1: an exact cancellation the design
    relies on, a fault decoupled by a combination of two equations, would be lost)."""
    q = Fraction(float(x)).limit_denominator(10 ** 12)
    return str(q.numerator) if q.denominator == 1 else f"({q.numerator}/{q.denominator})"


# -- rewrites --------------------------------------------------------------------------------
def rename(doc: dict, mapping: dict) -> Twin:
    """Rename states, inputs, outputs, parameters, definitions and faults (``old -> new``)
    everywhere: tables' keys, expressions, fault targets, controller inputs."""
    doc = copy.deepcopy(doc)
    out = _walk(doc, lambda t: _sub_words(t, mapping))

    def keys(tab):
        return {mapping.get(k, k): v for k, v in tab.items()}

    for sect in ("parameters", "states", "inputs", "outputs", "definitions", "dynamics",
                 "faults", "operating_point"):
        if sect in out:
            out[sect] = keys(out[sect])
    for f in out.get("faults", {}).values():
        if "target" in f:
            f["target"] = mapping.get(f["target"], f["target"])
        for t in f.get("terms", []):
            t["target"] = mapping.get(t["target"], t["target"])
    fdi = out.get("fdi", {})
    if "process_noise" in fdi:
        fdi["process_noise"] = keys(fdi["process_noise"])
    if "residual_keys" in fdi:     # what each derived residual is, in the new names
        fdi["residual_keys"] = {r: _sub_words(k, mapping)
                                for r, k in fdi["residual_keys"].items()}
    sim = out.get("simulation", {})
    if "initial" in sim:
        sim["initial"] = keys(sim["initial"])
    if "input" in sim:
        sim["input"] = mapping.get(sim["input"], sim["input"])
    for c in sim.get("controllers", {}).values():
        c["input"] = mapping.get(c["input"], c["input"])
    return Twin(out, dict(mapping))


def inline_definitions(doc: dict) -> Twin:
    """Substitute every definition into the expressions using it, and drop it; a
    definition carrying a fault's symbol stays (a fault symbol may not be in [dynamics])."""
    doc = copy.deepcopy(doc)
    defs = dict(doc.get("definitions", {}))
    faults = set(doc.get("faults", {}))
    keep = {}
    inline = {}
    for name, text in defs.items():
        text = _sub_words(text, inline)
        words = set(re.findall(r"[A-Za-z_]\w*", text))
        if words & faults:
            keep[name] = text
        else:
            inline[name] = f"({text})"
    out = _walk({k: v for k, v in doc.items() if k != "definitions"},
                lambda t: _sub_words(t, inline))
    if keep:
        out = {**out, "definitions": {k: v for k, v in keep.items()}}
        out = _reorder_like(out, doc)
    return Twin(out)


def extract_definitions(doc: dict, prefix: str = "rate") -> Twin:
    """Move each state's right-hand side into a definition ``<prefix>_<state>``."""
    doc = copy.deepcopy(doc)
    defs = dict(doc.get("definitions", {}))
    for state, rhs in doc["dynamics"].items():
        defs[f"{prefix}_{state}"] = rhs
    doc["definitions"] = defs
    doc["dynamics"] = {s: f"{prefix}_{s}" for s in doc["dynamics"]}
    return Twin(_reorder_like(doc, {k: None for k in _ORDER}))


def scale_state(doc: dict, state: str, factor: float) -> Twin:
    """The state in another unit, ``x' = factor*x`` (m -> cm: 100): ranges, limits,
    operating point, initial value, process noise and the terms faults add to its
    derivative follow; every expression reads ``x'/factor``."""
    doc = copy.deepcopy(doc)
    c = _num(factor)
    out = _walk(doc, lambda t: _sub_words(t, {state: f"({state}/{c})"}))
    out["dynamics"][state] = f"{c}*({out['dynamics'][state]})"
    var = out["states"][state]
    for key in ("range", "limits"):
        if key in var:
            var[key] = [_scaled(v, factor) for v in var[key]]
    op = out["operating_point"]
    op[state] = _scaled(doc["operating_point"][state], factor)
    _scale_fault_terms(out, state, c)
    pn = out.get("fdi", {}).get("process_noise", {})
    if state in pn:
        pn[state] = pn[state] * abs(factor)
    init = out.get("simulation", {}).get("initial", {})
    if state in init:
        init[state] = _scaled(doc["simulation"]["initial"][state], factor)
    return Twin(out)


def _scale_fault_terms(doc: dict, target: str, c: str):
    """Every fault term on ``target`` times ``c`` (in place)."""
    for f in doc.get("faults", {}).values():
        if f.get("target") == target:
            f["term"] = f"{c}*({f['term']})"
        for t in f.get("terms", []):
            if t["target"] == target:
                t["term"] = f"{c}*({t['term']})"


def _scaled(v, factor):
    if isinstance(v, str):
        return f"{_num(factor)}*({v})"
    return v * factor


def scale_input(doc: dict, name: str, factor: float) -> Twin:
    """An input in another unit, ``u' = factor*u`` (a pump's voltage in percent of its
    range, a flow in l/min): its range, operating point and the terms of faults on it
    follow, every expression reads ``u'/factor``, and the controllers that set it give
    ``factor`` times their law (PI gains, limits and offset scaled)."""
    c = _num(factor)
    out = _walk(copy.deepcopy(doc), lambda t: _sub_words(t, {name: f"({name}/{c})"}))
    var = out["inputs"][name]
    if "range" in var:
        var["range"] = [_scaled(v, factor) for v in doc["inputs"][name]["range"]]
    out["operating_point"][name] = _scaled(doc["operating_point"][name], factor)
    _scale_fault_terms(out, name, c)
    sim, before = out.get("simulation", {}), doc.get("simulation", {})
    if before.get("input") == name:
        sim["input"] = name
        sim["controller"] = f"{c}*({sim['controller']})"
    for key, ctl in sim.get("controllers", {}).items():
        if before["controllers"][key].get("input") != name:
            continue
        ctl["input"] = name
        if "law" in ctl:
            ctl["law"] = f"{c}*({ctl['law']})"
        for key in ("kp", "ki", "kd", "offset"):
            if key in ctl:
                ctl[key] = _scaled(ctl[key], factor)
        if "limits" in ctl:
            ctl["limits"] = [_scaled(v, factor) for v in ctl["limits"]]
    return Twin(out, input_scale={name: factor})


def scale_parameter(doc: dict, name: str, factor: float) -> Twin:
    """A parameter in another unit, ``p' = factor*p`` (Pa -> bar: 1e-5)."""
    doc = copy.deepcopy(doc)
    out = _walk(doc, lambda t: _sub_words(t, {name: f"({name}/{_num(factor)})"}))
    par = out["parameters"][name]
    par["value"] = par["value"] * factor
    if "bounds" in par:
        par["bounds"] = sorted(b * factor for b in par["bounds"])
    return Twin(out)


def scale_output(doc: dict, output: str, gain: float, offset: float = 0.0) -> Twin:
    """The sensor reads ``gain*y + offset`` (a level in volts): its noise and the terms of
    the faults on it follow, controllers and measurement expressions read it back
    through ``(y' - offset)/gain``, the thresholds of residuals on it scale by ``|gain|``
    (those of derived residuals are left to the caller: see ``Twin.output_scale``)."""
    doc = copy.deepcopy(doc)
    g, o = _num(gain), _num(offset)
    back = {output: f"(({output} - {o})/{g})"}
    out = copy.deepcopy(doc)
    spec = out["outputs"][output]
    spec["expr"] = f"{g}*({spec['expr']}) + {o}"
    spec["noise_std"] = spec.get("noise_std", 0.0) * abs(gain)
    _scale_fault_terms(out, output, g)
    sim = out.get("simulation", {})
    if "controller" in sim:
        sim["controller"] = _sub_words(sim["controller"], back)
    for c in sim.get("controllers", {}).values():
        for key in ("measurement", "law"):
            if key in c:
                c[key] = _sub_words(c[key], back)
    fdi = out.get("fdi", {})
    for spec_k in fdi.get("kalman", {}).values():
        if spec_k.get("measurement") == output:
            continue          # the filter's innovation is then in the sensor's unit
        spec_k["measurement"] = _sub_words(spec_k["measurement"], back)
    th = fdi.get("thresholds", {})
    for r, oname in fdi.get("parity", {}).items():
        if oname == output and r in th:
            th[r] = th[r] * abs(gain)
    for r, spec_k in fdi.get("kalman", {}).items():
        if spec_k.get("measurement") == output and r in th:
            th[r] = th[r] * abs(gain)
    return Twin(out, output_scale={output: (gain, offset)})


def reorder(doc: dict) -> Twin:
    """States (with their equations), inputs, outputs, faults, parity and Kalman residuals,
    thresholds and actions in reverse order (definitions keep their dependency order)."""
    out = copy.deepcopy(doc)
    for sect in ("states", "dynamics", "inputs", "outputs", "faults", "parameters"):
        if sect in out:
            out[sect] = dict(reversed(list(out[sect].items())))
    fdi = out.get("fdi", {})
    for sect in ("parity", "kalman", "thresholds", "actions", "process_noise"):
        if sect in fdi and not (sect == "kalman" and "voter" in fdi):
            fdi[sect] = dict(reversed(list(fdi[sect].items())))
    return Twin(out)


def guard_sqrt(doc: dict) -> Twin:
    """``sqrt(a)`` -> ``sqrt(max(a, 0))`` everywhere (same meaning where ``a >= 0``)."""
    return Twin(_walk(copy.deepcopy(doc), _guard))


def _guard(text: str) -> str:
    out, i = [], 0
    while True:
        k = text.find("sqrt(", i)
        if k < 0 or (k > 0 and (text[k - 1].isalnum() or text[k - 1] == "_")):
            if k < 0:
                out.append(text[i:])
                return "".join(out)
            out.append(text[i:k + 5])
            i = k + 5
            continue
        end = _matching(text, k + 4)
        inner = _guard(text[k + 5:end])
        out.append(f"{text[i:k]}sqrt(max({inner}, 0))")
        i = end + 1


def unguard_sqrt(doc: dict) -> Twin:
    """``sqrt(max(a, 0))`` -> ``sqrt(a)`` (and ``max(h, 0)`` of a bare name in a sqrt)."""
    def strip(text):
        while True:
            k = text.find("sqrt(max(")
            if k < 0:
                return text
            end = _matching(text, k + 8)
            inner = text[k + 9:end]
            depth, cut = 0, None
            for j, ch in enumerate(inner):
                depth += {"(": 1, ")": -1}.get(ch, 0)
                if ch == "," and depth == 0:
                    cut = j
            assert cut is not None and inner[cut + 1:].strip() == "0", text
            text = f"{text[:k]}sqrt({inner[:cut]}{text[end + 1:]}"
    return Twin(_walk(copy.deepcopy(doc), strip))


def fault_on_equations(doc: dict, fault: str) -> Twin:
    """An actuator fault on input ``u`` written instead as terms on every state equation
    (and output) ``u`` reaches, definitions inlined:
    ``term_k = f_k(u + term) - f_k(u)``; the same fault, written where it acts."""
    spec = doc["faults"][fault]
    u, term = spec["target"], spec["term"]
    flat = inline_definitions(doc).doc
    terms = []
    for state, rhs in flat["dynamics"].items():
        if re.search(rf"\b{re.escape(u)}\b", rhs):
            moved = _sub_words(rhs, {u: f"({u} + {term})"})
            terms.append({"target": state, "term": f"({moved}) - ({rhs})"})
    for oname, o in flat["outputs"].items():
        if re.search(rf"\b{re.escape(u)}\b", o["expr"]):
            moved = _sub_words(o["expr"], {u: f"({u} + {term})"})
            terms.append({"target": oname, "term": f"({moved}) - ({o['expr']})"})
    out = copy.deepcopy(doc)
    new = {k: v for k, v in spec.items() if k not in ("target", "term", "location")}
    new["terms"] = terms
    out["faults"][fault] = new
    return Twin(out)


def actuator_fault_in_definition(doc: dict, fault: str) -> Twin:
    """An actuator fault on input ``u`` written as the input the plant receives, a
    definition ``<u>_act = <u> + (<term>)`` read wherever ``u`` was, the fault declared
    without target or term (a pump's wear written as ``qin = (1 - wear)*Kp*u``)."""
    spec = doc["faults"][fault]
    u, term = spec["target"], spec["term"]
    name = f"{u}_act"
    out = copy.deepcopy(doc)
    swap = {u: name}
    out["definitions"] = {name: f"{u} + ({term})", **{
        k: _sub_words(v, swap) for k, v in out.get("definitions", {}).items()}}
    out["dynamics"] = {k: _sub_words(v, swap) for k, v in out["dynamics"].items()}
    for o in out["outputs"].values():
        o["expr"] = _sub_words(o["expr"], swap)
    out["faults"][fault] = {k: v for k, v in spec.items() if k not in ("target", "term")}
    return Twin(out)


def sensor_fault_in_map(doc: dict, fault: str) -> Twin:
    """A sensor fault on output ``y`` written inside the sensor's map instead of as a
    term: a definition ``<y>_read = (<expr>) + (<term>)`` that ``y`` reads, the fault
    declared without target or term (a user's gain loss written where it acts)."""
    spec = doc["faults"][fault]
    y, term = spec["target"], spec["term"]
    out = copy.deepcopy(doc)
    name = f"{y}_read"
    out["definitions"] = {**out.get("definitions", {}),
                          name: f"({out['outputs'][y]['expr']}) + ({term})"}
    out["outputs"][y] = {**out["outputs"][y], "expr": name}
    out["faults"][fault] = {k: v for k, v in spec.items() if k not in ("target", "term")}
    return Twin(out)


# -- TOML ---------------------------------------------------------------------------------
_ORDER = ("model", "parameters", "states", "inputs", "definitions", "dynamics", "outputs",
          "faults", "operating_point", "fdi", "simulation")


def _reorder_like(doc, like):
    order = [k for k in _ORDER if k in doc] + [k for k in doc if k not in _ORDER]
    return {k: doc[k] for k in order}


def dumps(doc: dict) -> str:
    """TOML text of a model document (the reliability tests' writer)."""
    from test_reliability_models import dump_toml

    return dump_toml(_reorder_like(doc, None))

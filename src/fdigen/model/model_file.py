"""Read a model file (TOML) into a :class:`~fdigen.model.model.Model`.

Equations are strings parsed by :func:`fdigen.model.expression.parse_expression`, never
evaluated. Every error names the file, the field and the offending symbol.
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from importlib import resources
from pathlib import Path

import sympy as sp

from fdigen.errors import ModelFileError
from fdigen.model.expression import parse_expression
from fdigen.model.numbers import number_problem
from fdigen.model.faults import parse_faults
from fdigen.model.model import Model, Output, Parameter, Variable
from fdigen.model.names import (SYMBOL_KINDS, check_class_name, check_model_name,
                                check_name)
from fdigen.model.sanity import check_controllers, check_physical_sanity
from fdigen.model.size import check_model_size
from fdigen.model.simulation_spec import parse_simulation

BUILTIN_MODELS = ("pneumatic_cylinder", "dc_motor", "three_tank", "heat_exchanger")
#: The values of an input's ``kind``: a command, or a measured disturbance.
INPUT_KINDS = ("actuator", "measured")

#: The tables of a model file and the keys of its [model] table.
TABLES = ("model", "parameters", "states", "inputs", "definitions", "dynamics", "outputs",
          "faults", "operating_point", "fdi", "simulation")
MODEL_KEYS = ("name", "description")
_MAX_FILE_BYTES = 1 << 20


def builtin_model_path(name: str = "pneumatic_cylinder") -> Path:
    """Path of a model file shipped with fdigen."""
    if name not in BUILTIN_MODELS:
        raise ModelFileError(f"no built-in model (have: {', '.join(BUILTIN_MODELS)})",
                             field="model", symbol=name)
    return Path(str(resources.files("fdigen.models").joinpath(f"{name}.toml")))


def load_model(path: str | Path | None = None) -> Model:
    """Load a model file; ``None`` loads the built-in pneumatic cylinder.

    Parameters
    ----------
    path : str or Path, optional
        A TOML model file, or the name of a built-in model.

    Returns
    -------
    Model
    """
    if path is None:
        path = builtin_model_path()
    elif str(path) in BUILTIN_MODELS:
        path = builtin_model_path(str(path))
    path = Path(path)
    from fdigen.files.bounded import read_bytes

    raw = read_bytes(path, _MAX_FILE_BYTES, what="model file",   # regular files only
                     error=lambda msg: ModelFileError(msg.removeprefix(f"{path}: "),
                                                      source=str(path)))
    for bom, what in ((b"\xef\xbb\xbf", "a UTF-8 byte-order mark (as Windows Notepad saves)"),
                      (b"\xff\xfe", "a UTF-16 byte-order mark"),
                      (b"\xfe\xff", "a UTF-16 byte-order mark")):
        if raw.startswith(bom):
            raise ModelFileError(f"the file starts with {what}: TOML is UTF-8 without one; "
                                 "save it as UTF-8 (no BOM)", source=str(path))
    return parse_model_text(raw.decode("utf-8", errors="replace"), source=str(path))


def _free_name(name: str, taken) -> str:
    """``name``, or ``name_2``, ``name_3``... the first not in ``taken``."""
    k, out = 1, name
    while out in taken:
        k += 1
        out = f"{name}_{k}"
    return out


def canonical_description(model: Model) -> dict:
    """A JSON-able, order-stable description of everything that defines a model."""
    return {
        "name": model.name,
        "states": [[s.name, s.unit, list(s.range or ()),
                    [sp.srepr(b) for b in s.limits] if s.limits is not None else None]
                   for s in model.states],
        "inputs": [[s.name, s.unit, list(s.range or ()), s.column]
                   + (["measured"] if not s.is_actuator else []) for s in model.inputs],
        "outputs": [[o.name, sp.srepr(o.expr), o.noise_std, o.column] for o in model.outputs],
        "parameters": [[q.name, repr(q.value), list(q.bounds or ()), q.uncertain]
                       + ([repr(q.tolerance)] if q.tolerance is not None else [])
                       for q in model.parameters],
        "definitions": [[n, sp.srepr(e)] for n, e in model.definitions],
        "dynamics": [sp.srepr(e) for e in model.dynamics],
        "faults": [[f.name, f.location, f.mode, f.target, sp.srepr(f.term), f.fault_class,
                    repr(f.test_size)]
                   + ([[[t, sp.srepr(e)] for t, e in f.terms]] if f.multi else [])
                   + ([["test_rate", repr(f.test_rate)]] if f.test_rate is not None else [])
                   for f in model.faults],
        "operating_point": sorted((k, repr(v)) for k, v in model.operating_point.items()),
        "fdi": model.fdi,
        "simulation": model.simulation,
    }


def model_hash(model: Model) -> str:
    """SHA-256 of the model's canonical description (the identity of a build)."""
    import json

    text = json.dumps(canonical_description(model), sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def parse_model_text(text: str, source: str = "<string>") -> Model:
    """Parse the text of a model file.

    Raises
    ------
    ModelFileError
        On malformed TOML, missing or mistyped fields, undefined symbols or functions.
    """
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ModelFileError(f"invalid TOML ({exc})", source=source)
    except ValueError as exc:    # an integer of more than 4300 digits (attack round 8)
        raise ModelFileError(f"invalid TOML: a number the reader cannot hold ({exc}); "
                             "model files need numbers below 1e150", source=source) from None
    except RecursionError:
        raise ModelFileError("invalid TOML: arrays or tables nested too deeply (a model "
                             "file needs a few levels)", source=source) from None
    model = _Reader(doc, source).model()
    check_model_size(model)          # before anything walks the substituted equations
    check_physical_sanity(model)
    check_controllers(model)
    return model


class _Reader:
    def __init__(self, doc, source):
        self.doc = doc
        self.src = source
        self.model_name = None

    def err(self, message, fld=None, symbol=None):
        return ModelFileError(message, source=self.src, field=fld, symbol=symbol)

    def table(self, key, required=True):
        value = self.doc.get(key, None)
        if value is None:
            if required:
                raise self.err("missing table", key)
            return {}
        if not isinstance(value, dict):
            raise self.err("must be a table", key)
        return value

    def number(self, value, fld, symbol=None):
        problem = number_problem(value)
        if problem:
            raise self.err(problem, fld, symbol)
        return float(value)

    def pair(self, value, fld, symbol):
        if value is None:
            return None
        if not isinstance(value, list) or len(value) != 2:
            raise self.err("expected [low, high]", fld, symbol)
        lo, hi = (self.number(v, fld, symbol) for v in value)
        if not lo < hi:
            raise self.err("low must be below high", fld, symbol)
        return (lo, hi)

    def entry(self, table_name, name, value, allowed):
        fld = f"{table_name}.{name}"
        if not isinstance(value, dict):
            raise self.err("must be a table {...}", fld, name)
        extra = set(value) - set(allowed)
        if extra:
            raise self.err(f"unknown key (allowed: {', '.join(sorted(allowed))})", fld,
                           sorted(extra)[0])
        return fld

    def names(self, kind, table, check=check_name):
        """The keys of ``table``, each checked as a name (field ``kind``)."""
        for key in table:
            check(key, source=self.src, field=kind, kind=_KIND.get(kind, "name"),
                  model_name=self.model_name)
        return table

    def unknown_keys(self, table, allowed, fld):
        extra = sorted(set(table) - set(allowed))
        if extra:
            raise self.err(f"unknown key (allowed: {', '.join(allowed)})", fld, extra[0])

    def simulation_settings(self, sim):
        """Type the [simulation] table: texts, a positive duration, integer sub-steps
        (its keys and controllers are checked by :func:`parse_simulation`)."""
        for key in ("controller", "input", "reference", "reference_column",
                    "reference_symbol"):
            if key in sim and not isinstance(sim[key], str):
                raise self.err(f"expected text, got {type(sim[key]).__name__}",
                               f"simulation.{key}")
        for key in ("input", "reference_symbol", "reference_column"):
            if key in sim:
                check_name(sim[key], source=self.src, field=f"simulation.{key}",
                           model_name=self.model_name)
        if "duration" in sim and self.number(sim["duration"], "simulation.duration") <= 0:
            raise self.err("duration must be > 0", "simulation.duration")
        steps = sim.get("substeps", 1)
        if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= 10000:
            raise self.err("substeps must be an integer in [1, 10000]", "simulation.substeps",
                           str(steps)[:30])
        if "initial" in sim and not isinstance(sim["initial"], dict):
            raise self.err("must be a table state = value", "simulation.initial")

    def model(self) -> Model:
        self.unknown_keys(self.doc, TABLES, None)
        head = self.table("model")
        self.unknown_keys(head, MODEL_KEYS, "model")
        name = head.get("name")
        if not isinstance(name, str):
            raise self.err("missing model name", "model.name")
        check_model_name(name, source=self.src)
        self.model_name = name
        self.simulation_settings(self.table("simulation", required=False))
        for kind in SYMBOL_KINDS:
            self.names(kind, self.table(kind, required=kind not in ("definitions", "faults")))

        params = []
        for pname, spec in self.table("parameters").items():
            fld = self.entry("parameters", pname, spec,
                             {"value", "unit", "description", "bounds", "uncertain",
                              "tolerance"})
            if "value" not in spec:
                raise self.err("parameter without a value", fld, pname)
            value = self.number(spec["value"], fld + ".value", pname)
            bounds = self.pair(spec.get("bounds"), fld + ".bounds", pname)
            if bounds and not bounds[0] <= value <= bounds[1]:
                raise self.err(f"value {value} outside bounds {bounds}", fld, pname)
            uncertain = spec.get("uncertain", False)
            if not isinstance(uncertain, bool):   # "false" is a true string (attack 10)
                raise self.err(f"expected true or false, got {uncertain!r}",
                               fld + ".uncertain", pname)
            tolerance = None
            if "tolerance" in spec:
                tolerance = self.number(spec["tolerance"], fld + ".tolerance", pname)
                if not 0 <= tolerance < 1:
                    raise self.err(f"tolerance {tolerance} is a relative spread +-tol: "
                                   "give a number in [0, 1) (0.05 for +-5 %)",
                                   fld + ".tolerance", pname)
                if not uncertain:
                    raise self.err("a tolerance on a parameter that is not uncertain: add "
                                   "uncertain = true, or remove the tolerance",
                                   fld + ".tolerance", pname)
            params.append(Parameter(pname, value, str(spec.get("unit", "")),
                                    str(spec.get("description", "")), bounds,
                                    uncertain, tolerance))

        param_syms = {q.name: q.symbol for q in params}

        def variables(kind):
            out = []
            for vname, spec in self.table(kind).items():
                fld = self.entry(kind, vname, spec,
                                 {"unit", "description", "range", "column", "limits",
                                  *(("kind",) if kind == "inputs" else ())})
                role = spec.get("kind", "actuator") if kind == "inputs" else ""
                if role not in ("", *INPUT_KINDS):
                    raise self.err(f"expected one of {', '.join(map(repr, INPUT_KINDS))} "
                                   "(a command, or a measured disturbance)",
                                   fld + ".kind", str(role)[:30])
                limits = spec.get("limits")
                if limits is not None:
                    if not isinstance(limits, list) or len(limits) != 2:
                        raise self.err("expected [low, high]", fld + ".limits", vname)
                    limits = tuple(
                        parse_expression(str(v), param_syms, source=self.src,
                                         field=fld + ".limits")
                        if isinstance(v, str) else sp.Float(self.number(v, fld, vname), 17)
                        for v in limits)
                out.append(Variable(vname, str(spec.get("unit", "")),
                                    str(spec.get("description", "")),
                                    self.pair(spec.get("range"), fld + ".range", vname),
                                    str(spec.get("column", vname)), limits, role))
            return out

        states = variables("states")
        inputs = variables("inputs")
        faults_raw = self.table("faults", required=False)

        symbols = {}
        for item in [*params, *states, *inputs]:
            if item.name in symbols:
                raise self.err("duplicated symbol", "model", item.name)
            symbols[item.name] = item.symbol
        for fname in faults_raw:
            if fname in symbols:
                raise self.err("duplicated symbol", "faults", fname)
        symbols_no_faults = dict(symbols)
        fault_syms = {fname: sp.Symbol(fname, real=True) for fname in faults_raw}

        definitions = []
        for dname, text in self.table("definitions", required=False).items():
            fld = f"definitions.{dname}"
            if dname in symbols:
                raise self.err("duplicated symbol", fld, dname)
            expr = parse_expression(text, {**symbols, **fault_syms}, source=self.src,
                                    field=fld)
            definitions.append((dname, expr))
            symbols[dname] = sp.Symbol(dname, real=True)
            symbols_no_faults[dname] = symbols[dname]

        dyn = self.table("dynamics")
        state_names = [s.name for s in states]
        for key in dyn:
            if key not in state_names:
                raise self.err("equation for a state that does not exist", "dynamics", key)
        dynamics = []
        for sname in state_names:
            if sname not in dyn:
                raise self.err("missing equation for state", "dynamics", sname)
            expr = parse_expression(dyn[sname], {**symbols, **fault_syms}, source=self.src,
                                    field=f"dynamics.{sname}")
            if expr.free_symbols & set(fault_syms.values()):
                # a fault written in the equation itself means what it means inside a
                # definition: the equation becomes one (a user's servo wrote
                # sqrt(Ps - supply_drop - pA) inline and was told "undefined symbol")
                dname = _free_name(f"d{sname}_dt", {*symbols, *fault_syms, *dyn,
                                                   *self.table("outputs")})
                definitions.append((dname, expr))
                symbols[dname] = sp.Symbol(dname, real=True)
                expr = symbols[dname]
            dynamics.append(expr)

        outputs = []
        for oname, spec in self.table("outputs").items():
            fld = self.entry("outputs", oname, spec,
                             {"expr", "unit", "description", "noise_std", "column"})
            if oname in symbols:
                raise self.err("duplicated symbol", fld, oname)
            if "expr" not in spec:
                raise self.err("output without an expression", fld, oname)
            expr = parse_expression(spec["expr"], {**symbols_no_faults, **fault_syms},
                                    source=self.src, field=fld + ".expr")
            if expr.free_symbols & set(fault_syms.values()):
                # a sensor fault written in the sensor's map means what it means inside a
                # definition the output reads (a user's `(1 + isens)*iL` was "undefined
                # symbol" here and accepted in [definitions])
                dname = _free_name(f"{oname}_map", {*symbols, *fault_syms, *dyn,
                                                   *self.table("outputs")})
                definitions.append((dname, expr))
                symbols[dname] = sp.Symbol(dname, real=True)
                expr = symbols[dname]
            noise = self.number(spec.get("noise_std", 0.0), fld + ".noise_std", oname)
            if noise < 0:
                raise self.err("noise standard deviation must be >= 0", fld + ".noise_std",
                               oname)
            outputs.append(Output(oname, expr, str(spec.get("unit", "")),
                                  str(spec.get("description", "")), noise,
                                  str(spec.get("column", oname))))

        fault_symbols = dict(symbols)
        for fname in faults_raw:
            fault_symbols[fname] = sp.Symbol(fname, real=True)
        columns = {}
        for kind, items in (("inputs", inputs), ("outputs", outputs)):
            for item in items:
                fld = f"{kind}.{item.name}.column"
                check_name(item.column, source=self.src, field=fld, kind="log column",
                           model_name=name)
                # compared exactly, as read_log and the generated main.c match columns
                # (a temperature column 'T' beside the time 't' is a different column)
                if item.column == "t":
                    raise self.err("log column 't' is the time column", fld, item.column)
                if item.column in columns:
                    raise self.err(f"log column already used by {columns[item.column]}",
                                   fld, item.column)
                columns[item.column] = f"{kind}.{item.name}"
        for fname, spec in faults_raw.items():
            if isinstance(spec, dict) and isinstance(spec.get("class"), str):
                check_class_name(spec["class"], source=self.src,
                                 field=f"faults.{fname}.class", model_name=name)
        in_definitions = {f for f, sym in fault_syms.items()
                          if any(sym in e.free_symbols for _, e in definitions)}
        kinds = {**{v.name: "state" for v in states}, **{o.name: "output" for o in outputs},
                 **{v.name: "input" for v in inputs}}
        faults = parse_faults(faults_raw, fault_symbols, kinds, in_definitions, self.src)

        op = {}
        for key, value in self.table("operating_point").items():
            fld = f"operating_point.{key}"
            if isinstance(value, str):
                expr = parse_expression(value, {p.name: p.symbol for p in params},
                                        source=self.src, field=fld)
                value = expr.xreplace({p.symbol: sp.Float(p.value, 17) for p in params})
                if not (value.is_number and value.is_real and value.is_finite):
                    raise self.err(f"operating point is not a finite real number ({value})",
                                   fld, key)
                value = float(value)
            op[key] = self.number(value, fld, key)

        parse_simulation(self.table("simulation", required=False),
                         inputs=[v.name for v in inputs], outputs=[o.name for o in outputs],
                         states=state_names, parameters={q.name: q.value for q in params},
                         operating_point=op, source=self.src,
                         columns=[v.column for v in (*inputs, *outputs)])
        sim = self.table("simulation", required=False)
        for key in sim.get("initial", {}):
            if key not in state_names:
                raise self.err("initial value for an unknown state", "simulation.initial",
                               str(key)[:40])
        return Model(
            name=name,
            description=str(head.get("description", "")),
            states=tuple(states),
            inputs=tuple(inputs),
            outputs=tuple(outputs),
            parameters=tuple(params),
            definitions=tuple(definitions),
            dynamics=tuple(dynamics),
            faults=tuple(faults),
            operating_point=op,
            fdi=self.table("fdi", required=False),
            simulation=self.table("simulation", required=False),
            source=self.src,
        )


_KIND = {"states": "state", "inputs": "input", "outputs": "output", "parameters": "parameter",
         "definitions": "definition", "faults": "fault"}

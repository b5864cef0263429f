"""Reliability: random well-formed and malformed model files either parse or fail cleanly.

Property tests (hypothesis) start from the built-in pneumatic cylinder model and mutate it:
equation strings replaced by random expression trees (known and unknown names, allowed and
forbidden operators and constructs), tables and keys dropped or duplicated, values replaced
by random TOML values, random bytes spliced into the text. Every case must either parse
(``parse_model_text``) or raise :class:`fdigen.errors.FdigenError` -- never another
exception -- within 5 s (hypothesis deadline: a parse takes milliseconds; 1 s failed on a
2-core machine loaded by other runs, 1.4 s for one case).

A model file can never run code: payloads that would create a sentinel file if evaluated
(``__import__``, ``open``, lambdas, comprehensions, walrus, f-strings, attribute access,
dunder names...) are refused and the sentinel never appears.

When ``FDIGEN_RELIABILITY_REPORT`` names a file, every test appends one JSON line
(class of input, number of cases, result) to it; ``scripts/reliability_report.py`` renders
them into ``docs/reliability.md``.
"""

from __future__ import annotations

import json
import math
import os
import time
import tomllib

import pytest

from reliability_log import reporter
import sympy as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fdigen.errors import FdigenError
from fdigen.model.expression import parse_expression
from fdigen.model.model_file import builtin_model_path, parse_model_text

BASE_TEXT = builtin_model_path("pneumatic_cylinder").read_text()
BASE_DOC = tomllib.loads(BASE_TEXT)
KNOWN = sorted({*BASE_DOC["parameters"], *BASE_DOC["states"], *BASE_DOC["inputs"],
                *BASE_DOC["definitions"]})
FAULT_NAMES = sorted(BASE_DOC["faults"])

SETTINGS = dict(deadline=5000, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.filter_too_much])


# ------------------------------------------------------------------------------ report
report = reporter("model files")


class Tally:
    """Counts hypothesis cases by outcome; records the line even when the test fails."""

    def __init__(self, test, kind):
        self.test, self.kind = test, kind
        self.parsed = self.refused = 0
        self.known = {}

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        n = self.parsed + self.refused + sum(self.known.values())
        details = f"{self.parsed} parsed, {self.refused} refused with FdigenError"
        if self.known:
            details += "; known defects hit: " + ", ".join(
                f"{k} x{v}" for k, v in sorted(self.known.items()))
        if exc_type is None:
            report(self.test, self.kind, n, "pass", details)
        else:
            report(self.test, self.kind, n, "FAIL",
                   f"{details}; {exc_type.__name__}: {str(exc)[:300]}")
        return False

    def check(self, func, *args, **kwargs):
        """Run func: it must return or raise FdigenError. Exceptions matching a known
        defect (each has its own xfail test below) are counted, not failed; anything
        else fails the property."""
        try:
            func(*args, **kwargs)
        except FdigenError:
            self.refused += 1
        except Exception as exc:  # noqa: BLE001
            defect = known_defect(exc)
            if defect is None:
                raise
            self.known[defect] = self.known.get(defect, 0) + 1
        else:
            self.parsed += 1


def known_defect(exc):
    """Name of the known parser defect an exception belongs to, or None (see the xfail
    tests at the end of this file)."""
    text = str(exc)
    if isinstance(exc, ZeroDivisionError):
        return "D1 float 0.0/0.0 -> ZeroDivisionError"
    if isinstance(exc, RecursionError):
        return "D2 deep unary chain -> RecursionError"
    if isinstance(exc, ValueError) and "digits" in text:
        return "D3 huge exact integer power -> ValueError"
    if isinstance(exc, TypeError) and "Cannot convert complex to float" in text:
        return "D4 complex operating_point -> TypeError"
    return None


# ------------------------------------------------------------------------- TOML writer
def _key(k):
    return json.dumps(str(k))


def _value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # JSON escapes are valid TOML basic-string escapes
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(type(v))


def dump_toml(doc: dict) -> str:
    """A minimal TOML writer: nested dicts become [table] headers, others inline."""
    lines = []

    def table(path, d):
        subs = []
        for k, v in d.items():
            if isinstance(v, dict):
                subs.append((k, v))
            else:
                lines.append(f"{_key(k)} = {_value(v)}")
        for k, v in subs:
            lines.append("")
            lines.append("[" + ".".join(_key(p) for p in (*path, k)) + "]")
            table((*path, k), v)

    table((), doc)
    return "\n".join(lines) + "\n"


def test_writer_round_trips_the_builtin_model():
    assert tomllib.loads(dump_toml(BASE_DOC)) == BASE_DOC
    parse_model_text(dump_toml(BASE_DOC))
    report("test_writer_round_trips_the_builtin_model", "unmutated model (writer sanity)", 1,
           "pass", "parses")


# ------------------------------------------------------------------------ strategies
IDENT = st.from_regex(r"\A[a-zA-Z][a-zA-Z0-9]{0,6}\Z")
NUMBER = st.one_of(st.integers(0, 100).map(str),
                   st.floats(-1e6, 1e6, allow_nan=False).map(repr),
                   st.sampled_from(["1e308", "1e-308", "5e-324", "0.0", "1_000", "0x1f",
                                    "1e999", "0b101"]))
FORBIDDEN_LEAF = st.sampled_from([
    '"text"', "b'x'", "True", "None", "...", "1j", "__import__", "_x", "__class__",
    "x.real", "A.__class__", "[1, 2]", "(1, 2)", "{1: 2}", "{1}", "v[0]", "*v", "not v",
    "~v", "lambda: 0", "(q := 1)", "[i for i in v]", "f'{v}'", "v if v else x",
    "eval('1')", "open('x')", "getattr(v, 'x')", "sin(x=1)", "print(1)", "globals()",
])
LEAF = st.one_of(st.sampled_from(KNOWN), IDENT, NUMBER, FORBIDDEN_LEAF)
ALLOWED_CALLS = ["sqrt", "exp", "log", "sin", "cos", "tan", "asin", "acos", "atan", "atan2",
                 "sinh", "cosh", "tanh", "abs", "sign", "min", "max"]
BINOPS = ["+", "-", "*", "/", "%", "//", "@", "&", "|", "^", "<<", ">>", "<", "==", " and ",
          " or ", " if 1 else "]
# Exponents stay small literals or names: nested integer powers with large exponents are a
# known parser defect (test_nested_integer_powers_are_refused_quickly, xfail).
EXPONENT = st.one_of(st.sampled_from(["2", "3", "-1", "0.5", "(1/2)", "65", "1e9"]),
                     st.sampled_from(KNOWN))


def _combine(children):
    return st.one_of(
        st.tuples(children, st.sampled_from(BINOPS), children).map(
            lambda t: f"({t[0]}{t[1]}{t[2]})"),
        st.tuples(children, EXPONENT).map(lambda t: f"({t[0]})**{t[1]}"),
        st.tuples(st.sampled_from(["-", "+"]), children).map(lambda t: f"{t[0]}({t[1]})"),
        st.tuples(st.sampled_from(ALLOWED_CALLS + ["eval", "exec", "open", "foo"]),
                  st.lists(children, min_size=0, max_size=3)).map(
            lambda t: f"{t[0]}({', '.join(t[1])})"),
    )


EXPR = st.recursive(LEAF, _combine, max_leaves=12)


def _equation_slots(doc):
    """Paths of every equation string in the model."""
    slots = [("definitions", k) for k in doc["definitions"]]
    slots += [("dynamics", k) for k in doc["dynamics"]]
    slots += [("outputs", k, "expr") for k in doc["outputs"]]
    slots += [("faults", k, "term") for k in doc["faults"]]
    slots += [("operating_point", k) for k in doc["operating_point"]]
    return slots


def _leaf_paths(node, path=()):
    if isinstance(node, dict):
        out = [path] if path else []
        for k, v in node.items():
            out += _leaf_paths(v, (*path, k))
        return out
    if isinstance(node, list):
        return [path] + [(*path, i) for i in range(len(node))]
    return [path]


def _get_parent(doc, path):
    node = doc
    for p in path[:-1]:
        node = node[p]
    return node


def _copy(doc):
    return json.loads(json.dumps(doc))


TOML_SCALAR = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-2**63, 2**63 - 1),
    st.booleans(), st.text(max_size=20), EXPR)
TOML_VALUE = st.recursive(TOML_SCALAR, lambda c: st.one_of(
    st.lists(c, max_size=3), st.dictionaries(IDENT, c, max_size=3)), max_leaves=6)


# ---------------------------------------------------------------------- property tests
def test_random_equations_parse_or_refuse_cleanly():
    with Tally("test_random_equations_parse_or_refuse_cleanly",
               "equation strings replaced by random expression trees") as tally:
        slots = _equation_slots(BASE_DOC)

        @settings(max_examples=250, **SETTINGS)
        @given(st.lists(st.tuples(st.sampled_from(slots), EXPR), min_size=1, max_size=3))
        def run(edits):
            doc = _copy(BASE_DOC)
            for path, text in edits:
                _get_parent(doc, path)[path[-1]] = text
            tally.check(parse_model_text, dump_toml(doc))

        run()
    assert tally.parsed > 0 and tally.refused > 0


def test_random_expressions_parse_or_refuse_cleanly():
    symbols = {n: sp.Symbol(n, real=True) for n in KNOWN}
    with Tally("test_random_expressions_parse_or_refuse_cleanly",
               "random expression trees, parse_expression directly") as tally:

        @settings(max_examples=1000, **SETTINGS)
        @given(EXPR)
        def run(text):
            tally.check(parse_expression, text, symbols, source="<fuzz>", field="eq")

        run()
    assert tally.parsed > 0 and tally.refused > 0


def test_structural_mutations_parse_or_refuse_cleanly():
    paths = _leaf_paths(BASE_DOC)
    with Tally("test_structural_mutations_parse_or_refuse_cleanly",
               "tables/keys dropped, duplicated, values replaced by random TOML values") as tally:

        @settings(max_examples=300, **SETTINGS)
        @given(st.lists(st.tuples(st.sampled_from(["drop", "set", "dup"]),
                                  st.sampled_from(paths), TOML_VALUE, IDENT),
                        min_size=1, max_size=4))
        def run(ops):
            doc = _copy(BASE_DOC)
            for op, path, value, name in ops:
                try:
                    parent = _get_parent(doc, path)
                    old = parent[path[-1]]
                except (KeyError, IndexError, TypeError):
                    continue
                if op == "drop":
                    if isinstance(parent, list):
                        parent.pop(path[-1])
                    else:
                        del parent[path[-1]]
                elif op == "set":
                    parent[path[-1]] = value
                elif isinstance(parent, dict):
                    # duplicate under another name (e.g. a definition shadowing a state)
                    parent[name if name not in parent else name + "_"] = _copy(old)
            tally.check(parse_model_text, dump_toml(doc))

        run()
    assert tally.parsed > 0 and tally.refused > 0


def test_duplicated_lines_and_tables_refused_cleanly():
    lines = BASE_TEXT.splitlines()
    with Tally("test_duplicated_lines_and_tables_refused_cleanly",
               "text lines / table headers duplicated or dropped") as tally:

        @settings(max_examples=300, **SETTINGS)
        @given(st.integers(0, len(lines) - 1), st.integers(1, 5), st.booleans())
        def run(start, count, drop):
            chunk = lines[start:start + count]
            new = lines[:start] + ([] if drop else chunk + chunk) + lines[start + count:]
            tally.check(parse_model_text, "\n".join(new))

        run()


def test_random_bytes_parse_or_refuse_cleanly():
    raw = BASE_TEXT.encode()
    with Tally("test_random_bytes_parse_or_refuse_cleanly",
               "random bytes spliced into / replacing the file") as tally:

        @settings(max_examples=400, **SETTINGS)
        @given(st.one_of(
            st.tuples(st.integers(0, len(raw)), st.integers(0, 16), st.binary(max_size=32)),
            st.tuples(st.just(0), st.just(len(raw)), st.binary(max_size=512))))
        def run(edit):
            pos, cut, blob = edit
            data = raw[:pos] + blob + raw[pos + cut:]
            # what load_model does with the bytes of a file
            tally.check(parse_model_text, data.decode("utf-8", errors="replace"))

        run()


# ---------------------------------------------------------------- code can never run
PAYLOADS = [
    "__import__('os').system('touch {s}')",
    "__import__('pathlib').Path('{s}').touch()",
    "open('{s}', 'w')",
    "exec(\"open('{s}', 'w')\")",
    "eval(\"open('{s}', 'w')\")",
    "(lambda: open('{s}', 'w'))()",
    "[open('{s}', 'w') for _ in [1]][0]",
    "{{open('{s}', 'w') for _ in [1]}}",
    "(f := open('{s}', 'w'))",
    "f\"{{open('{s}', 'w')}}\"",
    "x.__class__.__base__.__subclasses__()",
    "().__class__.__bases__[0].__subclasses__()",
    "getattr(x, 'real')",
    "x.real",
    "sin.__globals__",
    "globals()['__builtins__']",
    "breakpoint()",
    "sin(open('{s}', 'w'))",
    "max(x, *[open('{s}', 'w')])",
    "sin(x=open('{s}', 'w'))",
    "x if open('{s}', 'w') else x",
    "x[open('{s}', 'w')]",
    "x**10**10",
    "x**(10**10)",
    "9**9**9",
    "2**64**64**64",
    "x**-(10**10)",
    "x**1e300",
    "1e999",
    "sin(" * 70 + "x" + ")" * 70,
    "(" * 400 + "x" + ")" * 400,
    "x" + "+x" * 1999,
    "-" * 1000 + "x",
    "x" * 5000,
    "\x00",
    "x\u200b",
]


@pytest.mark.parametrize("payload", PAYLOADS, ids=[f"p{i}" for i in range(len(PAYLOADS))])
def test_model_file_can_never_run_code(payload, tmp_path, monkeypatch):
    sentinel = tmp_path / "pwned"
    monkeypatch.chdir(tmp_path)
    text = payload.replace("{s}", str(sentinel)).replace("{{", "{").replace("}}", "}") \
        if "{s}" in payload else payload
    symbols = {"x": sp.Symbol("x", real=True)}
    t0 = time.perf_counter()
    with pytest.raises(FdigenError):
        parse_expression(text, symbols, source="<payload>", field="eq")
    # the same payload inside a whole model file, in an equation and in a limit
    doc = _copy(BASE_DOC)
    doc["dynamics"]["x"] = text.replace("x", "xdot") if "x" in text else text
    doc["states"]["x"]["limits"] = [0.0, text]
    with pytest.raises(FdigenError):
        parse_model_text(dump_toml(doc), source="<payload>")
    elapsed = time.perf_counter() - t0
    assert not sentinel.exists(), "a model file ran code"
    assert not (tmp_path / "pwned").exists()
    assert elapsed < 1.0, f"payload took {elapsed:.2f} s"
    report("test_model_file_can_never_run_code", "code-execution payloads "
           "(__import__, open, exec/eval, lambda, comprehensions, walrus, f-strings, "
           "attribute access, dunders, huge exponents, deep nesting)", 1, "pass",
           "refused with FdigenError, no side effect, < 1 s")


# ------------------------------------------------------------ defects found (xfail)
def _xfail_case(test, kind, func, reason):
    """Run func expecting FdigenError; record the outcome, xfail if something else."""
    t0 = time.perf_counter()
    try:
        func()
    except FdigenError:
        report(test, kind, 1, "pass", f"refused with FdigenError in "
               f"{time.perf_counter() - t0:.2f} s")
        return
    except BaseException as exc:  # noqa: BLE001 - the point is to catch anything
        report(test, kind, 1, "FAIL (xfail)", f"{type(exc).__name__}: {str(exc)[:160]}; "
               f"{reason}")
        pytest.xfail(f"{type(exc).__name__}: {reason}")
    report(test, kind, 1, "FAIL (xfail)", f"accepted; {reason}")
    pytest.xfail(f"accepted: {reason}")


def test_float_zero_division_is_refused_cleanly():
    """'0.0/0.0': both constants become sympy Floats and Float.__truediv__ raises
    ZeroDivisionError (mpmath mpf_div), which _Converter._binop does not catch."""
    symbols = {"x": sp.Symbol("x")}
    _xfail_case("test_float_zero_division_is_refused_cleanly",
                "float zero divided by float zero '0.0/0.0'",
                lambda: parse_expression("0.0/0.0", symbols),
                "sympy Float 0.0/0.0 raises ZeroDivisionError in expression._binop")


def test_long_unary_chain_is_refused_cleanly():
    """3000 unary minus signs (< 4000 characters) make ast.parse raise RecursionError
    before the node-count limit is applied (expression.py calls ast.parse on any text
    up to MAX_LENGTH and only catches SyntaxError)."""
    symbols = {"x": sp.Symbol("x")}
    _xfail_case("test_long_unary_chain_is_refused_cleanly",
                "3000 nested unary minus (RecursionError in ast.parse)",
                lambda: parse_expression("-" * 3000 + "x", symbols),
                "ast.parse RecursionError escapes; expression.py catches only SyntaxError")


def test_nested_integer_powers_are_refused_quickly():
    """((((2**64)**64)**64)**64): each exponent is within +-64 but sympy evaluates the
    integer power exactly: 2**(64**4) has ~5 million digits and is ACCEPTED (anything that
    prints it, e.g. model_hash's srepr, then raises ValueError: int-to-str digit limit);
    5 levels take ~9 s to parse; 6 levels would need ~8 GB. The 4-level case runs here."""
    _xfail_case("test_nested_integer_powers_are_refused_quickly",
                "nested integer powers ((2**64)**64)**64)**64",
                lambda: parse_expression("((((2**64)**64)**64)**64)", {}),
                "exact integer power evaluated by sympy and accepted (2**16777216); "
                "printing it raises ValueError (4300-digit limit); 5 levels take ~9 s, "
                "6 levels exhaust memory")


@pytest.mark.parametrize("value", ["sqrt(-1)", "1/0", "log(0)"])
def test_operating_point_with_complex_value_is_refused(value):
    """operating_point strings are evaluated with float(expr.subs(...)) in model_file.py;
    a complex or infinite sympy result (I, zoo, -oo) raises TypeError, not ModelFileError."""
    doc = _copy(BASE_DOC)
    doc["operating_point"]["Pp"] = value
    _xfail_case("test_operating_point_with_complex_value_is_refused",
                f"operating_point value {value!r}",
                lambda: parse_model_text(dump_toml(doc)),
                "float() of a complex/zoo sympy value raises TypeError in "
                "model_file._Reader.model (operating_point)")


# ------------------------------------------------- well-formed variants build and verify
def _variant(rng, bad=None, extreme=False):
    """The cylinder model with random numbers: parameter values (each changed with
    probability 1/2, by a factor 0.5-2, or log-uniform within its bounds if ``extreme``),
    sample time, RMS window and
    process-noise scale; ``bad`` puts one of them out of range (a parameter outside its
    bounds, a non-positive sample time or window, a negative noise)."""
    doc = tomllib.loads(BASE_TEXT)
    changed = []
    for name, par in doc["parameters"].items():
        if rng.random() < 0.5:
            lo, hi = par["bounds"]
            if extreme and lo > 0:          # anywhere in the bounds
                value = math.exp(rng.uniform(math.log(lo), math.log(hi)))
            else:                           # a plausible other plant: 0.5x to 2x
                value = par["value"] * math.exp(rng.uniform(-math.log(2), math.log(2)))
            par["value"] = min(max(value, lo), hi)      # exp(log(lo)) may round below
            changed.append(name)
    # the operating point (chamber pressures P0) must lie within the state limits
    # [Patm, Psup], which the loader checks: keep the random plant physical
    pars = doc["parameters"]
    pars["P0"]["value"] = min(max(pars["P0"]["value"], pars["Patm"]["value"]),
                              pars["Psup"]["value"])
    fdi = doc["fdi"]
    fdi["sample_time"] = float(rng.choice([5e-4, 1e-3, 2e-3]))
    fdi["window"] = int(rng.choice([50, 200, 400]))
    scale = float(rng.choice([0.1, 1.0, 10.0]))
    if bad == "parameter":
        name = str(rng.choice(sorted(doc["parameters"])))
        hi = doc["parameters"][name]["bounds"][1]
        doc["parameters"][name]["value"] = hi * 2.0 if hi > 0 else hi + 1.0
    elif bad == "sample_time":
        fdi["sample_time"] = float(rng.choice([0.0, -1e-3]))
    elif bad == "window":
        fdi["window"] = int(rng.choice([0, -5]))
    elif bad == "noise":
        scale = -1.0
    fdi["process_noise"] = {k: v * scale for k, v in fdi["process_noise"].items()}
    return dump_toml(doc), changed, scale


def test_random_well_formed_models_build_and_verify_or_refuse_cleanly():
    """Seeded random variants: each well-formed one either designs, builds into C and
    matches the reference (points and a closed-loop trajectory, the tolerances of
    `fdigen verify`) or is refused with an FdigenError (a stiff or undetectable design);
    each malformed one is refused with a ModelFileError naming the file and field."""
    import numpy as np

    from fdigen.design.fdi_design import fdi_design
    from fdigen.errors import ModelFileError
    from fdigen.verify.equivalence import verify

    import os

    rng = np.random.default_rng(20261123)
    plausible, extreme = (6, 4) if os.environ.get("FDIGEN_FULL_SWEEP") else (2, 1)
    cases = [(None, False)] * plausible + [(None, True)] * extreme + [
        (bad, False) for bad in ("parameter", "sample_time", "window", "noise")]
    verified, refused, reasons, worst = 0, 0, {}, 0.0
    for bad, extreme in cases:
        text, changed, scale = _variant(rng, bad, extreme)
        try:
            design = fdi_design(parse_model_text(text, source="variant.toml"))
            rep = verify(design, backends=["c"], n_points=100, duration=1.0)
        except FdigenError as exc:
            refused += 1
            reasons[type(exc).__name__] = reasons.get(type(exc).__name__, 0) + 1
            assert extreme or bad is not None, f"a plausible variant was refused: {exc}"
            if bad is not None:
                assert isinstance(exc, ModelFileError) and "variant.toml" in str(exc), exc
            continue
        assert bad is None, f"malformed variant ({bad}) was accepted"
        c = rep["backends"]["c"]["summary"]
        assert c["ok"], (changed, scale, c)
        worst = max(worst, c["points_max_rel"], c["trajectories_max_rel"])
        verified += 1
    assert verified >= plausible, (verified, reasons)
    report("test_random_well_formed_models_build_and_verify_or_refuse_cleanly",
           "seeded random model variants (parameters 0.5-2x or anywhere in / outside their "
           "bounds, sample time, "
           "window, process noise): designed, built to C, verified against the reference",
           len(cases), "pass",
           f"{verified} built and verified (C vs reference, worst relative difference "
           f"{worst:.1e}), {refused} refused "
           f"({', '.join(f'{k} x{v}' for k, v in sorted(reasons.items()))}); "
           "every malformed one refused with ModelFileError")

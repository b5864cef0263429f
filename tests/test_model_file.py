"""Model files: parsed through a whitelist, with errors that name file, field and symbol."""

import time

import pytest
import sympy as sp

from fdigen.errors import ModelFileError
from fdigen.model.expression import parse_expression
from fdigen.model.model_file import builtin_model_path, parse_model_text

SYMS = {n: sp.Symbol(n, real=True) for n in ("x", "y", "a")}


def test_builtin_cylinder_has_paper_structure(cylinder):
    assert [s.name for s in cylinder.states] == ["Pp", "Pn", "x", "xdot"]
    assert [o.name for o in cylinder.outputs] == ["x3", "x2", "pp", "pn"]
    assert {f.name for f in cylinder.faults} >= {"valve", "leak_p", "blockage_p",
                                                  "position_sensor", "pressure_sensor_p",
                                                  "pressure_sensor_n"}
    # eq (1): dPp/dt = -gamma A Pp/Vp xdot + K gamma R Ts / Vp v, Vp = V0 + A x
    g, A, Pp, Vp0, x, xdot, K, R, Ts, v, V0 = sp.symbols(
        "gamma A Pp Vp0 x xdot K R Ts v V0", real=True)
    Vp = V0 + A * x
    expected = -g * A * Pp / Vp * xdot + K * g * R * Ts / Vp * v
    assert sp.simplify(cylinder.f()[0] - expected) == 0
    # datasheet defaults
    values = {q.name: q.value for q in cylinder.parameters}
    assert values["A"] == 8.04e-4 and values["K"] == 1e-3 and values["Psup"] == 6e5


@pytest.mark.parametrize("text,expected", [
    ("x + 2*y", SYMS["x"] + 2 * SYMS["y"]),
    ("-x**2/a", -SYMS["x"] ** 2 / SYMS["a"]),
    ("sqrt(abs(x)) + max(x, y)", sp.sqrt(sp.Abs(SYMS["x"])) + sp.Max(SYMS["x"], SYMS["y"])),
    ("atan2(y, x) + tanh(a)", sp.atan2(SYMS["y"], SYMS["x"]) + sp.tanh(SYMS["a"])),
    ("1.5e-3*x", sp.Float(1.5e-3, 17) * SYMS["x"]),
])
def test_parser_builds_the_expression(text, expected):
    assert sp.simplify(parse_expression(text, SYMS) - expected) == 0


@pytest.mark.parametrize("text,symbol", [
    ("__import__('os').system('echo pwned')", "__"),
    ("x.__class__", "__"),
    ("x.real", "x.real"),
    ("(lambda q: q)(x)", "lambda q: q"),
    ("[q for q in (x, y)]", "[q for q in (x, y)]"),
    ("open('/etc/passwd')", "open"),
    ("eval('1')", "eval"),
    ("x[0]", "x[0]"),
    ("'text'", "'text'"),
    ("x if y else a", "x if y else a"),
    ("x**1000000", "1000000"),
    ("sqrt(x=1)", "sqrt"),
    ("z + 1", "z"),
    ("x @ y", "MatMult"),
])
def test_parser_refuses_everything_else(text, symbol):
    with pytest.raises(ModelFileError) as info:
        parse_expression(text, SYMS, source="m.toml", field="dynamics.x")
    message = str(info.value)
    assert "m.toml" in message and "dynamics.x" in message
    assert info.value.symbol == symbol


def test_deep_nesting_and_huge_input_refused_quickly():
    deep = "(" * 100 + "x" + "+1)*2" * 100       # (a flat chain of +1 is one level)
    nested_calls = "sin(" * 100 + "x" + ")" * 100
    long_sum = "+".join(["x"] * 3000)
    for text in (deep, nested_calls, long_sum):
        start = time.perf_counter()
        with pytest.raises(ModelFileError):
            parse_expression(text, SYMS, source="m.toml", field="f")
        assert time.perf_counter() - start < 1.0


def _cylinder_text():
    return builtin_model_path().read_text()


@pytest.mark.parametrize("old,new,field,symbol", [
    ('Pp   = "-gamma*A*Pp/Vp*xdot', 'Pp   = "-gamma*A*Pq/Vp*xdot', "dynamics.Pp", "Pq"),
    ('x    = "xdot"', 'x    = "foo(xdot)"', "dynamics.x", "foo"),
    ('x    = "xdot"', 'x    = "__import__(\'os\')"', "dynamics.x", "__"),
    ('x    = "xdot"\n', '', "dynamics", "x"),
    ('xdot = "A/M', 'zdot = "0"\nxdot = "A/M', "dynamics", "zdot"),
    ('M     = { value = 3.0,', 'M     = {', "parameters.M", "M"),
    ('Vp = "V0 + A*x"', 'Vp = "V0 + A*x"\nA = "1"', "definitions.A", "A"),
    ('class = "position_sensor"\ndescription = "primary',
     'class = "position_sensor"\ndescription = "primary', None, None),
])
def test_structural_errors_name_file_field_symbol(old, new, field, symbol, tmp_path):
    text = _cylinder_text()
    assert old in text
    bad = text.replace(old, new, 1)
    if field is None:  # control case: unchanged text parses
        parse_model_text(bad, source="ok.toml")
        return
    with pytest.raises(ModelFileError) as info:
        parse_model_text(bad, source="bad.toml")
    msg = str(info.value)
    assert "bad.toml" in msg and field in msg and symbol in msg, msg


def test_invalid_toml_and_missing_tables():
    with pytest.raises(ModelFileError, match="invalid TOML"):
        parse_model_text("[model\nname=1", source="x.toml")
    with pytest.raises(ModelFileError, match="missing table"):
        parse_model_text('[model]\nname = "m"\n', source="x.toml")


def test_fault_must_target_existing_thing():
    text = _cylinder_text().replace('target = "x3"', 'target = "x9"', 1)
    with pytest.raises(ModelFileError) as info:
        parse_model_text(text, source="f.toml")
    assert "faults.position_sensor.target" in str(info.value) and "x9" in str(info.value)


def test_model_hash_covers_every_field_that_changes_the_build():
    """Two models that differ only in a state's limits, a Kalman filter's schedule or a
    parameter value are different builds (the design cache is keyed by this hash)."""
    from fdigen.model.model_file import model_hash

    text = builtin_model_path("pneumatic_cylinder").read_text()
    base = model_hash(parse_model_text(text))
    variants = [
        text.replace('limits = [0.0, "L"]', 'limits = [0.001, "L"]'),
        text.replace('schedule = "measured"      # prediction', 'schedule = "operating_point"  #'),
        text.replace("sample_time = 1e-3", "sample_time = 2e-3"),
    ]
    hashes = {model_hash(parse_model_text(v)) for v in variants}
    assert all(v != text for v in variants)
    assert base not in hashes and len(hashes) == len(variants)


@pytest.mark.parametrize("spec,message", [
    ("uncertain = true, tolerance = 1.5", "give a number in [0, 1)"),
    ("uncertain = true, tolerance = -0.1", "give a number in [0, 1)"),
    ("tolerance = 0.05", "not uncertain"),
])
def test_a_parameters_own_tolerance_is_checked(spec, message):
    """``tolerance`` is a parameter's own relative spread for tune's campaigns (written by
    ``fdigen commission``): a fraction, and only on an uncertain parameter."""
    text = builtin_model_path("three_tank").read_text()
    old = 'az12 = { value = '
    assert old in text
    line = next(ln for ln in text.splitlines() if ln.startswith(old))
    bad = text.replace(line, line.replace("uncertain = true", "").rstrip(" }").rstrip(",")
                       + f", {spec} }}")
    with pytest.raises(ModelFileError) as info:
        parse_model_text(bad, source="m.toml")
    assert message in str(info.value) and "parameters.az12.tolerance" in str(info.value)
    good = text.replace(line, line.replace("uncertain = true", "uncertain = true, "
                                           "tolerance = 0.03"))
    q = next(p for p in parse_model_text(good, source="m.toml").parameters if p.name == "az12")
    assert q.uncertain and q.tolerance == 0.03

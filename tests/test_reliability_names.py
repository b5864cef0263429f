"""Names and values from a model file are checked where the file is read (issue 13).

A corpus of bad names (injection payloads, C/C++/Python keywords, Unicode look-alikes,
names the generated code uses itself, whitelisted functions, a double underscore) is put
into every name field of a model file; each must be refused at load with the field named
and nothing run. Bad values (``window = 1.5``, ``extra_residuals = "no"``, reversed
limits, ``log`` of a negative number at the operating point...) likewise. Nothing is
built, so this is fast.
"""

from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path

import pytest

from reliability_log import reporter

from fdigen.design.config import read_fdi_config
from fdigen.errors import FdigenError, ModelFileError
from fdigen.model.model_file import builtin_model_path, parse_model_text

report = reporter("model files")

MOTOR = tomllib.loads(builtin_model_path("dc_motor").read_text())
CYLINDER = tomllib.loads(builtin_model_path("pneumatic_cylinder").read_text())

def _text(v):
    """A TOML basic string (JSON escapes; non-ASCII kept as is, TOML has no surrogates)."""
    return json.dumps(str(v), ensure_ascii=False)


def _value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return _text(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return "{ " + ", ".join(f"{_text(k)} = {_value(x)}" for k, x in v.items()) + " }"


def dump_toml(doc: dict) -> str:
    """A minimal TOML writer: nested dicts become [table] headers, others inline."""
    lines = []

    def table(path, d):
        subs = [(k, v) for k, v in d.items() if isinstance(v, dict)]
        lines.extend(f"{_text(k)} = {_value(v)}" for k, v in d.items()
                     if not isinstance(v, dict))
        for k, v in subs:
            lines.append("[" + ".".join(_text(q) for q in (*path, k)) + "]")
            table((*path, k), v)

    table((), doc)
    return "\n".join(lines) + "\n"


#: Bad names: payloads, punctuation, look-alikes, keywords, generated and reserved names.
BAD_NAMES = [
    "nf_x3[__import__('os').system('touch X')]", "__import__('os').system('touch X')",
    "a;b", "x*/", "x/*", "a\nb", "a b", "", "1abc", "_x", "x_", "my__motor", "a-b",
    '"', "$(shell touch X)", "a" * 33,
    "𝐊t", "Κt", "Kt\u200b", "ｋ", "é",
    "int", "for", "return", "class", "lambda", "None", "template",
    "V_raw", "par_w", "parc_i", "par0_k1_w", "yhat_Kw", "eu_Kw", "nf_w_tach", "sched_w",
    "vd12", "dp0", "Kw_post0", "freeze", "realign_gate",
    "sin", "sqrt", "select", "maximum", "NAN", "INT32_MAX", "memcpy", "pi",
    "dc_motor_fdi_step", "DC_MOTOR_FDI_OK",
    # macros of the headers a controller or the FMU wrapper includes (attack round 2)
    "EOF", "EXIT_SUCCESS", "RAND_MAX", "M_PI", "fmi2True", "linux", "DBL_MAX", "stdout",
]


def _set(doc, field, name):
    """Put ``name`` into one name field of the model document; returns the field the
    error must name."""
    if field == "model.name":
        doc["model"]["name"] = name
    elif field in ("parameters", "states", "inputs", "outputs", "definitions", "faults"):
        spec = {"parameters": {"value": 1.0}, "states": {"unit": "A"},
                "inputs": {"unit": "V"}, "outputs": {"expr": "w"}, "definitions": "Ra",
                "faults": {"location": "plant", "mode": "additive", "target": "w",
                           "term": "0", "class": "mechanical"}}[field]
        doc.setdefault(field, {})[name] = spec
    elif field == "faults.drive.class":
        doc["faults"]["drive"]["class"] = name
        del doc["fdi"]["actions"]["drive"]
        doc["fdi"]["actions"][name] = "none"
    elif field == "inputs.V.column":
        doc["inputs"]["V"]["column"] = name
    elif field == "outputs.w_tach.column":
        doc["outputs"]["w_tach"]["column"] = name
    elif field == "fdi.parity":
        doc["fdi"]["parity"][name] = "w_tach"
        doc["fdi"]["thresholds"][name] = 1.0
    elif field == "fdi.kalman":
        doc["fdi"]["kalman"][name] = {"measurement": "w_tach"}
        doc["fdi"]["thresholds"][name] = 1.0
    elif field == "fdi.thresholds":
        doc["fdi"]["thresholds"][name] = 1.0
    elif field == "fdi.actions":
        doc["fdi"]["actions"][name] = "none"
    elif field == "simulation.input":
        doc["simulation"]["input"] = name
    else:  # pragma: no cover
        raise KeyError(field)
    return field


NAME_FIELDS = ["model.name", "parameters", "states", "inputs", "outputs", "definitions",
               "faults", "faults.drive.class", "inputs.V.column", "outputs.w_tach.column",
               "fdi.parity", "fdi.kalman", "fdi.thresholds", "fdi.actions",
               "simulation.input"]


def _load(doc, source="bad.toml"):
    model = parse_model_text(dump_toml(doc), source=source)
    read_fdi_config(model)
    return model


def _refused_naming(doc, field, name, source="bad.toml"):
    with pytest.raises(ModelFileError) as info:
        _load(doc, source)
    exc = info.value
    assert exc.source == source, exc
    assert exc.field is not None and exc.field.startswith(field.split(".")[0]), (field, exc)
    return exc


@pytest.mark.parametrize("field", NAME_FIELDS)
def test_bad_names_are_refused_in_every_name_field(field, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    fields_named = 0
    for name in BAD_NAMES:
        if field == "model.name" and name.lower().startswith("dc_motor_fdi"):
            continue  # a fine model name (its own prefix would be dc_motor_fdi_step_fdi)
        doc = copy.deepcopy(MOTOR)
        _set(doc, field, name)
        exc = _refused_naming(doc, field, name)
        fields_named += exc.field == field or exc.field.startswith(field + ".")
    assert not Path("X").exists()
    assert fields_named >= len(BAD_NAMES) - 8, fields_named   # a few are refused earlier
    report(f"test_bad_names_are_refused_in_every_name_field[{field}]",
           f"bad names in {field}: injection payloads, punctuation, Unicode look-alikes, "
           "keywords, names the generated code uses (V_raw, par_w...), functions, '__'",
           len(BAD_NAMES), "pass",
           f"every one refused with ModelFileError naming the file; {fields_named} naming "
           f"'{field}' exactly; nothing ran")


def test_voter_names_and_class_none_are_refused():
    cases = 0
    for name in ["nf_x3[__import__('os').system('touch X')]", "V_raw", "int", "x3 ", "𝐊t"]:
        doc = copy.deepcopy(CYLINDER)
        doc["fdi"]["voter"]["names"] = ["w1", name, "w3"]
        doc["fdi"]["thresholds"][name] = 0.5
        exc = _refused_naming(doc, "fdi.voter.names", name)
        assert exc.field == "fdi.voter.names", exc
        cases += 1
    for name in ("none", "None", "NONE"):
        doc = copy.deepcopy(MOTOR)
        _set(doc, "faults.drive.class", name)
        exc = _refused_naming(doc, "faults", name)
        assert exc.field == "faults.drive.class" and exc.symbol == name, exc
        cases += 1
    report("test_voter_names_and_class_none_are_refused",
           "voter names (payloads, keywords, look-alikes) and a fault class 'none'", cases,
           "pass", "refused with ModelFileError naming the field")


def test_unicode_lookalike_cannot_shadow_a_parameter():
    doc = copy.deepcopy(MOTOR)
    doc["parameters"]["𝐊t"] = {"value": 99.0}
    exc = _refused_naming(doc, "parameters", "𝐊t")
    assert "'Kt'" in str(exc), exc
    report("test_unicode_lookalike_cannot_shadow_a_parameter",
           "parameter '𝐊t' beside 'Kt' (one name after NFKC normalisation)", 1, "pass",
           "refused, the message names the normalised form")


def test_a_name_the_step_defines_is_refused_by_the_program_check():
    """The exact check behind the name patterns: a program whose assignment reuses an
    input's name is refused (V_raw as a parameter and the raw input V)."""
    import sympy as sp

    from fdigen.design.program import Program

    v_raw = sp.Symbol("V_raw", real=True)
    prog = Program({"u": (v_raw,), "p": (sp.Symbol("V_raw", real=True),)}, (), {})
    with pytest.raises(ModelFileError, match="V_raw"):
        prog.check_unique_names("m.toml")
    a = sp.Symbol("a", real=True)
    prog = Program({"u": (a,)}, ((sp.Symbol("b", real=True), a), (sp.Symbol("a", real=True), a)),
                   {})
    with pytest.raises(ModelFileError, match="'a'"):
        prog.check_unique_names("m.toml")


def _cyl_limits_reversed(doc):
    doc["states"]["x"]["limits"] = ["L", 0.0]


BAD_VALUES = [
    ("fdi.window", lambda d: d["fdi"].__setitem__("window", 1.5)),
    ("fdi.window", lambda d: d["fdi"].__setitem__("window", 0)),
    ("fdi.window", lambda d: d["fdi"].__setitem__("window", "100")),
    ("fdi.substeps", lambda d: d["fdi"].__setitem__("substeps", 0.5)),
    ("fdi.substeps", lambda d: d["fdi"].__setitem__("substeps", True)),
    ("fdi.confirm", lambda d: d["fdi"].__setitem__("confirm", 2.5)),
    ("fdi.isolate_within_classes",
     lambda d: d["fdi"].__setitem__("isolate_within_classes", 1.5)),
    ("fdi.extra_residuals", lambda d: d["fdi"].__setitem__("extra_residuals", "no")),
    ("fdi.extra_residuals", lambda d: d["fdi"].__setitem__("extra_residuals", 0)),
    ("fdi.sample_time", lambda d: d["fdi"].__setitem__("sample_time", "1e-3")),
    ("fdi.realign_noise_scale", lambda d: d["fdi"].__setitem__("realign_noise_scale", [1])),
    ("fdi.thresholds.Rw", lambda d: d["fdi"]["thresholds"].__setitem__("Rw", "2")),
    ("fdi.thresholds", lambda d: d["fdi"]["thresholds"].__setitem__("Rx", 1.0)),
    ("fdi", lambda d: d["fdi"].__setitem__("windw", 100)),
    ("fdi.kalman.Kw", lambda d: d["fdi"]["kalman"]["Kw"].__setitem__("schedul", "measured")),
    ("fdi.kalman.Kw", lambda d: d["fdi"]["kalman"]["Kw"].__setitem__("measurement", 3)),
    ("fdi.parity", lambda d: d["fdi"].__setitem__("parity", ["Rw"])),
    ("fdi.process_noise.i", lambda d: d["fdi"]["process_noise"].__setitem__("i", "5")),
    ("fdi.actions", lambda d: d["fdi"]["actions"].__setitem__("thermal", "none")),
    ("model", lambda d: d["model"].__setitem__("nmae", "x")),
    ("simulation", lambda d: d["simulation"].__setitem__("durration", 1.0)),
    ("simulation.substeps", lambda d: d["simulation"].__setitem__("substeps", 0.5)),
    ("simulation.duration", lambda d: d["simulation"].__setitem__("duration", -1.0)),
    ("simulation.initial", lambda d: d["simulation"]["initial"].__setitem__("q", 1.0)),
    (None, lambda d: d.__setitem__("fdi_extra", {"a": 1})),
    ("parameters.La", lambda d: d["parameters"]["La"].__setitem__("value", 2.0)),
    ("parameters.La.bounds", lambda d: d["parameters"]["La"].__setitem__("bounds", [1.0, 1e-6])),
    ("states.i.range", lambda d: d["states"]["i"].__setitem__("range", [5.0, -5.0])),
    ("dynamics.i", lambda d: d["dynamics"].__setitem__("i", "(V - Ra*i - Ke*w)/La + 1e-9*log(-V)")),
    ("definitions.d", lambda d: d.setdefault("definitions", {}).__setitem__("d", "sqrt(-Vnom)")),
    ("outputs.w_tach.expr", lambda d: d["outputs"]["w_tach"].__setitem__("expr", "w/(V - Vnom)")),
    ("faults.drive.term", lambda d: d["faults"]["drive"].__setitem__("term", "drive*V/(V - Vnom)")),
    ("operating_point.V", lambda d: d["operating_point"].__setitem__("V", "log(-Vnom)")),
]

CYL_BAD_VALUES = [
    ("states.x.limits", _cyl_limits_reversed),
    ("operating_point.x", lambda d: d["operating_point"].__setitem__("x", "2*L")),
    ("operating_point.Pp", lambda d: d["operating_point"].__setitem__("Pp", "0.5*Patm")),
    ("parameters.V0", lambda d: d["parameters"]["V0"].__setitem__("value", -1e-5)),
    ("fdi.voter", lambda d: d["fdi"]["voter"].__setitem__("tolerence", 1e-3)),
    ("fdi.voter.names", lambda d: d["fdi"]["voter"].__setitem__("names", "w1")),
]


def test_bad_values_are_refused_naming_the_field():
    cases = 0
    for base, table in ((MOTOR, BAD_VALUES), (CYLINDER, CYL_BAD_VALUES)):
        for field, mutate in table:
            doc = copy.deepcopy(base)
            mutate(doc)
            with pytest.raises(ModelFileError) as info:
                _load(doc)
            exc = info.value
            assert exc.source == "bad.toml", exc
            if field is None:
                assert exc.field is None and exc.symbol == "fdi_extra", exc
            else:
                assert exc.field == field, (field, str(exc))
            cases += 1
    report("test_bad_values_are_refused_naming_the_field",
           "bad values: window 1.5/0/'100', substeps 0.5/true, extra_residuals 'no'/0, "
           "mistyped numbers, unknown keys in every table, unknown residual/class, "
           "reversed bounds/range/limits, operating point outside the limits, log(-V), "
           "sqrt(-V), zero denominators at the operating point", cases, "pass",
           "every one refused with ModelFileError naming the file and the field")


def test_missing_thresholds_and_actions_are_listed_at_once():
    doc = copy.deepcopy(MOTOR)
    for key in ("Rw", "Ki"):
        del doc["fdi"]["thresholds"][key]
    for key in ("drive", "tachometer"):
        del doc["fdi"]["actions"][key]
    with pytest.raises(ModelFileError) as info:
        _load(doc)
    assert "Rw, Ki" in str(info.value), info.value
    del doc["fdi"]["thresholds"]
    doc["fdi"]["thresholds"] = dict(MOTOR["fdi"]["thresholds"])
    with pytest.raises(ModelFileError) as info:
        _load(doc)
    assert "drive, tachometer" in str(info.value), info.value
    report("test_missing_thresholds_and_actions_are_listed_at_once",
           "two thresholds, then two actions missing", 2, "pass",
           "one error lists all missing names")


def test_builtin_models_pass_the_name_rules():
    for name in ("dc_motor", "pneumatic_cylinder"):
        _load(tomllib.loads(builtin_model_path(name).read_text()), f"{name}.toml")


def test_unknown_derived_threshold_is_refused_at_design(motor):
    import dataclasses

    from fdigen.design.fdi_design import fdi_design

    fdi = dict(motor.fdi)
    fdi["thresholds"] = {**fdi["thresholds"], "R9": 1.0}
    with pytest.raises(FdigenError, match="R9"):
        fdi_design(dataclasses.replace(motor, fdi=fdi))


@pytest.mark.parametrize("command", [["inspect"], ["build", "--out", "out"], ["verify"]])
def test_cli_refuses_a_bad_name_with_exit_2(command, tmp_path, monkeypatch):
    from click.testing import CliRunner

    from fdigen.cli import main

    monkeypatch.chdir(tmp_path)
    payload = "nf_x3[__import__('os').system('touch X')]"
    doc = copy.deepcopy(MOTOR)
    _set(doc, "fdi.parity", payload)
    Path("bad.toml").write_text(dump_toml(doc))
    res = CliRunner().invoke(main, [command[0], "--model", "bad.toml", *command[1:]])
    assert res.exit_code == 2, res.output
    assert "bad.toml" in res.output and "fdi.parity" in res.output and payload in res.output
    assert not Path("X").exists() and not Path("out").exists()
    report("test_cli_refuses_a_bad_name_with_exit_2",
           "an injection payload as a [fdi.parity] name through fdigen inspect, build, verify",
           1, "pass", "exit 2, the message names the file, the field and the name; "
           "nothing ran, nothing written")

"""Attack round 5 (2026-11-28), on what this session added: balances with state-dependent
weights (the first-integral search), sensors of several states, the ``[fdi] refused``
mark. Every finding ended in an internal error (exit 3), a design that depended on the
machine's load, or a residual that was not what the table said.
"""

import json
from pathlib import Path

import pytest
import sympy as sp
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.design.decoupling import decoupling_direction, decoupling_refusal
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "attack5"


@pytest.mark.parametrize("name, balance", [
    ("fi_ratio", True),        # f*xa, f*xb: the ratio xb/xa; its unit crashed inspect
    ("fi_integral", False),    # xb*exp(sin(xa)): an integral with no closed form
    ("fi_recursion", False),   # exp(xb/xa) + xb/xa: dsolve recursed past Python's limit
    ("fi_bern", False),        # a Bernoulli equation dsolve took 6-10 s for, against 10
    ("fi_pole", False),        # xb/(xa - 1.4): a pole inside xa's range [1, 2]
])
def test_a_balance_is_found_or_refused_cleanly(name, balance, tmp_path, monkeypatch):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    model = load_model(str(DATA / f"{name}.toml"))
    found = decoupling_direction(model, model.fault("f"))
    assert (found is not None) == balance, decoupling_refusal(model, model.fault("f"))
    if not balance:
        assert "f enters xa and xb" in decoupling_refusal(model, model.fault("f"))
    res = CliRunner().invoke(main, ["inspect", "--json", "--model", str(DATA / f"{name}.toml")])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    blind = [r for r in info["extra_residuals"] if r["blind_to"] == "f"]
    assert bool(blind) == balance


def test_the_search_is_by_form_so_the_design_does_not_depend_on_the_clock(monkeypatch):
    """The search integrates separable and linear directions; it never runs a general
    solver against a CPU budget, so the same file derives the same design on a loaded
    machine: with a budget of 0.5 s the answers are those of 10 s."""
    import fdigen.design.first_integral as fi

    answers = {}
    for budget in (10.0, 0.5):
        monkeypatch.setattr(fi, "BUDGET", budget)
        out = []
        for name in ("fi_ratio", "fi_bern", "fi_pole"):
            model = load_model(str(DATA / f"{name}.toml"))
            found = fi.first_integral(*_slope(model))
            out.append(None if found is None else sp.srepr(found))
        answers[budget] = out
    assert answers[10.0] == answers[0.5]


def _slope(model):
    from fdigen.derive.nonsmooth import jacobian

    f = model.fault("f")
    e = jacobian(model.f(with_faults=True), [f.symbol]).xreplace({s: 0 for s in model.f_sym})
    xa, xb = (s.symbol for s in model.states)
    return sp.cancel(e[1] / e[0]), xa, xb


def test_a_load_step_inside_a_sensor_map_is_in_the_balance_that_reads_it(tmp_path,
                                                                        monkeypatch):
    """A user's buck converter: the load step enters the output voltage through the
    capacitor's ESR. The combination "blind to load_step" read that voltage, so it saw the
    step (2.2x its threshold), while the table said it did not and inspect called the
    table "more than the structure". A fault in a sensor's map the combination reads is
    in its signature: no residual claims what the structure forbids."""
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    res = CliRunner().invoke(main, ["inspect", "--json", "--model",
                                    str(DATA / "buck_newuser27.toml")])
    assert res.exit_code == 0, res.output
    iso = json.loads(res.output)["isolability"]
    assert iso["achieved_not_achievable"] == []
    model = load_model(str(DATA / "buck_newuser27.toml"))
    from fdigen.design.decoupling import decoupled_submodel

    signature = decoupled_submodel(model, model.fault("load_step"), "m")[-1]
    assert signature["load_step"] is True


def test_a_refusal_with_a_newline_is_refused(tmp_path):
    """``[fdi] refused`` is printed as one line: a newline could fake a line of the
    commands' own output ("diagnosis: none", "fdigen: design ACCEPTED")."""
    from fdigen.design.cache import cached_design
    from fdigen.errors import ModelFileError

    with pytest.raises(ModelFileError) as exc:
        cached_design(load_model(str(DATA / "dcm_ref_nl.toml")))
    assert "fdi.refused" in str(exc.value) and "one line" in str(exc.value)


def test_a_balance_generic_in_a_parameter_is_taken_at_its_value(tmp_path, monkeypatch):
    """``f*xb**k`` with ``k = 1``: the generic balance ``k log(xa) + xb**(1 - k) -
    log(xa)`` is constant at ``k = 1``; the direction integrated at the parameters'
    values gives ``xb/xa``. inspect had refused the model with an "unknown function
    Piecewise" the user never wrote (dsolve's case split)."""
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    model = load_model(str(DATA / "fi_pw_nan.toml"))
    found = decoupling_direction(model, model.fault("f"))
    assert found is not None
    xa, xb = (s.symbol for s in model.states)
    assert sp.simplify(found[1] - xb / xa) == 0
    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "fi_pw_nan.toml")])
    assert res.exit_code == 0, res.output

"""Attack round 11: discover's measured-input offset, the tie a free run decides, and
inspect's domain warnings (tests/data/attack11: the buffer tank of
tests/test_input_offset.py with one line changed)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

from fdigen.discover.effects import library
from fdigen.model.model_file import load_model
from fdigen.model.names import MAX_NAME_LENGTH

DATA = Path(__file__).parent / "data" / "attack11"
RIG = Path(__file__).parent / "data" / "input_offset" / "rig.py"


@pytest.fixture(scope="module")
def tank_log(tmp_path_factory):
    spec = importlib.util.spec_from_file_location("input_offset_rig", RIG)
    rig = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rig)
    path = tmp_path_factory.mktemp("a11") / "tank.csv"
    rig.write_log(path)
    return path


def _discover(log, model, out):
    proc = subprocess.run([sys.executable, "-m", "fdigen.cli", "discover", str(log),
                           "--model", str(model), "--out", str(out), "--no-build",
                           "--no-fdi", "--json"], capture_output=True, text=True,
                          env={**os.environ, "FDIGEN_CACHE": str(out) + "_cache"},
                          timeout=600)
    return proc


def _offset(model):
    (e,) = [e for e in library(model) if e.family == "input_offset"]
    return e


def test_exp_of_one_reads_back_as_exp_of_one_not_the_models_E():
    """``exp(qin/12 + 1)`` expanded to ``E*exp(qin/12)`` and printed ``E``: read back as
    the model's own parameter E = 1000, the term was 368 times f(u + off) - f(u)."""
    m = load_model(DATA / "m_E_param.toml")
    e = _offset(m)
    assert "E" not in e.text("h").replace("exp", "")
    from fdigen.model.expression import expression_text

    assert expression_text(sp.E * sp.Symbol("x")) == "exp(1)*x"
    syms = {s.name: s.symbol for s in [*m.parameters, *m.states, *m.inputs]}
    off = sp.Symbol(e.parameters[0].name, real=True)
    f = m.f()[0]
    want = f.xreplace({syms["qin"]: syms["qin"] + off}) - f
    got = m.expand(e.terms(m)["h"])
    at = {syms["qin"]: 5.0, syms["h"]: 40.0, off: 0.4, **m.parameter_values}
    assert float(got.xreplace(at)) == pytest.approx(float(want.xreplace(at)), rel=1e-12)


def test_a_huge_expansion_is_not_attempted():
    """``1e-40*((qin + h)**7 + 1)**7``: the expanded difference has about 32 million
    terms; discover ran out of memory (killed, no message)."""
    m = load_model(DATA / "m_pow2.toml")
    e = _offset(m)
    assert len(e.text("h")) < 200            # the difference itself, not its expansion


def test_a_long_input_names_offset_gets_a_name_a_model_file_holds(tank_log, tmp_path):
    """A 32-character input: ``off_<name>`` (36) was refused only when discover wrote its
    file, after the whole search, naming that file."""
    m = load_model(DATA / "m_long.toml")
    (p,) = _offset(m).parameters
    assert len(p.name) <= MAX_NAME_LENGTH and p.name.startswith("off_qabc")
    proc = _discover(tank_log, DATA / "m_long.toml", tmp_path / "d")
    assert proc.returncode == 0, proc.stderr[-2000:]
    info = json.loads(proc.stdout)
    assert p.name in info["parameters"]
    written = load_model(info["model_file"])
    assert p.name in {q.name for q in written.parameters}


def test_an_offset_that_takes_sqrt_below_zero_is_a_losing_candidate(tank_log, tmp_path):
    """``2*sqrt(qin)`` with ``off_qin`` down to -3 L/min under a log down to 0.5: scipy
    raised "array must not contain infs or NaNs" and discover exited 3 (internal error)."""
    proc = _discover(tank_log, DATA / "r_sqrt.toml", tmp_path / "d")
    assert proc.returncode == 0, proc.stderr[-2000:]
    info = json.loads(proc.stdout)
    assert "input_offset_qin" in {c["effect"] for c in info["candidates"]}


def test_a_diverged_free_run_is_an_infinite_error():
    from types import SimpleNamespace

    from fdigen.discover import fit_report

    calls = {}

    def fake_output_error(data, effects, params, mask, reinit):
        calls["n"] = 1
        return {"rms": {"level": float("nan"), "other": 0.2}}

    model = SimpleNamespace(derived=lambda key: {"stable": True})
    import fdigen.discover.report as report
    old = report.output_error
    report.output_error = fake_output_error
    try:
        ratio = fit_report.free_run_ratios(model, SimpleNamespace(dt=1.0), np.ones(40, bool),
                                           (), {}, {"level": 0.05, "other": 0.1})
    finally:
        report.output_error = old
    assert ratio == {"level": float("inf"), "other": pytest.approx(2.0)}

"""Plants a user wrote from the README alone (tests/data/newuser17): a pump filling a
pressurised vessel through a check valve, pressures in kPa, its flow a definition that
a flow meter reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fdigen.detect import summarise_run
from fdigen.design.cache import cached_design
from fdigen.backends.reference import ReferenceFdi
from fdigen.model.model_file import load_model
from fdigen.sim.plant import FaultEvent, simulate

DATA = Path(__file__).parent / "data" / "newuser17"


def test_the_action_explanation_names_the_classes_the_core_acted_on():
    """Pump wear: the flags named the wear alone (a structural residual, fault-level,
    excludes the others) while the class decision, which does not read that residual,
    held the pressure sensor too and took its action, accommodate. detect said
    "accommodate ... every consistent class calls for it: pump" although pump's action is
    none. The explanation now lists the classes the core's decision held."""
    model = load_model(str(DATA / "pump.toml"))
    design = cached_design(model)
    ev = design.evaluation
    sim = simulate(model, 900.0, faults=(FaultEvent("wear", 600.0, 0.05),), seed=0)
    out = ReferenceFdi(design).run(sim.u, sim.y)
    d = summarise_run(design, sim.t, out)["diagnosis"]
    assert d["consistent_faults"] == ["wear"] and d["fault"] == "none"
    assert "pressure_sensor" in d["action_classes"]
    k = int(np.flatnonzero(out["action"])[0])
    held = int(out["flags"][k]) & ev.class_flags
    core = {ev.classes[c] for mask, c in ev.patterns if held & ~mask == 0}
    assert set(d["action_classes"]) == core
    codes = {ev.action_codes[ev.classes.index(c)] for c in core}
    assert d["action"] == ("none", "accommodate", "safety_stop")[max(codes)]
    assert d["action_basis"] == ("unanimous" if len(codes) == 1 else "most_severe")
    own = model.fdi["actions"]
    assert d["action_basis"] != "unanimous" or all(own[c] == d["action"] for c in core)


def test_no_effect_is_chosen_against_a_calibration_that_did_not_converge(monkeypatch):
    """A user's heating zone: every output-error fit stopped before converging, and two
    sensor offsets were chosen (one whose parameter moved no output) and committed. An
    effect's gain against a calibration that did not converge may be that calibration's
    own unfinished descent: none is chosen, and an effect whose parameter is alone in a
    blind direction of the final fit is refused."""
    from types import SimpleNamespace

    from fdigen.discover import output_loop
    from fdigen.discover.fit_checks import blind_effect
    from fdigen.sim.log import read_log

    data = Path(__file__).parent / "data" / "newuser16"
    model = load_model(str(data / "two_tank_untuned.toml"))
    lg = read_log(data / "tanks_lagged_l2.csv", model)
    real = output_loop._fit
    calls = []

    def stopped(*args, **kw):
        fit = real(*args, **kw)
        calls.append(args[3])
        fit.success = False               # as IPOPT at its iteration limit
        return fit

    monkeypatch.setattr(output_loop, "_fit", stopped)
    base, final, chosen, cands = output_loop.explain_by_output_error(
        model, lg, None, ["a1", "a2", "kp"])
    assert chosen == [] and cands == [] and final is base
    assert calls == [()]                  # no candidate was even fitted
    offset = SimpleNamespace(name="sensor_offset_y2",
                             parameters=(SimpleNamespace(name="off_y2"),))
    leak = SimpleNamespace(name="leak_sqrt_h1", parameters=(SimpleNamespace(name="Kl_h1"),))
    fit = SimpleNamespace(null_directions=[{"off_y2": 1.0, "a1": 0.02}])
    assert blind_effect([leak, offset], fit) is offset
    fit = SimpleNamespace(null_directions=[{"Kl_h1": 1.0, "a1": -0.9}])   # a scale
    assert blind_effect([leak, offset], fit) is None


def test_a_python_conditional_is_refused_with_the_functions_to_write_it():
    """A user wrote a check valve as ``Kp*sqrt(hp - p) if hp > p else 0``: refused
    (models are parsed, never evaluated), and the message now says how to write it."""
    import pytest

    from fdigen.errors import ModelFileError
    from fdigen.model.model_file import parse_model_text

    text = (DATA / "pump.toml").read_text()
    bad = text.replace('[definitions]\n', '[definitions]\nqv = "Kp*sqrt(hp - p) if hp > p else 0"\n', 1)
    assert bad != text
    with pytest.raises(ModelFileError, match=r"'IfExp' is not allowed .*max\(\), min\(\)"):
        parse_model_text(bad, source="valve.toml")

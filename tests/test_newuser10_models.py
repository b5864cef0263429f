"""Plants a user wrote from the README alone (tests/data/newuser10): a vessel whose level
three transmitters read (mA, cm, kPa), one state; a boost converter (inductor current
through a Hall sensor in volts, output voltage) with no declared parity residual.

Both designs stopped short of what `inspect` itself called achievable: the vessel's leak
had an all-zero row (a one-state plant has no proper sub-model, and only the sensors'
static relations were derived), the boost converter's two sensor faults shared every
residual. The whole model checked on one sensor is now the structural selection's last
resort.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.design.cache import cached_design
from fdigen.design.structural_selection import missing_pairs
from fdigen.design.structure import isolability, model_structure
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser10"


@pytest.mark.parametrize("name", ["vessel.toml", "boost.toml"])
def test_the_design_reaches_what_the_structure_allows(name):
    model = load_model(DATA / name)
    design = cached_design(model)
    achievable = isolability(model_structure(model))
    assert missing_pairs(design.signature_table, achievable) == set()
    assert all(design.signature_table[f.name] for f in model.faults)   # no all-zero row
    whole = [e for e in design.extra_residuals if not e["drivers"]
             and e["realisation"] == "parallel model"]
    assert whole and all(set(e["equations"]) == {s.name for s in model.states} for e in whole)


def test_the_vessels_leak_is_detected_and_isolated(tmp_path):
    """Half the outlet area leaking from 300 s: flags, then the leak class; a healthy
    log of another seed stays quiet (thresholds from `tune --runs 8 --write`)."""
    model = str(DATA / "vessel.toml")
    out = {}
    for label, extra in (("leak", ["--fault", "leak@300=6e-4"]), ("healthy", ["--seed", "5"])):
        log = tmp_path / f"{label}.csv"
        assert CliRunner().invoke(main, ["simulate", "--model", model, "-o", str(log),
                                         *extra]).exit_code == 0
        res = CliRunner().invoke(main, ["detect", "--model", model, str(log)])
        assert res.exit_code == 0, res.output
        out[label] = res.output
    assert "diagnosis: leak at" in out["leak"]
    t = float(out["leak"].split("diagnosis: leak at ")[1].split(" s")[0])
    assert 300.0 < t < 450.0
    assert "diagnosis: none (no flag raised)" in out["healthy"]


def test_thresholds_that_failed_validation_say_so_in_the_file():
    """tune --write wrote thresholds that raised flags in 5 of 10 validation runs (a
    user's quadruple tank) under a header that read as a clean campaign."""
    from fdigen.tune.model_update import threshold_note

    settings = {"runs": 6, "duration": 600.0, "seed": 0, "tolerance": 0.1,
                "false_alarm_rate": 0.01, "margin": 1.25}
    clean = threshold_note(settings, {"validation_false_alarms": 0, "validation_runs": 10})
    failed = threshold_note(settings, {"validation_false_alarms": 5, "validation_runs": 10})
    assert "FAILED" not in clean
    assert failed.endswith("; FAILED validation: 5 of 10 healthy runs raised a flag)")


def test_a_pump_fault_inside_a_flow_means_the_fault_on_the_input():
    """The quadruple tank's pump wear written inside the flow definition (``q1 = (1 -
    pump1)*k1*v1``, location actuator) and as a term on the input (``v1 - pump1*v1``):
    one flow into two tanks either way. The definition spelling's structure had the fault
    in both balances, two ordered pairs fewer achievable and no residual blind to it."""
    from fdigen.design.signatures import decoupling_candidates
    from fdigen.model.model_file import parse_model_text

    text = (DATA / "quadtank.toml").read_text()
    term = text.replace('q1 = "(1 - pump1)*k1*v1"', 'q1 = "k1*v1"').replace(
        'location = "actuator"\nmode = "multiplicative"\nclass = "pump_1"',
        'location = "actuator"\nmode = "multiplicative"\ntarget = "v1"\nterm = "-pump1*v1"'
        '\nclass = "pump_1"')
    assert term != text and 'term = "-pump1*v1"' in term
    models = [parse_model_text(t, source=n) for t, n in ((text, "def.toml"),
                                                            (term, "term.toml"))]
    structures = [isolability(model_structure(m)) for m in models]
    assert structures[0] == structures[1]
    blind = [{c.decoupled for c in decoupling_candidates(m, [f.name for f in m.faults])}
             for m in models]
    assert blind[0] == blind[1] and "pump1" in blind[0]


def test_a_symbolic_budget_spent_once_is_not_spent_again(tmp_path, monkeypatch):
    """A user's ball screw spent its 60 s symbolic budget again in every command (two
    minutes an inspect, a build, a commission) for a numeric fallback it had taken
    already: the over-budget mark is kept in the cache, keyed by the physics and the code."""
    import warnings

    from fdigen.derive import observability
    from fdigen.errors import FdigenNote
    from fdigen.model.model_file import builtin_model_path

    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path))
    monkeypatch.setenv("FDIGEN_SYMBOLIC_BUDGET", "0.001")
    model = load_model(builtin_model_path("pneumatic_cylinder"))
    notes = []
    from sympy.core.cache import clear_cache

    for _ in range(2):
        observability._REDUCTIONS.clear()          # a new command: nothing in memory
        clear_cache()       # (sympy's own, warm from other tests: under 1 ms of CPU)
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always", FdigenNote)
            red = observability.observable_reduction(model, ("x3",))
        notes.append([str(w.message) for w in seen if issubclass(w.category, FdigenNote)])
        assert red.numeric_fallback
    assert notes[0] and "exceeded its budget" in notes[0][0]
    assert "not tried again" not in notes[0][0]
    assert notes[1] and notes[1][0].endswith("known from an earlier attempt, not tried again")
    assert len(list((tmp_path / "over_budget").iterdir())) == 1

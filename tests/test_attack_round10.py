"""Attack round 10 (tests/data/attack10): this session's own features, attacked.

* inspect judged a residual without a designed threshold against the 1e30 stand-in;
* a fault without a test size was judged at a size of 1;
* a filter with a pole at 1 - 1e-8 was followed for 100,000 samples per fault in Python
  (86 s for ten filters);
* report drew a log whose command was missing on 998 of 1000 rows and said nothing of it;
* one stiff tolerance vertex raised every campaign run to 31,904 RK4 sub-steps (hours);
* ``CFdi.core_run`` took a transposed ``y`` of the right size;
* ``uncertain = "false"`` made a parameter uncertain.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.errors import ModelFileError
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "attack10"


def _settled(path):
    res = CliRunner().invoke(main, ["inspect", "--model", str(path), "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)["isolability"]


def test_a_residual_without_a_threshold_is_judged_against_three_sigma():
    iso = _settled(DATA / "f1_placeholder_threshold.toml")
    entries = [e for es in iso["settled_responses"].values() for e in es.values()]
    assert entries and all(e["threshold"] is None for e in entries)
    for e in entries:
        assert e["seen"] == (np.hypot(e["noise"], e["rms_peak"]) > 3 * e["noise"])
    # the 20 % torque-constant loss (test size 4 here) is seen: no pair lost through it
    assert iso["settled_responses"]["R1"]["kt_loss"]["seen"]
    assert ["kt_loss", "fric"] not in iso["transient_only_pairs"]


def test_a_fault_without_a_test_size_is_not_judged():
    iso = _settled(DATA / "f2_test_size_zero.toml")
    assert "kt_loss" not in iso["settled_responses"].get("R1", {})
    assert "stiff_loss" in iso["settled_responses"]["R1"]


def test_slow_filters_are_followed_for_a_bounded_horizon_and_make_no_claim():
    """Ten filters with their slowest pole at 1 - 7e-9: followed for at most
    MAX_SAMPLES samples (all faults of a filter at once), and a response not settled by
    then is no claim."""
    from fdigen.design.cache import cached_design
    from fdigen.design.settled_response import MAX_SAMPLES, settled_responses

    design = cached_design(load_model(DATA / "f3_slow_filters.toml"))
    assert len(design.kalman) == 10
    assert MAX_SAMPLES <= 20000
    assert settled_responses(design) == {}


@pytest.mark.parametrize("log, said", [
    ("f4_outage_log.csv", "logger outage (a command missing), not diagnosed"),
    ("f4_dup_log.csv", "1000 duplicated rows (written twice, stamp and values) dropped")])
def test_report_says_what_reading_the_log_did(tmp_path, log, said):
    res = CliRunner().invoke(main, ["report", "--model", "dc_motor", str(DATA / log),
                                    "-o", str(tmp_path / "r.html")])
    assert res.exit_code == 0, res.output
    assert said in res.output
    det = CliRunner().invoke(main, ["detect", "--model", "dc_motor", str(DATA / log)])
    assert said in det.output


def test_a_stiff_vertex_raises_the_campaign_at_most_four_times_and_says_so():
    from fdigen.sim.substeps import CAMPAIGN_SUBSTEP_FACTOR, simulation_substeps
    from fdigen.tune.run_notes import substeps_raise
    from fdigen.tune.settings import TuneSettings

    model = load_model(DATA / "f5_stiff_vertex.toml")
    nominal = simulation_substeps(model, model.fdi["sample_time"])
    raised = substeps_raise(model, TuneSettings(runs=2, duration=1.0))
    assert raised["needed"] > 1000 * nominal
    assert raised["used"] == CAMPAIGN_SUBSTEP_FACTOR * nominal
    assert "kk +10 %" in raised["text"] and "may diverge" in raised["text"]


def test_core_run_refuses_a_log_of_the_wrong_shape():
    from fdigen.backends.c import CFdi
    from fdigen.design.cache import cached_design
    from fdigen.sim.plant import simulate

    model = load_model("dc_motor")
    design = cached_design(model)
    c = CFdi(design)
    sim = simulate(model, 0.05, seed=1)
    z0 = np.zeros(c.nz)
    ok = c.core_run(z0, sim.u, sim.y, 10)
    assert ok.shape == (len(sim.u), c.nr)
    for u, y in ((sim.u, np.ascontiguousarray(sim.y.T)), (sim.u, sim.y.ravel()),
                 (sim.u[:0], sim.y[:0]), (sim.u.ravel(), sim.y)):
        with pytest.raises(ValueError, match=r"u must be \(K, "):
            c.core_run(z0, u, y, 10)


def test_uncertain_must_be_a_boolean():
    with pytest.raises(ModelFileError, match=r"expected true or false, got 'no'"):
        load_model(DATA / "f7_uncertain_string.toml")

"""Plants a first-time user wrote from the README alone (stop of 2026-11-27, newuser6).

* ``li_cell.toml``: a Li-ion cell (coulomb counting, one RC pair, a cubic OCV); its
  terminal voltage ``OCV - Vp - R0 (1 + rinc) I`` reads the input current directly. The
  simulator measured every output with the inputs at zero, so the ohmic drop and the
  resistance fault never reached a simulated log; the Kalman residual's prediction left
  the feedthrough out, so a healthy log under load kept it at ``R0 |I|``.
* ``two_mass.toml``: a two-mass drive whose shaft-stiffness fault enters both speed
  balances through the unmeasured twist: ``inspect`` ended in an internal KeyError (the
  combination that cancels the fault cancels the twist too, and the twist was taken for
  a measured state).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.backends.reference import ReferenceFdi
from fdigen.cli import main
from fdigen.design.cache import cached_design
from fdigen.model.model_file import load_model, parse_model_text
from fdigen.sim.plant import FaultEvent, simulate

DATA = Path(__file__).parent / "data" / "newuser6"
CELL = DATA / "li_cell.toml"


@pytest.fixture(scope="module")
def cell():
    return load_model(CELL)


def test_a_simulated_output_reads_the_input_it_feeds_through(cell):
    """Same plant, terminal voltage with and without ``R0 I``: the logs differ by exactly
    ``R0 I`` at every sample (the current is the logged input of that row)."""
    text = CELL.read_text()
    assert 'expr = "OCV - Vp - R0eff*I"' in text
    no_r0 = parse_model_text(text.replace('expr = "OCV - Vp - R0eff*I"', 'expr = "OCV - Vp"'),
                             source="no_r0.toml")
    a = simulate(cell, 600.0, noise=False)
    b = simulate(no_r0, 600.0, noise=False)
    np.testing.assert_allclose(a.u, b.u, rtol=0, atol=0)
    np.testing.assert_allclose(b.y[:, 0] - a.y[:, 0], 0.03 * a.u[:, 0], rtol=1e-9, atol=1e-12)
    # the resistance fault (inside a definition of the output map) now changes the log
    f = simulate(cell, 600.0, noise=False, faults=[FaultEvent("rinc", 300.0, 0.5)])
    after = a.t >= 300.0
    np.testing.assert_allclose(a.y[after, 0] - f.y[after, 0], 0.015 * a.u[after, 0],
                               rtol=1e-9, atol=1e-12)
    assert np.array_equal(a.y[~after], f.y[~after])


def test_the_kalman_prediction_adds_the_feedthrough(cell):
    """The filter's measured expression has ``D_r = -R0``; on a noise-free healthy log that
    starts at the operating point, the innovation stays at the linearisation's error
    (the cubic OCV away from 0.6), far below the ``R0 |I|`` of up to 0.135 V it had."""
    design = cached_design(cell)
    kr = {k.residual: k for k in design.kalman}["Kv"]
    assert kr.discrete.D[0, 0] == pytest.approx(-0.03, rel=1e-12)
    run = simulate(cell, 600.0, noise=False, initial={"SOC": 0.6, "Vp": 0.0})
    out = ReferenceFdi(design).run(run.u, run.y)
    r = np.asarray(out["r"])[:, design.residual_names.index("Kv")]
    assert np.max(np.abs(r[40:])) < 0.01, np.max(np.abs(r[40:]))
    assert np.max(0.03 * np.abs(run.u[40:, 0])) > 0.1


def test_a_fault_cancelled_with_an_unmeasured_state_derives(tmp_path):
    """kloss scales the shaft torque ``ks th``, which enters both speed balances: the
    combination of the two balances cancels it and the twist with it (a sub-model of one
    state driven by both speed sensors, blind to kloss and to nothing else); ``inspect``
    exits 0."""
    from fdigen.design.decoupling import decoupled_submodel

    model = load_model(DATA / "two_mass.toml")
    sub, drivers, measured, _, _, signature = decoupled_submodel(
        model, model.fault("kloss"), "m_kloss")
    assert [s.name for s in sub.states] == ["m_kloss"]
    assert set(drivers) == {"wm", "wl"}
    assert signature == {"kloss": False, "dTL": True, "encg": True, "tloss": True}
    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "two_mass.toml")])
    assert res.exit_code == 0, res.output
    assert "internal error" not in res.output


def test_a_definitions_fault_has_one_structure_whatever_its_location():
    """A valve blockage written inside a definition (``Kin (1 - block) u sqrt(Ps - P)``)
    as ``location = "actuator"`` and as ``"plant"``: the same equations entered, the same
    achievable isolability (the actuator spelling made it undetectable structurally and
    suggested 'a sensor on  as the actuator delivers it' with an empty input name)."""
    from fdigen.design.structure import isolability, model_structure

    path = DATA / "gas_vessel.toml"
    text = path.read_text()
    assert text.count('location = "actuator"') == 1
    actuator = load_model(path)
    plant = parse_model_text(text.replace('location = "actuator"', 'location = "plant"'),
                             source="plant.toml")
    sa, sp_ = model_structure(actuator), model_structure(plant)
    assert sa.faults == sp_.faults and sa.faults["block"] == frozenset({"e_P"})
    assert sa.equations == sp_.equations
    assert isolability(sa) == isolability(sp_)
    assert isolability(sa)[("block", "block")]
    res = CliRunner().invoke(main, ["inspect", "--model", str(path)])
    assert res.exit_code == 0 and "a sensor on  as" not in res.output, res.output


def test_tune_says_when_a_threshold_is_set_by_the_start(tmp_path):
    """The cell's filter starts its charge state at the operating point (0.6), the plant at
    0.8: its innovation converges over the first 1000 s and its threshold is set there.
    ``tune`` says so (``false_alarm.early_peaks`` and a warning); a residual whose maximum
    is not far above its second half is not named."""
    import json

    from fdigen.tune.run_notes import EARLY_PEAK_FACTOR, early_peaks

    runs = [{"max_rms": {"A": 3.0, "B": 1.0}, "max_rms_late": {"A": 0.5, "B": 0.9},
             "t_max": {"A": 40.0 + k, "B": 500.0}} for k in range(3)]
    found = early_peaks(runs, ["A", "B"], 30.0)
    assert set(found) == {"A"} and found["A"]["ratio"] == 6.0 > EARLY_PEAK_FACTOR
    assert found["A"]["median_t_max"] == 41.0
    res = CliRunner().invoke(main, ["tune", "--model", str(CELL), "--runs", "3",
                                    "--validation-runs", "1", "--fault-sizes", "1",
                                    "--fault-starts", "1", "--horizon-runs", "0",
                                    "--duration", "1200", "--scheduler", "synchronous",
                                    "--no-realign-search", "--json"])
    assert res.exit_code == 0, res.output
    peaks = json.loads(res.stdout)["false_alarm"]["early_peaks"]
    assert "Kv" in peaks and peaks["Kv"]["ratio"] > 10


def _report(detected: dict, masked=False, wrong=0, fa=0, keys=None):
    """A tune report reduced to what the realignment search reads: per (fault, kind) at
    the test size, (detected runs, isolated runs) out of 2."""
    faults = {}
    for (name, kind), (det, iso) in detected.items():
        faults.setdefault(name, {"by_size": []})["by_size"].append(
            {"factor": 1.0, "kind": kind, "runs": 2, "detected": det, "isolated_correct": iso})
    missing = [(n, k) for (n, k), (det, _) in detected.items() if det < 2]
    return {"faults": faults, "wrong_isolations_by_class": {"c": wrong},
            "false_alarm": {"validation_false_alarms": fa},
            "parameter_masking": [{"fault": n, "kind": k, "masked": masked,
                                   "below_noise": False} for n, k in missing],
            "residual_keys": keys or {"R2": "parallel model: equations [T]"}}


def test_the_realignment_search_takes_only_a_better_design(tmp_path):
    """The search tries the ladder's scales above the model's in order, stops at the first
    that detects more (and isolates no less, with no more wrong isolations or false
    alarms), writes each tried scale into a copy of the model file, and tries nothing
    when the misses are masked by the spread or the design has no parallel model.
    (The user's CSTR, `tune --runs 20 --validation-runs 5 --fault-sizes 0.5,1,2
    --fault-starts 1 --horizon-runs 2`, measured by hand: the valve loss missed with 0
    and 0.05, detected with 0.2, which `--write` writes: docs/isolation.md.)"""
    from fdigen.tune.realign_search import LADDER, better, campaign_score, search_realignment

    path = DATA / "cstr.toml"
    model = load_model(path)
    base = _report({("valve", "step"): (0, 0), ("deact", "step"): (2, 0)})
    outcomes = {0.05: _report({("valve", "step"): (0, 0), ("deact", "step"): (2, 0)}),
                0.2: _report({("valve", "step"): (2, 0), ("deact", "step"): (2, 0)})}
    seen = []

    def run(alt_path):
        scale = load_model(alt_path).fdi["realign_noise_scale"]
        seen.append(scale)
        return outcomes[scale]

    res = search_realignment(path, base, model, run)
    assert seen == [0.05, 0.2] == list(LADDER[:2])
    assert res["taken"] and res["scale"] == 0.2
    assert [t["scale"] for t in res["tried"]] == [0.05, 0.2]
    assert ("valve", "step") in map(tuple, res["after"]["detected"])
    # more detected but a wrong isolation, or a false alarm more: not better
    worse = campaign_score(_report({("valve", "step"): (2, 0), ("deact", "step"): (2, 0)},
                                   wrong=1))
    assert not better(campaign_score(base), worse)
    # a miss the spread masks, or no parallel model: nothing tried
    assert search_realignment(path, _report({("valve", "step"): (0, 0)}, masked=True),
                              model, run) is None
    assert search_realignment(path, _report({("valve", "step"): (0, 0)},
                                            keys={"R1": "Kalman filter: [CA]"}),
                              model, run) is None


@pytest.mark.skipif(__import__("os").environ.get("FDIGEN_FULL_SWEEP") != "1",
                    reason="FDIGEN_FULL_SWEEP=1: four tune campaigns of the CSTR, about 40 s")
def test_tune_default_path_finds_the_realignment_that_detects_the_valve(tmp_path):
    """The user's CSTR through `tune --write`'s default path. When this test was written
    the valve loss was missed with the file's design (no realignment) and the search took
    a stronger realignment that detected it. Since the whole model checked on one sensor
    became the structural selection's last resort (docs/isolation.md section 16), the
    file's own design detects the valve (R3, [CA, T] checked on iA): the search still runs
    (a thermometer step is missed by the design's fault), finds no scale that detects more
    with nothing worse, takes none, and the file keeps its scale. The search's taking
    path is checked on reports in test_the_realignment_search_takes_only_a_better_design."""
    import json
    import shutil

    path = tmp_path / "cstr.toml"
    shutil.copy(DATA / "cstr.toml", path)
    res = CliRunner().invoke(main, ["tune", "--model", str(path), "--runs", "20",
                                    "--validation-runs", "5", "--fault-sizes", "0.5,1,2",
                                    "--fault-starts", "1", "--horizon-runs", "2", "--write",
                                    "--json"])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.stdout)
    search = rep["realign_search"]
    assert ["valve", "step"] in search["before"]["detected"]
    assert [t["scale"] for t in search["tried"]] == [0.05, 0.2, 1.0]
    assert not search["taken"]
    assert "realign_noise_scale" not in load_model(path).fdi


def test_thresholds_wide_of_their_span_start_the_search_and_fewer_is_better(tmp_path):
    """A user's water network, open loop: nothing missed at the test size, but its level
    threshold was 93 % of the transmitter's span and tune never tried a realignment. A
    threshold of 25 % of its span or more starts the search; a scale that removes it
    with nothing worse is taken, one that adds one never is."""
    from fdigen.cli.tune_view import realign_text
    from fdigen.tune.realign_search import search_realignment, search_reason

    path = DATA / "cstr.toml"
    model = load_model(path)
    base = {**_report({("valve", "step"): (2, 0)}),
            "thresholds_wide": {"R2": {"output": "T", "threshold": 0.9, "span": 1.0}}}
    assert "threshold R2 of at least 25 % of its sensor's span" in search_reason(base)
    outcomes = {0.05: {**_report({("valve", "step"): (2, 0)}), "thresholds_wide": {
                    "R1": {}, "R2": {}}},
                0.2: _report({("valve", "step"): (2, 0)})}
    res = search_realignment(path, base, model,
                             lambda p: outcomes[load_model(p).fdi["realign_noise_scale"]])
    assert res["taken"] and res["scale"] == 0.2
    assert [t["scale"] for t in res["tried"]] == [0.05, 0.2]
    text = realign_text(res)
    assert text.startswith("realignment search (threshold R2 of at least 25 %")
    assert "  0.05: detected valve step; isolated 0 cases" in text and "R1, R2" in text
    # one line per scale, and why the one taken was taken
    assert "-> 0.2 taken: it has fewer thresholds of a large part of their sensor's " \
        "span" in text
    # a better scale that leaves a wide threshold is tried against the next one
    outcomes = {0.05: {**_report({("valve", "step"): (2, 1)}), "thresholds_wide": {"R2": {}}},
                0.2: {**_report({("valve", "step"): (2, 1)}), "thresholds_wide": {}},
                1.0: _report({("valve", "step"): (2, 2)})}
    res = search_realignment(path, base, model,
                             lambda p: outcomes[load_model(p).fdi["realign_noise_scale"]])
    assert res["taken"] and res["scale"] == 0.2
    assert [t["scale"] for t in res["tried"]] == [0.05, 0.2]     # nothing wide left
    # nothing missed and nothing wide: no search
    assert search_realignment(path, _report({("valve", "step"): (2, 0)}), model,
                              lambda p: None) is None

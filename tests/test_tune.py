"""``fdigen tune``: the Monte Carlo threshold design, its statistics and the TOML writer."""

from __future__ import annotations

import math
import shutil
import tomllib

import numpy as np
import pytest
from scipy import stats

from fdigen.model.model_file import builtin_model_path, load_model
from fdigen.tune import (TuneSettings, clopper_pearson_upper, demand_expression, fit_maxima,
                         gev_cdf, gev_quantile, round_up, summarise_faults, tune,
                         updated_model_text, write_thresholds)
from fdigen.design.config import read_fdi_config
from fdigen.tune.cases import plant_time_scale, ramp_rate
from fdigen.tune.fault_summary import poorly_isolated, wrong_isolations_by_class

FAULT_KEYS = {"class", "ramp", "runs", "detected", "missed", "detection_delay",
              "isolated_correct", "false_isolations", "not_isolated", "isolation_delay",
              "false_alarms_before_onset", "isolated_as", "by_size"}
DELAY_KEYS = {"n", "min", "median", "max"}


@pytest.fixture(scope="module")
def smoke():
    """A tiny campaign: 4 healthy runs of 3 s, 1 validation run, 2 faults x 1 size."""
    settings = TuneSettings(runs=4, duration=3.0, validation_runs=1, fault_factors=(1.0,),
                            fault_starts=1, faults=("leak_p", "pressure_sensor_n"), seed=3)
    return tune(None, settings, scheduler="synchronous", progress=False)


# -- the smoke campaign ------------------------------------------------------------------
def test_smoke_thresholds_finite_and_above_every_healthy_rms(smoke):
    names = smoke["residuals"]
    J = np.array([smoke["thresholds"][n] for n in names])
    assert np.all(np.isfinite(J)) and np.all(J > 0)
    healthy = smoke["runs"]["healthy"]
    assert len(healthy) == 4
    for run in healthy:
        assert np.all(np.array([run["max_rms"][n] for n in names]) < J)
        assert np.all(np.array([run["max_rms_startup"][n] for n in names]) < J)
    # 4 runs: no extreme-value fit, and the report says so
    assert smoke["false_alarm"]["basis"].startswith("empirical")
    assert smoke["false_alarm"]["fitted"] is None
    assert all(s["basis"] == "empirical"
               for s in smoke["threshold_statistics"]["residuals"].values())
    # the TOML literal is the value used in the design, rounded up
    for n in names:
        assert float(smoke["threshold_text"][n]) == smoke["thresholds"][n]
        assert smoke["thresholds"][n] >= smoke["threshold_statistics"]["margin"] * max(
            r["max_rms"][n] for r in healthy)
    # only the residuals [fdi.thresholds] controls are tuned
    assert set(names) == set(load_model().fdi["thresholds"])


def test_smoke_fault_summary_has_the_delays(smoke):
    faults = smoke["faults"]
    assert set(faults) == {"leak_p", "pressure_sensor_n"}
    for name, entry in faults.items():
        assert FAULT_KEYS <= set(entry)
        assert set(entry["detection_delay"]) == DELAY_KEYS
        assert set(entry["isolation_delay"]) == DELAY_KEYS
        n = 2 if entry["ramp"] else 1     # additive sensor faults: a step and a ramp
        assert entry["runs"] == n == entry["detected"] + entry["missed"]
        assert [b["kind"] for b in entry["by_size"]] == ["step", "ramp"][:n]
    assert faults["pressure_sensor_n"]["ramp"] and not faults["leak_p"]["ramp"]
    step, ramp = faults["pressure_sensor_n"]["by_size"]
    model = load_model()
    assert step["size"] == model.fault("pressure_sensor_n").test_size
    # the ramp's rate: test_size over the plant's slowest time constant (or one window)
    cfg = read_fdi_config(model)
    window = cfg.window * cfg.sample_time        # 0.2 s, longer than the plant's 0.06 s
    assert plant_time_scale(model) < window
    assert ramp["size"] == pytest.approx(step["size"] / window)
    for run in smoke["runs"]["fault"]:
        if run["detected"]:
            assert run["detection_delay"] >= 0
    # 8 runs and the 4 vertices of the cylinder's two uncertain parameters
    assert len(smoke["runs"]["vertex"]) == 4
    assert smoke["timing"]["samples"] == (8 + 4) * 3000


def test_fault_summary_counts():
    base = {"fault": "f", "fault_class": "c", "ramp": False, "factor": 1.0, "size": 1.0,
            "false_alarm_before_onset": False}
    runs = [dict(base, detected=True, detection_delay=0.1, isolated="c",
                 isolation_delay=0.3, isolation_correct=True),
            dict(base, detected=True, detection_delay=0.2, isolated="other",
                 isolation_delay=None, isolation_correct=False),
            dict(base, detected=False, detection_delay=None, isolated="none",
                 isolation_delay=None, isolation_correct=False, size=2.0, factor=2.0)]
    s = summarise_faults(runs)["f"]
    assert (s["detected"], s["missed"], s["isolated_correct"], s["false_isolations"],
            s["not_isolated"]) == (2, 1, 1, 1, 1)
    assert s["detection_delay"] == {"n": 2, "min": 0.1, "median": pytest.approx(0.15),
                                    "max": 0.2}
    assert [b["size"] for b in s["by_size"]] == [1.0, 2.0]
    # wrong isolations per class: the class isolated while another's fault was injected
    assert wrong_isolations_by_class(runs) == {"other": 1}
    # rates per size; isolated in 1 of the 2 runs at test size: below 90 %, warned
    assert [(b["kind"], b["detection_rate"], b["isolation_rate"]) for b in s["by_size"]] \
        == [("step", 1.0, 0.5), ("step", 0.0, 0.0)]
    assert s["isolation_rate_at_test_size"] == 0.5
    assert poorly_isolated({"f": s}, ["f"]) == {"f": 0.5}
    assert poorly_isolated({"f": s}, []) == {}


def test_ramp_rate_from_the_plant_time_scale_or_the_model_file():
    """A sensor drift reaches test_size after the slowest time constant (three tanks:
    ~515 s, not test_size per second); ``test_rate`` in the model file overrides it."""
    import dataclasses

    model = load_model(builtin_model_path("three_tank"))
    tau = plant_time_scale(model)
    A = __import__("fdigen.derive.linearisation", fromlist=["linearise"]).linearise(model).A
    assert tau == pytest.approx(1 / np.abs(np.linalg.eigvals(A).real).min())
    assert 100 < tau < 2000
    s1 = model.fault("s1")
    assert ramp_rate(model, s1, 10.0) == pytest.approx(s1.test_size / tau)
    assert ramp_rate(model, s1, 1e4) == pytest.approx(s1.test_size / 1e4)   # window longer
    assert ramp_rate(model, dataclasses.replace(s1, test_rate=2e-4), 10.0) == 2e-4
    # a run whose time after the onset is shorter than the time constant: the drift
    # reaches its test size half-way through it (the other half detects it)
    assert ramp_rate(model, s1, 10.0, 300.0) == pytest.approx(s1.test_size / 150.0)
    assert ramp_rate(model, s1, 10.0, 1e5) == pytest.approx(s1.test_size / tau)


def test_test_rate_is_parsed_and_checked(tmp_path):
    from fdigen.errors import ModelFileError
    from fdigen.model.model_file import parse_model_text

    text = builtin_model_path("three_tank").read_text()
    assert "test_rate" not in text
    marked = text.replace("test_size = 0.02", "test_size = 0.02\ntest_rate = 2e-4", 1)
    model = parse_model_text(marked, source="t.toml")
    assert [f.test_rate for f in model.faults if f.test_rate is not None] == [2e-4]
    with pytest.raises(ModelFileError, match="test_rate"):
        parse_model_text(marked.replace("test_rate = 2e-4", 'test_rate = "fast"'),
                         source="t.toml")


def test_smoke_campaign_isolates_to_the_fault_and_never_wrongly(smoke):
    assert smoke["wrong_isolations_by_class"] == {}
    for run in smoke["runs"]["fault"]:
        if run["false_alarm_before_onset"]:
            # thresholds from 4 runs of 3 s: a flag before the onset breaks assumption (A3)
            # of docs/isolation.md (the sensor ramp's run drew one); it must not isolate
            assert run["isolated"] in ("none", run["fault_class"])
            continue
        assert run["fault"] in run["faults_consistent"]
        assert set(run["entry_delays"]) <= set(smoke["residuals"]) | {
            r for r in run["t_raised"]}


# -- extreme-value statistics --------------------------------------------------------------
def test_gumbel_sample_quantile_recovered():
    mu, beta, alpha = 1.0, 0.2, 1e-3
    x = stats.gumbel_r.rvs(loc=mu, scale=beta, size=2000, random_state=7)
    true = mu - beta * math.log(-math.log(1 - alpha))
    fit = fit_maxima(x, alpha)
    assert fit["basis"] == "gumbel"            # the LR test does not reject xi = 0
    assert fit["quantile"] == pytest.approx(true, rel=0.03)
    assert abs(fit["gev"]["xi"]) < 0.05
    assert fit["empirical_quantile"] == pytest.approx(true, rel=0.15)


def test_heavy_tail_uses_gev_and_small_samples_are_empirical():
    x = stats.genextreme.rvs(-0.25, loc=1.0, scale=0.2, size=3000, random_state=1)
    fit = fit_maxima(x, 1e-3)
    assert fit["basis"] == "gev" and fit["gev"]["xi"] == pytest.approx(0.25, abs=0.05)
    assert fit["quantile"] == pytest.approx(
        stats.genextreme.ppf(1 - 1e-3, -0.25, loc=1.0, scale=0.2), rel=0.08)
    few = fit_maxima(x[:5], 1e-3)
    assert few["basis"] == "empirical" and few["quantile"] is None
    assert few["empirical_quantile"] is None     # 5 runs cannot estimate a 1e-3 quantile


@pytest.mark.parametrize("xi", [-0.3, 0.0, 1e-12, 0.4])
def test_gev_formulas_match_scipy(xi):
    for p in (0.5, 0.99, 0.999):
        q = gev_quantile(p, xi, 2.0, 0.5)
        assert q == pytest.approx(stats.genextreme.ppf(p, -xi, loc=2.0, scale=0.5), rel=1e-9)
        assert gev_cdf(q, xi, 2.0, 0.5) == pytest.approx(p, rel=1e-9)


def test_round_up_and_confidence_bound():
    assert round_up(1.431e-4) == (1.44e-4, "1.44e-4")
    assert round_up(2000.0) == (2000.0, "2.0e3")
    assert round_up(0.29999) == (0.3, "0.3")
    assert round_up(9.9951) == (10.0, "10.0")
    assert clopper_pearson_upper(0, 10) == pytest.approx(1 - 0.05 ** 0.1)


def test_demand_starts_like_the_rig():
    from dataclasses import replace

    from fdigen.sim.plant import reference_signal

    model = load_model()
    expr = demand_expression(model, 0.9, 37.0, centre=0.1)
    varied = replace(model, simulation={**model.simulation, "reference": expr})
    r0 = reference_signal(model, np.array([0.0]))[0]
    assert reference_signal(varied, np.array([0.0]))[0] == pytest.approx(0.1 + 0.9 * (r0 - 0.1))
    t = np.array([20.0])
    shifted = reference_signal(model, t + 37.0)[0]
    assert reference_signal(varied, t)[0] == pytest.approx(0.1 + 0.9 * (shifted - 0.1),
                                                           abs=1e-9)


# -- writing the model file ----------------------------------------------------------------
def test_toml_writer_changes_only_threshold_values(tmp_path):
    src = builtin_model_path()
    path = tmp_path / "cylinder.toml"
    shutil.copy(src, path)
    before = path.read_text()
    old = tomllib.loads(before)
    new_values = {name: round_up(1.2345e-3 * (k + 1))[0]
                  for k, name in enumerate(old["fdi"]["thresholds"])}
    new_values["R7"] = 0.123456789      # not 3 digits: written exactly, never rounded
    diff = write_thresholds(path, new_values)
    after = path.read_text()
    assert diff and after != before
    new = tomllib.loads(after)
    assert new["fdi"]["thresholds"] == new_values
    # everything else parses identically
    new["fdi"].pop("thresholds")
    old["fdi"].pop("thresholds")
    assert new == old
    # line by line: only threshold assignments changed, each keeps its comment
    a, b = before.splitlines(), after.splitlines()
    assert len(a) == len(b)
    keys = set(new_values)
    for la, lb in zip(a, b):
        if la == lb:
            continue
        key = la.split("=")[0].strip()
        assert key in keys and lb.split("=")[0].strip() == key
        if "#" in la:
            ca, cb = la[la.index("#"):], lb[lb.index("#"):]
            assert ca == cb and la.index("#") == lb.index("#")   # comment and its column
    assert sum(la != lb for la, lb in zip(a, b)) == len(keys)
    # the model still loads, with the new thresholds
    m = load_model(path)
    assert m.fdi["thresholds"]["R1"] == new_values["R1"]


def test_toml_writer_dry_run_and_snippet(tmp_path):
    path = tmp_path / "cylinder.toml"
    shutil.copy(builtin_model_path(), path)
    before = path.read_text()
    import tomllib
    old = tomllib.loads(before)["fdi"]["thresholds"]["R1"]
    diff = write_thresholds(path, {"R1": 4.2e-3}, dry_run=True)
    assert path.read_text() == before
    assert f"-R1 = {old!r}".replace("0.00347", "3.47e-3") in diff or "-R1 = " in diff
    assert "+R1 = 4.2e-3" in diff
    assert updated_model_text(before, {"R1": old}) == before


def test_dask_local_cluster_matches_synchronous():
    """Two worker processes return exactly what the in-process runner returns."""
    from fdigen.tune import NO_FLAG, CampaignExecutor, design_with_thresholds, make_cases

    model = load_model()
    design = design_with_thresholds(model, {n: NO_FLAG for n in model.fdi["thresholds"]})
    cases = make_cases(model, TuneSettings(runs=2, duration=0.5, validation_runs=0,
                                           faults=(), seed=5))["healthy"]
    with CampaignExecutor(scheduler="synchronous", progress=False) as ex:
        local = ex.run(design, cases, 200)
    with CampaignExecutor(workers=2, progress=False) as ex:
        assert ex.client is not None and len(ex.client.scheduler_info()["workers"]) == 2
        remote = ex.run(design, cases, 200)
    assert [r["index"] for r in remote] == [0, 1]
    for a, b in zip(local, remote):
        assert a["max_rms"] == b["max_rms"] and a["samples"] == b["samples"] == 500


def test_write_creates_the_thresholds_table_of_a_model_not_tuned_yet():
    """`fdigen build` tells a user without thresholds to run `fdigen tune --write`: the
    file may have no [fdi.thresholds] table at all, and the values must land in one."""
    import tomllib

    text = ('[model]\nname = "m"\n\n[fdi]\nsample_time = 0.001\nwindow = 100\n\n'
            '[fdi.parity]\nR1 = "y"\n\n[simulation]\nduration = 1.0\n')
    new = updated_model_text(text, {"R1": 0.0123, "K1": 4.5e-3})
    doc = tomllib.loads(new)
    assert doc["fdi"]["thresholds"] == {"R1": 0.0123, "K1": 4.5e-3}
    assert doc["fdi"]["parity"] == {"R1": "y"} and doc["simulation"] == {"duration": 1.0}


def test_an_isolation_before_the_onset_is_a_false_alarm_not_a_wrong_isolation():
    """A user's leak run isolated as a sensor fault at 73 s, its onset at 300 s: the run
    never tested the leak; it is counted as isolated before its onset, not as wrong."""
    from fdigen.tune.fault_summary import (isolated_before_onset, wrong_isolation,
                                           wrong_isolations_by_class)

    runs = [{"fault": "leak1", "fault_class": "leak", "isolated": "level_sensor",
             "t_isolated": 73.0, "t0": 300.0},
            {"fault": "leak1", "fault_class": "leak", "isolated": "pump",
             "t_isolated": 312.0, "t0": 300.0},
            {"fault": "s2", "fault_class": "level_sensor", "isolated": "level_sensor",
             "t_isolated": 305.0, "t0": 300.0},
            {"fault": "s2", "fault_class": "level_sensor", "isolated": "none",
             "t_isolated": None, "t0": 300.0}]
    assert [isolated_before_onset(r) for r in runs] == [True, False, False, False]
    assert [wrong_isolation(r) for r in runs] == [False, True, False, False]
    assert wrong_isolations_by_class(runs) == {"pump": 1}

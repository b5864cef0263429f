"""Round 36: a user's electro-hydraulic position axis (tests/data/newuser36: the model as
written from the README, in mm and bar with a valve's max/sqrt orifice law, and the
user's own simulator of the rig, with internal leakage, viscous and dry friction, a valve
gain 10 % low and a dead band, kept out of fdigen's tuning)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser36"


def test_a_log_whose_motion_never_reverses_is_said_to():
    """A slow ramp out (50 -> 150 mm over 15 s): the position's range (20..180 mm) does
    not hold zero, so the check of measured states said nothing, while the velocity, a
    state no sensor reads, never changed sign. discover chose a pressure-transmitter
    offset of 1.59 bar on the healthy rig. The velocity of a measured position (dx/dt =
    v) is now read as the position's smoothed derivative and checked too."""
    from fdigen.discover.coverage import coverage_warning, unreversed_states

    model = load_model(DATA / "hydraulic_axis.toml")
    dt = 1e-3
    t = np.arange(0, 15, dt)
    y = np.zeros((len(t), len(model.outputs)))
    j = model.output_index("x_m")
    rng = np.random.default_rng(0)
    y[:, j] = 50 + 100 * t / 15 + 0.002 * rng.standard_normal(len(t))     # ramp out
    found = unreversed_states(model, y, dt)
    assert [(e["state"], e["read"]) for e in found] == [("v", "rate")]
    assert abs(found[0]["seen"][1] - 100 / 15) < 0.5                      # 6.67 mm/s
    assert "never reverses v (" in coverage_warning(model, y, dt)
    assert unreversed_states(model, y) == []        # without the sample time: not read
    y[:, j] = 100 + 40 * np.sin(2 * np.pi * 0.3 * t)                       # reversing
    assert unreversed_states(model, y, dt) == []


def test_a_sensor_effect_that_worsens_its_own_sensor_is_not_confirmed():
    """discover on the ramp log chose ``sensor_offset_pA_m = 1.59 +- 0.015 bar`` on a
    healthy transmitter: the pressure's error grew 4.234 -> 5.243 bar, but the position's
    (416x its noise) fell 0.8323 -> 0.8286 mm and outweighed it in the sum over the
    sensors, so the effect was confirmed. A sensor's effect must now explain its own
    sensor; commission then does not commit it."""
    from fdigen.commission.withhold import not_committed
    from fdigen.discover.fit_report import unconfirmed_effects

    from fdigen.discover.effects import library

    model = load_model(DATA / "hydraulic_axis.toml")
    offset = next(e for e in library(model) if e.name == "sensor_offset_pA_m")
    assert set(offset.outputs) == {"pA_m"} and not offset.states
    found = {"effects": ["sensor_offset_pA_m"],
             "sensor_effects": {"sensor_offset_pA_m": ["pA_m"]},   # (as discover records)
             "parameters": {"off_pA_m": 1.59061, "Kv": 3e-6}, "calibrated": {"Kv": 3e-6},
             "uncertainty": {"off_pA_m": 0.015},
             "noise": {"x": 0.002, "pA": 0.15, "pB": 0.15},
             "error_before": {"x": 0.8323, "pA": 4.234, "pB": 10.07},
             "error_after": {"x": 0.8286, "pA": 5.243, "pB": 10.02},
             "ties": [], "declared_faults": []}
    why = unconfirmed_effects(found, model)
    assert why == ["sensor_offset_pA_m makes its own sensor's free-run error larger on the "
                   "log (pA 4.234 -> 5.243)"]
    assert [w["chosen"] for w in not_committed(found, True, model)[0]] == \
        ["sensor_offset_pA_m"]
    # the headline says it too, on either path (the user read "effect found:
    # coulomb_friction" above the warning that it was not confirmed)
    from fdigen.discover.pipeline import _say_unconfirmed

    for head in ("effect found", "effects"):
        info = {**found, "warnings": [], "message": f"{head}: sensor_offset_pA_m"}
        _say_unconfirmed(info, model)
        assert info["message"] == f"{head}, NOT confirmed: sensor_offset_pA_m"
        assert info["warnings"][0].startswith("the effects are NOT confirmed: ")
    # within 5 % (or the noise) of its own error: confirmed as before
    assert unconfirmed_effects({**found, "error_after": {**found["error_after"],
                                                         "pA": 4.30}}, model) == []


def test_a_friction_bound_reaches_what_the_balance_can_push():
    """discover put the axis's Coulomb friction at its bound of 100 N (truth 300 N):
    the bound came from the mass and the speed range alone (20 kg x 0.15 m/s = 3 N),
    where 130 bar on the 19.6 cm^2 piston is 25.5 kN. The bound is now also a tenth of
    the balance's largest force term; the cylinder's and the motor's are as they were
    (their damping gives the larger bound)."""
    from fdigen.discover.effects import DRIVE_SHARE, library
    from fdigen.discover.roles import motions

    def fc_bound(m):
        e = next(e for e in library(m) if e.name.startswith("coulomb_friction"))
        return e.parameters[0].bounds[1]

    axis = load_model(DATA / "hydraulic_axis.toml")
    (mo,) = motions(axis)
    assert abs(mo.drive - 1e5 * 130 * 1.963e-3) < 1.0       # pA at the top of its range
    assert fc_bound(axis) >= 0.999 * DRIVE_SHARE * mo.drive > 300.0   # (3 digits)
    for name in ("pneumatic_cylinder", "dc_motor"):
        m = load_model(name)
        (mo,) = motions(m)
        assert DRIVE_SHARE * mo.drive < 1000.0 / 30.0 * mo.force
        assert abs(fc_bound(m) - 1000.0 / 30.0 * mo.force) <= 1e-3 * fc_bound(m)


def test_thresholds_discover_reads_from_its_log_are_marked_not_designed(tmp_path):
    """The axis's discovered file carried thresholds read from the log (R5 = 121 mm of a
    160 mm range) as a tuned file would, and `detect` ran it in silence, blind to a 40 %
    valve loss. The file now carries `[fdi] refused = "fdigen discover: ..."`, which every
    command says first, and a passing `tune --write` lifts."""
    import shutil

    from fdigen.design.config import DISCOVER_REFUSAL, refused_text
    from fdigen.discover.design_check import ensure_design
    from fdigen.sim.log import read_log
    from fdigen.tune.refusal import refusal_value

    data = Path(__file__).parent / "data" / "newuser16"
    path = tmp_path / "tanks_augmented.toml"
    shutil.copy(data / "two_tank_untuned.toml", path)
    model = load_model(path)
    assert "thresholds" not in model.fdi and "refused" not in model.fdi
    lg = read_log(data / "tanks_lagged_l2.csv", model)
    model, design, notes = ensure_design(path, model, data=(lg.u, lg.y))
    mark = model.fdi["refused"]
    assert mark.startswith(f"{DISCOVER_REFUSAL} thresholds of R1, R2")
    assert set(model.fdi["thresholds"]) >= {"R1", "R2"}
    assert "were NOT designed" in refused_text(mark)
    passing = {"false_alarm": {"validation_false_alarms": 0, "validation_runs": 10},
               "faults": {}}
    assert refusal_value(passing, mark) is None


def test_the_equation_path_says_which_parameters_the_log_hardly_determines(tmp_path):
    """The axis's viscous friction came back 1024 +- 1500 from a one-speed ramp, said
    nowhere on the equation path (the output-error loop says it). A two-tank model with
    a second pump gain almost collinear with the first: its interval is said."""
    import json

    from click.testing import CliRunner

    from fdigen.cli import main

    data = Path(__file__).parent / "data" / "newuser16"
    text = (data / "two_tank_untuned.toml").read_text()
    assert 'h1 = "(kp*u - q1)/A1"' in text and 'g = { value = 981.0,' in text
    text = text.replace('h1 = "(kp*u - q1)/A1"', 'h1 = "(kp*u + cl*(u + 0.02*h1) - q1)/A1"')
    text = text.replace('g = { value = 981.0,', 'cl = { value = 0.01, unit = "cm^3/(s V)", '
                        'bounds = [-1.0, 1.0], uncertain = true }\ng = { value = 981.0,')
    path = tmp_path / "tanks.toml"
    path.write_text(text)
    res = CliRunner().invoke(main, ["discover", str(data / "tanks_lagged_l2.csv"), "--model",
                                    str(path), "--out", str(tmp_path / "d"), "--no-build",
                                    "--no-fdi", "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.stdout)
    poor = {p["parameter"]: p for p in info["poorly_determined"]}
    assert "cl" in poor and poor["cl"]["std"] > 0.5 * abs(poor["cl"]["value"])
    assert "a1" not in poor and "a2" not in poor
    assert any(w.startswith("parameter cl = ") and "the log hardly determines it" in w
               for w in info["warnings"])


def test_validation_logs_of_a_model_not_tuned_yet_are_read():
    """`commission --validate` on the user's model, which has no thresholds yet, was
    refused for the missing thresholds before any work: the check of a validation log
    read the whole [fdi] configuration for its sample time and window."""
    from fdigen.commission.validation_logs import refuse_unusable_logs

    data = Path(__file__).parent / "data" / "newuser16"
    model = load_model(data / "two_tank_untuned.toml")
    assert "thresholds" not in model.fdi
    refuse_unusable_logs(model, [data / "tanks_lagged_l2.csv"])       # no exception

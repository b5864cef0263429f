"""Plants a first-time user wrote from the README alone (newuser7, 2026-11-27).

``maglev_open_loop.toml``: a magnetic levitation rig, unstable open loop, its parity
residuals' parallel models without realignment (the README's default). They diverge:
``tune`` ended in "cannot write threshold inf" (no residual named), and ``verify`` failed
with "max rel inf" although every backend agreed bit for bit (inf - inf read as a
difference).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser7"
MAGLEV = DATA / "maglev_open_loop.toml"


def test_inspect_warns_of_open_loop_parallel_models_on_an_unstable_plant():
    res = CliRunner().invoke(main, ["inspect", "--model", str(MAGLEV)])
    assert res.exit_code == 0, res.output
    assert "unstable open loop at the operating point" in res.output
    assert "realign_noise_scale" in res.output


def test_tune_names_the_residuals_without_a_finite_healthy_rms(tmp_path):
    path = tmp_path / "m.toml"
    path.write_text(MAGLEV.read_text())
    res = CliRunner().invoke(main, ["tune", "--model", str(path), "--runs", "6",
                                    "--validation-runs", "1", "--fault-sizes", "1",
                                    "--fault-starts", "1", "--horizon-runs", "0"])
    assert res.exit_code == 2, res.output
    assert "healthy RMS of Rgap" in res.stderr and "not finite" in res.stderr
    assert "threshold inf" not in res.stderr


def test_equal_infinities_are_no_difference():
    from fdigen.verify.equivalence import _compare

    got = np.array([[np.inf, 1.0], [np.nan, 2.0], [-np.inf, 3.0]])
    d = _compare("c", "trajectory", ["a", "b"], got, got.copy())
    assert [x.max_rel for x in d] == [0.0, 0.0] and [x.max_abs for x in d] == [0.0, 0.0]
    other = got.copy()
    other[0, 0] = 5.0
    assert _compare("c", "trajectory", ["a", "b"], got, other)[0].max_rel == np.inf


def test_discover_reads_an_output_that_reads_an_input(tmp_path):
    """A pump's outlet pressure is a function of its speed (an input): discover's output
    error built the output map of the states only, and CasADi refused it (exit 3)."""
    model = DATA / "pump_tank.toml"
    log = tmp_path / "p.csv"
    assert CliRunner().invoke(main, ["simulate", "--model", str(model), "-o", str(log),
                                     "--duration", "300"]).exit_code == 0
    res = CliRunner().invoke(main, ["discover", str(log), "--model", str(model), "--out",
                                    str(tmp_path / "d"), "--no-build", "--no-fdi"])
    assert res.exit_code == 0, (res.output, res.stderr)
    assert "internal error" not in res.stderr


def test_commission_text_report_with_a_held_parameter():
    """A parameter held at its datasheet value has no interval (``null``): the text report
    crashed on it after the whole commissioning (the user's pH tank, its JSON kept)."""
    import json

    from fdigen.commission.report import text_report

    res = json.loads((DATA / "ph_commission.json").read_text())
    assert None in res["uncertainty"].values()
    text = text_report(res)
    assert "(held)" in text and "REFUSED" in text


def test_tune_names_a_threshold_beyond_its_sensors_span():
    """RpH = 9.21 pH (RMS) on a pH sensor that the declared ranges let cover 7.2 pH: the
    tune report names it (thresholds_beyond_span) and the warning says why."""
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.tune.sensor_span import output_span, span_warning, thresholds_beyond_span

    design = cached_design(load_model(DATA / "ph_tank.toml"))
    span = output_span(design.model, "y_pH")
    assert 5.0 < span < 9.21
    found = thresholds_beyond_span(design, dict(design.config.thresholds))
    assert set(found) == {"RpH"} and found["RpH"]["threshold"] == 9.21
    assert "RpH = 9.21" in span_warning(found)


def test_an_effects_parameter_is_shown_in_the_models_own_units(tmp_path):
    """`--effect leak_sqrt_h=1e-4` on a level in cm and on one in m is not the same leak
    (the parameter is in the model's units): simulate says the unit, the ground truth
    records it, and the list of effects gives each parameter's unit."""
    import json

    model = DATA / "pump_tank.toml"
    log = tmp_path / "e.csv"
    res = CliRunner().invoke(main, ["simulate", "--model", str(model), "-o", str(log),
                                    "--duration", "10", "--effect", "leak_sqrt_h=1e-4"])
    assert res.exit_code == 0, res.output
    assert "Kl_h = 0.0001 (m^2)*(cm)^0.5/s" in res.output
    truth = json.loads(log.with_suffix(".json").read_text())
    assert truth["truth"]["effects"][0]["units"] == {"Kl_h": "(m^2)*(cm)^0.5/s"}
    bad = CliRunner().invoke(main, ["simulate", "--model", str(model), "-o", str(log),
                                    "--duration", "10", "--effect", "nonsense=1"])
    assert bad.exit_code == 2 and "leak_sqrt_h (Kl_h in (m^2)*(cm)^0.5/s" in bad.stderr


def test_discover_holds_one_of_a_pair_the_log_cannot_separate(tmp_path):
    """Without the pressure sensor a pump curve's and a pipe's friction (Kc, Kf) enter
    only as their sum: the equation-error calibration stopped at Kc 2.2x and Kf -1.3x
    their datasheet values with intervals of 0.005 % (pinv of a singular matrix) and called
    Kc a model error. Now the blind direction is found, Kf held at its datasheet value, Kc
    calibrated with it (the log is the nominal plant's: Kc comes back within 1 %)."""
    import json

    model = DATA / "pump_tank_nop.toml"
    log = tmp_path / "n.csv"
    assert CliRunner().invoke(main, ["simulate", "--model", str(model), "-o", str(log),
                                     "--duration", "600"]).exit_code == 0
    res = CliRunner().invoke(main, ["discover", str(log), "--model", str(model), "--out",
                                    str(tmp_path / "d"), "--no-build", "--no-fdi", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert any("cannot determine Kc, Kf separately" in w for w in out["warnings"])
    assert out["calibrated"]["Kf"] == 2e6
    assert abs(out["calibrated"]["Kc"] / 3.7e6 - 1) < 0.01
    assert not any("Kc calibrated to" in w for w in out["warnings"])


def test_discover_warns_that_free_run_fits_of_an_unstable_plant_say_little(tmp_path):
    """The maglev (unstable open loop, a hidden differentiator state): discover's
    output-error loop "confirmed" a dead band on free-run errors of volts. It now says
    that a free-run simulation of an unstable plant departs from any log."""
    import json

    model = DATA / "maglev.toml"
    log = tmp_path / "m.csv"
    assert CliRunner().invoke(main, ["simulate", "--model", str(model), "-o", str(log),
                                     "--duration", "0.3"]).exit_code == 0
    res = CliRunner().invoke(main, ["discover", str(log), "--model", str(model), "--out",
                                    str(tmp_path / "d"), "--no-build", "--no-fdi",
                                    "--max-effects", "0", "--json"])
    assert res.exit_code == 0, (res.output, res.stderr)
    warnings = json.loads(res.stdout)["warnings"]
    assert any("unstable open loop" in w for w in warnings), warnings

"""Plants a user wrote from the README alone (tests/data/newuser14): a hydraulic press in
bar, mm and mA whose valve flow reads max(... sign(u) ..., 0), and a greenhouse whose
commissioning calibrated its ventilation capacity to a negative value."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from click.testing import CliRunner

from fdigen.cli import main
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser14"


def test_discover_on_a_valve_flow_with_max_and_sign(tmp_path, monkeypatch):
    """`dpv = max((1 + sign(u))/2*(Ps - p) + (1 - sign(u))/2*(p - Pt), 0)`: sympy's
    simplify raised inside discover's kinematic-chain check ("The argument 'nan' is not
    comparable"), an internal error (exit 3) of discover and commission. Now the default
    path runs on a simulated healthy log."""
    shutil.copy(DATA / "press.toml", tmp_path / "press.toml")
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    sim = runner.invoke(main, ["simulate", "--model", "press.toml", "-o", "healthy.csv"])
    assert sim.exit_code == 0, sim.output
    res = runner.invoke(main, ["discover", "healthy.csv", "--model", "press.toml", "--out",
                               "d", "--no-build", "--no-fdi", "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert info["effects"] == []          # the log is the model's own: nothing to add


def test_an_undetermined_calibration_keeps_the_datasheet_value(tmp_path):
    """The greenhouse's ventilation capacity calibrated to -1.85 +- 3.4 (datasheet 3):
    commission wrote it into the commissioned model. A value whose interval reaches 0, or
    whose sign is not the datasheet's, is not written; the well-determined UA is."""
    from fdigen.discover.augment import undetermined, write_augmented

    model = load_model(str(DATA / "greenhouse.toml"))
    sheet = {q.name: q.value for q in model.parameters}
    uncertain = [q.name for q in model.parameters if q.uncertain]
    assert {"Gmax", "UA"} <= set(uncertain)
    calibrated = {"Gmax": -1.85, "UA": 1.1 * sheet["UA"]}
    std = {"Gmax": 3.4, "UA": 0.02 * sheet["UA"]}
    why = undetermined(model, calibrated, std)
    assert set(why) == {"Gmax"} and "opposite sign" in why["Gmax"]
    assert set(undetermined(model, {"Gmax": 0.5 * sheet["Gmax"]}, {"Gmax": 2.0})) == {"Gmax"}
    notes = []
    params = {**sheet, **calibrated}
    path, written = write_augmented(DATA / "greenhouse.toml", tmp_path, model, [], params, std,
                                    calibrated=calibrated, notes=notes,
                                    file_name="greenhouse_calibrated.toml")
    values = {q.name: q.value for q in written.parameters}
    assert values["Gmax"] == sheet["Gmax"]
    assert values["UA"] == calibrated["UA"]
    assert len(notes) == 1 and "keeps the datasheet value" in notes[0]


def test_an_operating_point_outside_its_range_and_away_from_equilibrium_is_warned_of():
    """The press with its chamber pressure's operating point at 3 bar against a range of
    5-150 bar and a spring that needs 30: inspect and simulate said nothing. The shipped
    models' and the user's own press's operating points are quiet."""
    from fdigen.design.cache import cached_design
    from fdigen.design.design_warnings import operating_point_warnings
    from fdigen.pipeline import resolve_model_path
    from fdigen.tune.model_update import fill_missing_thresholds

    def warnings(path):
        model, _ = fill_missing_thresholds(load_model(str(path)), 1e3)
        return operating_point_warnings(cached_design(model))

    bad = warnings(DATA / "m2_op.toml")
    assert any("p = 3 lies outside its declared range [5, 150]" in w for w in bad), bad
    assert any("not an equilibrium" in w and "p = 3, its equilibrium near" in w for w in bad), bad
    assert warnings(DATA / "press.toml") == ()
    for name in ("pneumatic_cylinder", "three_tank", "dc_motor", "heat_exchanger"):
        assert warnings(resolve_model_path(name)) == (), name


def test_a_null_direction_of_one_parameter_and_crumbs_is_that_parameter():
    """A user's conveyor: 'scaling them as b1^+1 cf^-0.016 ... (the scale of the hidden
    state F)', while b1 was only weakly excited and has nothing to do with F's scale."""
    from types import SimpleNamespace

    from fdigen.discover.output_loop import identifiability

    model = load_model(str(DATA / "press.toml"))
    fit = SimpleNamespace(null_directions=[{"Kv": 1.0, "A": -0.016}], held={}, J=None,
                          free=[], params={"Kv": 1.0, "A": 1.0}, std={})
    _, warnings = identifiability(model, fit, {})
    assert warnings[0].startswith("Kv = ") and "does not move any output" in warnings[0]
    assert "scale of the hidden" not in warnings[0]


def test_a_dimensionless_target_reads_as_a_bare_number():
    """The greenhouse's vent opening (unit "1"): "offsets from 0.2 1 detected"."""
    from fdigen.tune.fault_sensitivity import fault_unit, sensitivity_text

    model = load_model(str(DATA / "greenhouse.toml"))
    fault = model.fault("vent_stuck")
    assert fault_unit(model, fault) == ""
    entry = {"unit": "", "offset": True, "ramp": False, "basis": "campaign", "detected_from": 0.2,
             "isolated_from": 0.2, "isolation_delay_max": 30.0}
    assert sensitivity_text("vent_stuck", entry).startswith(
        "vent_stuck: offsets from 0.2 detected, from 0.2 isolated")

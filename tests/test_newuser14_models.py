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

"""commission chooses the class decision as tune's search does: the heat exchanger
without ``structural_classes``, commissioned from one healthy simulated log, isolates its
hot-loop losses and thermometers only once R2 (the stored heat, blind to fouling) decides
classes; the commissioned file takes the key."""

from __future__ import annotations

import json

from click.testing import CliRunner

from fdigen.cli import main
from fdigen.model.model_file import builtin_model_path, load_model


def test_commission_takes_the_structural_class_decision_when_it_isolates_more(tmp_path):
    text = builtin_model_path("heat_exchanger").read_text()
    model = tmp_path / "hx.toml"
    model.write_text("".join(line for line in text.splitlines(keepends=True)
                             if not line.startswith("structural_classes")))
    assert "structural_classes" not in model.read_text()
    log = tmp_path / "healthy.csv"
    runner = CliRunner()
    assert runner.invoke(main, ["simulate", "--model", str(model), "--duration", "1200",
                                "--seed", "5", "--output", str(log)]).exit_code == 0
    res = runner.invoke(main, ["commission", str(log), "--model", str(model), "--out",
                               str(tmp_path / "c"), "--runs", "6", "--validation-runs", "4",
                               "--no-build", "--json"])
    info = json.loads(res.output)
    note = next(w for w in info["warnings"] if w.startswith("class decision:"))
    assert "taken" in note and "not taken" not in note
    assert load_model(info["model_file"]).fdi["structural_classes"] is True
    delays = info["delays"]
    assert all(delays[f]["isolated_correct"] == delays[f]["runs"]
               for f in ("fouling", "heater", "insulation", "cold_sensor"))
    assert sum(d["false_isolations"] for d in delays.values()) == 0
    assert info["false_alarm"]["validation_false_alarms"] == 0

"""An on/off controller with hysteresis in `[simulation]` (a thermostat).

A user's hot-water tank (round 40) switched its element at +-2 K around 55 degC; the
simulation had only PI and expression loops, so the campaigns ran a PI thermostat and
their thresholds came out 5-160x below the real log's levels.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.errors import ModelFileError
from fdigen.model.model_file import parse_model_text

DATA = Path(__file__).parent / "data" / "onoff"
TEXT = (DATA / "hot_water.toml").read_text()


def test_the_thermostat_switches_at_the_edges_of_its_band(tmp_path):
    log = tmp_path / "hw.csv"
    res = CliRunner().invoke(main, ["simulate", "--model", str(DATA / "hot_water.toml"),
                                    "-o", str(log), "--seed", "2"])
    assert res.exit_code == 0, res.output
    d = np.genfromtxt(log, delimiter=",", names=True)
    el = d["el"]
    assert set(np.unique(el)) == {0.0, 1.0}
    measured = (d["R_T"] / 100 - 1) / 3.85e-3          # the controller's measurement
    on = np.flatnonzero(np.diff(el) > 0.5) + 1
    off = np.flatnonzero(np.diff(el) < -0.5) + 1
    assert len(on) >= 3 and len(off) >= 3
    assert np.all(measured[on] < 55 - 2) and np.all(measured[off] > 55 + 2)
    # held inside the band: no switch where the reading is inside it
    inside = (measured > 53) & (measured < 57)
    assert not np.any(inside[1:] & (np.diff(el) != 0))
    assert el[0] == 0.0 and measured[0] > 53                         # off at the start


def test_a_burnt_coil_is_detected_on_the_thermostat_loop(tmp_path):
    model = DATA / "hot_water_tuned.toml"
    r = CliRunner()
    log = tmp_path / "burnt.csv"
    assert r.invoke(main, ["simulate", "--model", str(model), "--fault", "burnt@5000=0.5",
                           "-o", str(log)]).exit_code == 0
    res = r.invoke(main, ["detect", str(log), "--model", str(model)])
    assert res.exit_code == 0, res.output[-2000:]
    assert "RT" in res.output and "diagnosis: none" not in res.output
    healthy = tmp_path / "healthy.csv"
    assert r.invoke(main, ["simulate", "--model", str(model), "--seed", "5", "-o",
                           str(healthy)]).exit_code == 0
    res = r.invoke(main, ["detect", str(healthy), "--model", str(model)])
    assert res.exit_code == 0 and "diagnosis: none" in res.output, res.output[-2000:]


@pytest.mark.parametrize("old,new,field", [
    ("levels = [0.0, 1.0]", "levels = [1.0, 1.0]", "levels"),
    ("levels = [0.0, 1.0]", "levels = [0.0]", "levels"),
    ("hysteresis = 4.0", "hysteresis = -1.0", "hysteresis"),
    ("levels = [0.0, 1.0]\n", "", "levels"),
])
def test_a_bad_thermostat_is_refused_naming_its_key(old, new, field):
    assert old in TEXT
    with pytest.raises(ModelFileError) as err:
        parse_model_text(TEXT.replace(old, new, 1), source="hw.toml")
    assert f"simulation.controllers.thermostat.{field}" in str(err.value)

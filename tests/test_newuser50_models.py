"""Round 50: plants written from the README alone (tests/data/newuser50): an engine's
cooling circuit with NTC sensors in ohm, a boost converter, a clean-room pressure cascade.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

DATA = Path(__file__).parent / "data" / "newuser50"


def test_an_ntc_in_ohm_reads_its_own_simulated_log(tmp_path):
    """``R25*exp(B (1/(T + 273.15) - 1/298.15))`` falls as the temperature rises: the
    unit check took its reading at the lower limit (-30 degC, 2.002e5 ohm) as the
    smallest, and detect and report refused every log fdigen itself had simulated as
    "the wrong unit"."""
    from fdigen.model.model_file import load_model
    from fdigen.sim.log_units import check_units, sensor_span

    model = load_model(DATA / "cooling.toml")
    run = [sys.executable, "-m", "fdigen.cli"]
    log = tmp_path / "healthy.csv"
    sim = subprocess.run([*run, "simulate", "--model", str(DATA / "cooling.toml"), "-o",
                          str(log), "--duration", "120"], capture_output=True, text=True,
                         timeout=600)
    assert sim.returncode == 0, sim.stderr[-2000:]
    det = subprocess.run([*run, "detect", str(log), "--model", str(DATA / "cooling.toml"),
                          "--json"], capture_output=True, text=True, timeout=600)
    assert det.returncode == 0, det.stderr[-2000:]
    assert json.loads(det.stdout)["flags"] == []
    ntc = [o for o in model.outputs if "exp" in str(o.expr)]
    assert ntc
    for o in ntc:
        _, lo, bounds = sensor_span(model, o)
        assert lo == bounds[0] < bounds[1]          # the smallest reading, the hot end
    # a log in kOhm for a model in ohm is still refused
    from fdigen.sim.log import read_log

    lg = read_log(log, model, missing="fill")
    j = model.output_index(ntc[0].name)
    y = np.array(lg.y, copy=True)
    y[:, j] = y[:, j] / 1000.0
    try:
        check_units(log, model, y)
    except Exception as exc:  # noqa: BLE001 - the refusal is the point
        assert "wrong unit" in str(exc)
    else:
        raise AssertionError("a log in kOhm for a model in ohm was accepted")

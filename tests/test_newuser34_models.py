"""Round 34: plants written from the README alone (tests/data/newuser34): an averaged buck
converter sampled at 20 us with its current through a shunt amplifier in volts, a steam
boiler drum in bar and mm, a cart-pole stabilised by a PID on one measurement."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser34"


def test_detect_gives_times_to_the_sample_time_of_a_fast_plant(tmp_path, monkeypatch):
    """At 20 us, detect printed every flag, the action and the consistent faults "at
    0.025 s": their order and the confirmation delay could not be read. Times now carry
    the sample time's decimals, and each printed time is a sample instant."""
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    shutil.copy(DATA / "buck.toml", tmp_path / "buck.toml")
    res = CliRunner().invoke(main, ["simulate", "--model", "buck.toml", "--fault",
                                    "load_short@0.025=0.2", "-o", "f.csv"])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(main, ["detect", "--model", "buck.toml", "f.csv"])
    assert res.exit_code == 0, res.output
    raised = re.findall(r"│ (R\w+|K\w+)\s+│\s+([0-9.]+) │", res.stdout)
    assert len(raised) >= 2, res.stdout
    times = [float(t) for _, t in raised]
    for _, t in raised:
        assert len(t.split(".")[1]) == 5                 # 20 us: five decimals
    assert all(abs(t / 20e-6 - round(t / 20e-6)) < 1e-3 for t in times)
    assert len(set(times)) > 1                          # the order can be read
    assert re.search(r"action: \w+ from 0\.0\d{4} s", res.stdout), res.stdout


def test_sensor_placement_names_only_quantities_of_the_model():
    """inspect told the buck's user to fit "a sensor on ... z_cap_deg, z_load_short": the
    structure's unknowns for a fault written into several equations, no quantity of the
    model. Every suggested sensor is a state, an input as delivered or a definition."""
    from fdigen.design.structure import isolability_report
    from fdigen.model.model_file import load_model

    model = load_model(str(DATA / "buck.toml"))
    rep = isolability_report(model)
    known = ({s.name for s in model.states} | {d for d, _ in model.definitions}
             | {f"{u.name}_eff" for u in model.inputs})
    suggested = {v for p in rep["sensor_placement"] for v in p["sensors"]}
    assert suggested, rep["sensor_placement"]           # the pair is still given sensors
    assert suggested <= known, suggested - known

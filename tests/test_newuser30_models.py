"""Plants a first-time user wrote from the README (2026-11-28, round 30): an EV battery
thermal loop, a water network in cm and bar, a CSTR with transmitters in volts and mA.

* ``detect`` on the battery's pump fault said "action: safety_stop (every consistent
  class calls for it: coolant_flow)" beside "consistent faults: pump or cool_sensor": the
  summary read a late flag (``Rb_p``, after its validity horizon) as evidence, which the
  core leaves out; the action was the ambiguity policy's most severe one.
"""

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser30"


def test_late_flags_are_read_as_the_core_keeps_them(tmp_path, monkeypatch):
    from fdigen.backends.reference import ReferenceFdi
    from fdigen.design.cache import cached_design
    from fdigen.detect import late_flags
    from fdigen.model.model_file import load_model
    from fdigen.sim.log import read_log

    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    model_path = str(DATA / "ev_battery.toml")
    log = tmp_path / "pump.csv"
    res = CliRunner().invoke(main, ["simulate", "--model", model_path, "--duration", "2400",
                                    "--fault", "pump@1200=0.4", "-o", str(log)])
    assert res.exit_code == 0, res.output
    design = cached_design(load_model(model_path))
    lg = read_log(log, design.model)
    ref = ReferenceFdi(design)
    ref.reset()
    flags, late = [], []
    for k in range(len(lg.t)):
        out = ref.step(lg.u[k], lg.y[k])
        flags.append(out["flags"])
        late.append(ref.state.late)
    assert np.array_equal(late_flags(design, np.array(flags)), np.array(late))
    assert any(late)              # the case the summary got wrong has a late flag
    res = CliRunner().invoke(main, ["detect", "--model", model_path, str(log), "--json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    d = summary["diagnosis"]
    late_names = [f["residual"] for f in summary["flags"] if f["late"]]
    assert late_names
    if d["action_basis"] in ("unanimous", "most_severe"):
        # the classes the action reads are those of the faults consistent then, whatever
        # the late flags say
        classes = {design.model.fault(f).fault_class for f in d["consistent_faults"]}
        assert classes <= set(d["action_classes"]), (classes, d["action_classes"])
        acts = {design.evaluation.actions[design.evaluation.classes.index(c)]
                for c in d["action_classes"]}
        assert (d["action_basis"] == "unanimous") == (len(acts) == 1)
    res = CliRunner().invoke(main, ["detect", "--model", model_path, str(log)])
    assert f"{late_names[0]} (late)" in res.output

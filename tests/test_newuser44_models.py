"""Round 44: a user's hydraulic press, air-handling unit and water main
(tests/data/newuser44), written from the README.

* ``inspect --sensitivity`` before tuning scaled against the never-flagging stand-in
  thresholds: "ptA offsets detected from ~1.09e+30 bar";
* the refusal mark, which the README says inspect states first, came on line 62 of 64;
* a campaign that detected a leak at 1x its test size and missed it at 2x said "not
  detected in every run up to 7.5e-05, 0.00015, 0.0003, 0.0006".
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser44"


def test_sensitivity_before_tuning_is_not_estimated():
    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "press_untuned.toml"),
                                    "--sensitivity", "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.stdout)
    assert info["sensitivity"] is None
    assert info["sensitivity_needs"] == info["thresholds_missing"] != []
    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "press_untuned.toml"),
                                    "--sensitivity"])
    assert "Fault sensitivity at the thresholds: not estimated: the thresholds of" in res.output
    assert "e+30" not in res.output and "e+32" not in res.output


def test_inspect_says_a_refused_design_first():
    proc = subprocess.run([sys.executable, "-m", "fdigen.cli", "inspect", "--model",
                           str(DATA / "ahu.toml")], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    first = proc.stderr.splitlines()[0]
    assert first.startswith("warning: this design was REFUSED by `fdigen tune`"), first
    assert proc.stderr.count("REFUSED") == 1


def test_a_size_detected_below_a_missed_one_is_said_as_measured():
    from fdigen.tune.fault_sensitivity import sensitivity_text

    entry = {"unit": "", "ramp": False, "offset": False, "detected_from": None,
             "isolated_from": None, "sizes": [7.5e-05, 0.00015, 0.0003, 0.0006],
             "detected_at": [0.0003], "basis": "campaign"}
    text = sensitivity_text("leak", entry)
    assert text == ("leak: faults detected at 0.0003 in some run, but not in every run at "
                    "the largest size tried, so from no size on (tried 7.5e-05, 0.00015, "
                    "0.0003, 0.0006)")

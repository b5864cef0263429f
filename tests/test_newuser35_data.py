"""Round 35: a user's drive train (tests/data/newuser35: the model as written from the
README, and the user's own simulator of the rig, with backlash, dry friction, a constant
load torque and a torque constant 8 % low, kept out of fdigen's tuning). The logs it
writes stamp time in ms with +-0.1 ms of jitter (tests/test_log_gaps.py reads such
logs); what the data loop made of them is tested here."""

from __future__ import annotations

import sys
from pathlib import Path

from fdigen.commission.withhold import not_committed
from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser35"


def _oe_info(ties):
    """discover's output-error result on the drive's one-direction log (the numbers of
    the user's run), ``ties`` as the loop records them."""
    return {"effects": ["sensor_offset_i_meas"], "ties": ties, "declared_faults": [],
            "parameters": {"off_i_meas": 0.2405, "Ra": 1.006},
            "uncertainty": {"off_i_meas": 0.042, "Ra": 0.049}, "calibrated": {"Ra": 1.01},
            "noise": {"i_meas": 0.01}, "error_before": {"i_meas": 0.173},
            "error_after": {"i_meas": 0.093}}


def test_a_sensor_offset_tied_with_a_load_torque_is_not_committed():
    """On a log whose speed never reversed, the output-error loop chose a current-sensor
    offset (0.24 V) over the constant load torque and dry friction the rig had, warned of
    the tie, and commission wrote the offset into the current sensor's map. A tie between
    a sensor's effect and a plant's is now withheld; a tie of one kind (a load torque on
    either inertia) is committed as the loop chose."""
    model = load_model(DATA / "drive.toml")
    cross = [{"chosen": "sensor_offset_i_meas", "other": o, "round": 1, "delta_bic": d,
              "chosen_delta_bic": -15.2, "acts_on": "sensor", "other_acts_on": "plant"}
             for o, d in (("external_load_wm", -14.4), ("coulomb_friction_wl", -14.1))]
    tied, faulty, notes = not_committed(_oe_info(cross), False, model)
    assert [t["chosen"] for t in tied] == ["sensor_offset_i_meas"] and not faulty
    assert tied[0]["tied_with"] == {"external_load_wm": -14.4, "coulomb_friction_wl": -14.1}
    assert "sensor_offset_i_meas (dBIC -15.2) ties with external_load_wm (-14.4)" in notes[0]
    same = [{**cross[0], "chosen": "external_load_wl", "other": "external_load_wm",
             "acts_on": "plant", "other_acts_on": "plant"}]
    info = {**_oe_info(same), "effects": ["external_load_wl"],
            "parameters": {"Tload_wl": 0.0506}, "uncertainty": {"Tload_wl": 0.0039}}
    assert not_committed(info, False, model)[0] == []


def test_the_loop_records_what_each_tied_candidate_acts_on():
    from types import SimpleNamespace

    from fdigen.discover.fit_checks import output_error_ties

    cands = [{"effect": "sensor_offset_i_meas", "round": 1, "delta_bic": -15.2,
              "acts_on": "sensor"},
             {"effect": "external_load_wm", "round": 1, "delta_bic": -14.4,
              "acts_on": "plant"},
             {"effect": "gain_loss_V", "round": 1, "delta_bic": -3.0, "acts_on": "plant"}]
    ties = output_error_ties(cands, [SimpleNamespace(name="sensor_offset_i_meas")], 2.0)
    assert [(t["other"], t["acts_on"], t["other_acts_on"]) for t in ties] == [
        ("external_load_wm", "sensor", "plant")]


def test_progress_reaches_a_terminal_under_json_and_never_a_captured_stream(monkeypatch):
    """A user's output-error discovery ran 10 minutes under --json without a line."""
    from fdigen.cli.errors import progress_printer

    assert progress_printer(False) is not None
    monkeypatch.setattr(sys.stderr, "isatty", lambda: False, raising=False)
    assert progress_printer(True) is None
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    assert progress_printer(True) is not None


def test_a_log_that_never_reverses_a_state_is_said_to(tmp_path):
    """The drive's commissioning log never reversed its speeds (ranges -100..100 rad/s):
    its backlash and dry friction could not show, their constant part became a
    current-sensor offset, and nothing said so. The user's simulator writes a
    one-direction log and a two-direction one; an encoder's one count around standstill
    is no reversal."""
    import numpy as np

    from fdigen.discover.coverage import coverage_warning, unreversed_states

    model = load_model(DATA / "drive.toml")
    t = np.arange(0, 10, 0.002)
    count = 2 * np.pi / 1024 / 0.002                       # one encoder count: 3.07 rad/s
    one_way = 45 + 40 * np.sin(2 * np.pi * 0.2 * t)
    one_way[:200] = -count                                  # standstill, one count back
    current = 2 * np.sin(2 * np.pi * 0.5 * t)              # the current reverses
    y = np.column_stack([current, one_way, one_way, np.zeros_like(t)])
    names = [o.name for o in model.outputs]
    assert names[1:3] == ["wm_meas", "wl_meas"], names
    y = y[:, :len(names)]
    states = unreversed_states(model, y)
    assert [e["state"] for e in states] == ["wm", "wl"]
    assert states[0]["seen"][0] == -count
    text = coverage_warning(model, y)
    assert text.startswith("the log never reverses wm (-3.068 to 85 rad/s of its range -100 to 100)")
    both = y.copy()
    both[:, 1:3] = (40 * np.sin(2 * np.pi * 0.2 * t))[:, None]
    assert unreversed_states(model, both) == [] and coverage_warning(model, both) == ""


def test_a_validation_log_the_design_cannot_judge_is_refused_before_any_work(tmp_path):
    """Attack round 7: `commission --validate` took a 2-row log and one whose stamps ran
    9 % slow and reported both "quiet"; a refused input left an empty --out folder."""
    import json

    from click.testing import CliRunner

    from conftest import RIG
    from fdigen.cli import main

    base = RIG / "logs" / "fdi_healthy.csv"
    lines = base.read_text().splitlines()
    short = tmp_path / "rows2.csv"
    short.write_text("\n".join(lines[:3]) + "\n")
    slow = tmp_path / "slow.csv"
    slow.write_text("\n".join([lines[0]] + [
        ",".join([repr(1.09 * float(r.split(",")[0]))] + r.split(",")[1:])
        for r in lines[1:]]) + "\n")
    for log, says in ((short, "fewer than the RMS window"),
                      (slow, "the FDI design expects 0.001 s"),
                      (tmp_path / "loop", "cannot read log")):
        if log.name == "loop":
            log.symlink_to(log)
        out = tmp_path / f"out_{log.stem}"
        res = CliRunner().invoke(main, ["commission", str(base), "--validate", str(log),
                                        "--out", str(out), "--runs", "4", "--json"])
        assert res.exit_code == 2, res.output
        assert says in json.loads(res.stdout)["error"]["message"]
        assert not out.exists()
    # a main log refused after the folder was made: the folder goes too
    res = CliRunner().invoke(main, ["commission", str(short), "--out", str(tmp_path / "o"),
                                    "--runs", "4"])
    assert res.exit_code == 2 and "log too short" in res.output
    assert not (tmp_path / "o").exists()

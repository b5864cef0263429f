"""The command line's text output: never cut (no ``…``) when piped or on a narrow terminal,
the default durations of ``simulate`` and ``verify`` taken from the model, a fault after
the end of a log refused, and ``detect``'s wording for flags without isolation."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.model.model_file import builtin_model_path, load_model

PIPED = {"COLUMNS": "60", "TTY_COMPATIBLE": None, "FORCE_COLOR": None}
TERMINAL = {"COLUMNS": "60", "TTY_COMPATIBLE": "1", "NO_COLOR": "1", "FORCE_COLOR": None}
ANSI = re.compile(r"\x1b\[[0-9;]*m")


def run(args, env):
    res = CliRunner().invoke(main, [str(a) for a in args], env=env)
    assert res.exit_code == 0, res.output
    return ANSI.sub("", res.output)


def assert_uncut(text, words, width=None):
    """No ellipsis; every word on one line of ``text``; no line wider than ``width``."""
    assert "…" not in text, text
    for w in words:
        assert w in text, (w, text)
    if width is not None:
        assert max(len(line) for line in text.splitlines()) <= width, text


@pytest.fixture(scope="module")
def cylinder_log(tmp_path_factory):
    """A 4 s cylinder log, valve loss at 1 s, under a long name (the header line)."""
    out = tmp_path_factory.mktemp("logs") / "a_log_name_long_enough_to_wrap_a_narrow_header.csv"
    res = CliRunner().invoke(main, ["simulate", "--duration", "4", "-o", str(out),
                                    "--fault", "valve@1=-1"])
    assert res.exit_code == 0, res.output
    return out


# -- tables and prose never cut ------------------------------------------------------------
def test_inspect_piped_keeps_every_name_whole():
    info = json.loads(run(["inspect", "--json"], PIPED))
    text = run(["inspect"], PIPED)
    words = [*info["faults"], *{f["class"] for f in info["faults"].values()},
             *info["signature_table"], f"sample time {info['sample_time']} s"]
    assert_uncut(text, words)
    lines = text.splitlines()
    head = [c.strip() for c in next(x for x in lines if x.startswith("┃ fault ")).split("┃")
            if c.strip()]
    assert head[:2] == ["fault", "class"] and sorted(head[2:]) == sorted(info["signature_table"])
    for f, spec in info["faults"].items():  # each table row whole on one line
        row = next(x for x in lines if x.startswith(f"│ {f} "))
        cells = [c.strip() for c in row.split("│") if c.strip()]
        assert cells == [f, spec["class"], *(str(info["signature_table"][r][f])
                                             for r in head[2:])]


def test_inspect_on_a_narrow_terminal_wraps_instead_of_cutting():
    info = json.loads(run(["inspect", "--json"], PIPED))
    text = run(["inspect"], TERMINAL)  # the residual columns split over several tables
    assert_uncut(text, [f"sample time {info['sample_time']} s", *info["signature_table"],
                        *info["faults"]], width=60)
    assert text.count("┃ fault ") > 1


def test_detect_piped_and_narrow(cylinder_log):
    summary = json.loads(run(["detect", cylinder_log, "--json"], PIPED))
    raised = [f["residual"] for f in summary["flags"]]
    assert raised and summary["diagnosis"]["fault"] != "none"
    header = f"{cylinder_log}: {summary['samples']} samples at {summary['sample_time']:g} s"
    text = run(["detect", cylinder_log], PIPED)
    assert_uncut(text, [header, "flag raised at [s]", *raised,
                        f"diagnosis: {summary['diagnosis']['fault']} at "
                        f"{summary['diagnosis']['t_isolated']:.3f} s"])
    assert_uncut(run(["detect", cylinder_log], TERMINAL), ["flag raised at [s]", *raised],
                 width=60)


def test_tune_tiny_campaign_piped_and_narrow(tmp_path, monkeypatch, capsys):
    report = tmp_path / "tune.json"
    text = run(["tune", "--model", "dc_motor", "--runs", "2", "--duration", "0.5",
                "--validation-runs", "1", "--fault-sizes", "1", "--fault-starts", "1",
                "--scheduler", "synchronous", "--report", report], PIPED)
    rep = json.loads(report.read_text())
    headers = ["residual", "current", "healthy max", "empirical q", "Gumbel q", "GEV q (xi)",
               "basis", "tuned", "x current", "fault", "sizes", "detected", "missed",
               "detection delay", "class ok", "class wrong", "no class", "isolation delay",
               "FA before", "off-signature before isolation",
               f"healthy runs of {rep['settings']['duration']:g} s",
               "(delays in s: median [max])"]
    assert_uncut(text, [*headers, *rep["residuals"], *rep["faults"]])
    # detection and isolation per fault, kind and size; the < 90 % warning per fault
    assert_uncut(text, ["Detection and isolation per fault, kind and size", "kind", "x test",
                        "class ok", "class wrong", "ramp", "step"])
    # the class columns and the fault-level line say what they count (the user read
    # "isolated ok 0" beside "isolated to the fault: pumploss 4/4")
    flat = " ".join(text.split())
    assert "runs in which the core's class decision named the fault's class" in flat
    def narrowest(n, f):    # a set of several faults is said (the DC motor's drive and
        others = [g for g in f["fault_set_best"] if g != n]      # winding share a row)
        return f" (to {n} or {' or '.join(others)})" if others else ""

    assert ("consistent faults narrowed to the fault's signature" in flat
            and "not the class decision): " + ", ".join(
                f"{n} {f['fault_isolated']}/{f['runs']}{narrowest(n, f)}"
                for n, f in rep["faults"].items()) in flat)
    assert "(to drive or winding)" in flat
    for name, rate in rep["poorly_isolated"].items():
        assert (f"warning: {name} is class-isolable but isolated in {100 * rate:.0f} % of "
                "its runs at its test size (< 90 %)") in " ".join(text.split())
    assert rep["written"] is False
    # the same report on a 60-column terminal: split into tables that fit, names whole
    from fdigen.cli.tune_view import _print_tune
    for k, v in TERMINAL.items():
        if v is None:
            monkeypatch.delenv(k, raising=False)
        else:
            monkeypatch.setenv(k, v)
    _print_tune(rep)
    narrow = ANSI.sub("", capsys.readouterr().out)
    assert_uncut(narrow, [*headers[:-2], *rep["residuals"], *rep["faults"]], width=60)
    assert narrow.count("┃ fault ") > 1


def test_verify_says_the_duration_it_used(monkeypatch):
    text = run(["verify", "--model", "dc_motor", "--points", "20", "--duration", "0.25",
                "--backend", "casadi_sx"], PIPED)
    assert_uncut(text, ["20 random points", "of 0.25 s (--duration), ", "casadi_sx",
                        "discrete mismatches 0  OK"])

    import fdigen.verify.equivalence as eq
    seen = {}

    def fake_verify(design, backends, n_points, duration):
        seen["duration"] = duration
        return {"trajectories": [{"label": "healthy", "samples": round(duration / 1e-3)}],
                "backends": {}}
    monkeypatch.setattr(eq, "verify", fake_verify)
    text = run(["verify", "--model", "dc_motor"], PIPED)
    duration = load_model("dc_motor").simulation["duration"]
    assert seen["duration"] == duration
    assert f"of {duration:g} s (the model's [simulation] duration)" in text


# -- default durations ---------------------------------------------------------------------
def test_verify_duration_from_the_model_or_the_sample_time(tmp_path):
    from fdigen.cli.durations import simulation_duration, verify_duration

    cylinder = load_model()
    assert verify_duration(cylinder, 1e-3, None)[0] == 20.0  # its [simulation] duration
    assert verify_duration(cylinder, 1e-3, 3.0) == (3.0, "--duration")
    text = builtin_model_path("dc_motor").read_text()
    assert "\nduration = 10.0\n" in text
    path = tmp_path / "fast.toml"
    path.write_text(text.replace("\nduration = 10.0\n", "\n")
                    .replace("sample_time = 1e-3", "sample_time = 1e-4"))
    fast = load_model(str(path))
    dt = fast.fdi["sample_time"]
    assert dt == 1e-4 and "duration" not in fast.simulation
    seconds, source = verify_duration(fast, dt, None)
    # one rule with simulate and tune: 6 RMS windows of 100 samples (0.06 s) outlast
    # 5 slowest time constants (5 x 6.5 ms)
    assert round(seconds / dt) == 600 and seconds == pytest.approx(0.06)
    assert source == "no [simulation] duration: 6 RMS windows of 100 samples"
    assert simulation_duration(fast, None) == (seconds, source)


def test_simulate_uses_the_model_duration_and_refuses_a_late_fault(tmp_path):
    duration = load_model("dc_motor").simulation["duration"]
    out = tmp_path / "m.csv"
    text = run(["simulate", "--model", "dc_motor", "--no-noise", "-o", out], PIPED)
    t = np.loadtxt(out, delimiter=",", skiprows=1, usecols=0)
    assert len(t) == round(duration / 1e-3) and t[-1] < duration <= t[-1] + 1e-3 + 1e-12
    assert f"({duration:g} s, the model's [simulation] duration)" in text
    late = duration + 2
    res = CliRunner().invoke(main, ["simulate", "--model", "dc_motor", "-o", str(out),
                                    "--fault", f"drive@{late:g}=-0.5"])
    assert res.exit_code == 2
    assert "--fault" in res.output and f"T0 = {late:g} s" in res.output
    assert f"end of the log at {duration:g} s" in res.output
    res = CliRunner().invoke(main, ["simulate", "--model", "dc_motor", "-o", str(out),
                                    "--duration", "1", "--fault", "drive@1=-0.5"])
    assert res.exit_code == 2 and "T0 = 1 s" in res.output and "at 1 s (--duration)" in res.output


# -- detect's decision line ------------------------------------------------------------------
def test_detect_says_detected_not_isolated_with_the_raised_flags(motor_design):
    from fdigen.cli.run_cmds import _decision_text
    from fdigen.detect import summarise_run

    ev = motor_design.evaluation
    t = np.arange(100) * 1e-3
    flags = np.zeros(100, dtype=np.int64)
    flags[40:] |= 1 << 1
    flags[70:] |= 1 << 3
    summary = summarise_run(motor_design, t, {"flags": flags,
                                              "fault_class": np.zeros(100, dtype=np.int64)})
    assert summary["detected"] and summary["diagnosis"]["t_isolated"] is None
    line = _decision_text(summary).replace("\u00a0", " ")
    assert line.startswith("diagnosis: detected, not isolated")
    assert f"{ev.residuals[1]} at 0.040 s, {ev.residuals[3]} at 0.070 s" in line
    assert "diagnosis: none" not in line
    quiet = summarise_run(motor_design, t, {"flags": np.zeros(100, dtype=np.int64),
                                            "fault_class": np.zeros(100, dtype=np.int64)})
    assert _decision_text(quiet) == "diagnosis: none (no flag raised), action: none"


def test_detect_says_an_action_was_latched_before_the_isolation(motor_design):
    """An action taken under ambiguity (the most severe of the consistent classes') stays
    latched after a class is isolated: the decision line says so, or it reads as the
    isolated class's own action (a first-time user's tach offset read 'speed_sensor,
    action: safety_stop' where the file says accommodate)."""
    from fdigen.cli.run_cmds import _decision_text
    from fdigen.detect import summarise_run

    t = np.arange(100) * 1e-3
    flags = np.zeros(100, dtype=np.int64)
    flags[40:] |= 1 << 1
    cls = np.zeros(100, dtype=np.int64)
    cls[80:] = 1
    act = np.zeros(100, dtype=np.int64)
    act[60:] = 2
    summary = summarise_run(motor_design, t, {"flags": flags, "fault_class": cls,
                                              "action": act})
    d = summary["diagnosis"]
    assert d["t_isolated"] == pytest.approx(0.080) and d["action_basis"] != "isolated"
    line = _decision_text(summary).replace("\u00a0", " ")
    assert "action: safety_stop" in line
    assert "(latched: taken before the isolation, at 0.060 s" in line
    act[60:80] = 0                     # taken with the isolation: nothing to explain
    summary = summarise_run(motor_design, t, {"flags": flags, "fault_class": cls,
                                              "action": act})
    assert "latched" not in _decision_text(summary)


def test_a_bug_under_build_is_an_internal_error_not_bad_input(tmp_path, monkeypatch):
    """A non-fdigen exception while deriving or rendering is a bug: exit 3 'internal
    error' naming the model (it was exit 2, 'error', as if the user's model were at
    fault)."""
    from click.testing import CliRunner

    import fdigen.pipeline as pipeline
    from fdigen.cli import main

    def broken(*args, **kwargs):
        raise AttributeError("'NoneType' object has no attribute 'P'")

    monkeypatch.setattr(pipeline, "render_all", broken)
    res = CliRunner().invoke(main, ["build", "--out", str(tmp_path / "g")])
    assert res.exit_code == 3, res.output
    assert "internal error" in res.output and "pneumatic_cylinder" in res.output
    assert not (tmp_path / "g").exists()                  # nothing half-written


def test_inspect_warns_of_thresholds_set_by_the_spread_not_the_noise(tmp_path):
    """Three tanks: the parity thresholds are 9-28x their noise-only level (set by the
    +-10 % outflow coefficients), R6's (the T1 + T2 volume's parallel model) 7x; the
    filters' (R4, R5) are under 2x. The warning lists exactly the residuals at 5x or
    more, with the ratios the table prints."""
    import json

    from click.testing import CliRunner

    from fdigen.cli import main

    res = CliRunner().invoke(main, ["inspect", "--model", "three_tank", "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    thr = info["isolation"]["thresholds"]
    ratio = {n: thr[n] / sc["noise_level"] for n, sc in info["residual_scales"].items()
             if sc["noise_level"] and thr.get(n)}
    high = sorted(n for n, r in ratio.items() if r >= 5.0)
    assert high == ["R1", "R2", "R3", "R6"] and ratio["R4"] < 2 and ratio["R5"] < 2
    (msg,) = [w for w in info["warnings"] if "level on noise alone" in w]
    for n in high:
        assert f"{n} {ratio[n]:.3g}x" in msg
    assert "R4" not in msg and "commission" in msg
    # R1-R3 are parity residuals: the realignment is their other lever
    assert "parity residuals R1, R2, R3" in msg and "realign_noise_scale, now 0.05" in msg
    # the text output says it too, on stderr
    res = CliRunner().invoke(main, ["inspect", "--model", "three_tank"],
                             env={"COLUMNS": "200"})
    assert res.exit_code == 0 and "level on noise alone (R1 " in res.stderr


def test_build_before_tune_names_every_threshold_it_will_need(tmp_path):
    """A new model without thresholds: build's refusal named only the declared residuals
    (R1-R3 of the three tanks), and the user met R4, R5 after tuning those; the derived
    ones are now named too, with what they are."""
    from fdigen.model.model_file import builtin_model_path

    text = builtin_model_path("three_tank").read_text()
    start = text.index("[fdi.thresholds]")
    end = text.index("[fdi.frozen_horizon]")
    keys = text.index("[fdi.residual_keys]")
    stop = text.index("\n[", keys + 1)
    path = tmp_path / "tanks.toml"
    path.write_text(text[:start] + text[end:keys] + text[stop + 1:])
    res = CliRunner().invoke(main, ["build", "--model", str(path), "--out",
                                    str(tmp_path / "gen")])
    assert res.exit_code == 2, res.output
    msg = " ".join(res.output.split())
    assert "missing thresholds for residuals R1, R2, R3" in msg
    assert "also derives R4 (equations [h2]" in msg and "R5 (equations [h3]" in msg
    assert not (tmp_path / "gen").exists()

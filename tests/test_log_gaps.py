"""Logs as a real logger writes them (a user's two-tank rig, tests/data/newuser16): a
few dropped samples (empty fields, ``nan``, whole rows missing), timestamp jitter, a unit
in the header, time in milliseconds, levels in mm for a model in cm."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fdigen.errors import LogError
from fdigen.model.model_file import load_model
from fdigen.sim.log import read_log

DATA = Path(__file__).parent / "data" / "newuser16"
MODEL = load_model(str(DATA / "two_tank_untuned.toml"))
LINES = (DATA / "tanks_lagged_l2.csv").read_text().splitlines()
CLEAN = read_log(DATA / "tanks_lagged_l2.csv", MODEL)


def _write(tmp_path, lines, name="log.csv"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def _blank(lines, row, column):
    """Row ``row`` (1 = header) with field ``column`` emptied."""
    head = lines[0].split(",")
    out = list(lines)
    fields = out[row - 1].split(",")
    fields[head.index(column)] = ""
    out[row - 1] = ",".join(fields)
    return out


def test_a_few_missing_samples_are_interpolated_and_counted(tmp_path):
    lines = _blank(_blank(LINES, 700, "L1"), 1500, "L2")
    lines[900 - 1] = lines[900 - 1].replace(lines[900 - 1].split(",")[2], "nan", 1)
    path = _write(tmp_path, lines)
    with pytest.raises(LogError, match="row 700, column 'L1': not a number"):
        read_log(path, MODEL)                       # the default is unchanged
    for mode in ("keep", "fill"):
        log = read_log(path, MODEL, missing=mode)
        assert log.missing == {"L1": 2, "L2": 1}
        assert np.all(np.isfinite(log.y))
        k = 700 - 2                                  # row 700 is sample 698
        assert log.y[k, 0] == pytest.approx(0.5 * (CLEAN.y[k - 1, 0] + CLEAN.y[k + 1, 0]),
                                            rel=1e-9)


def test_dropped_rows_are_put_back_and_jitter_is_accepted(tmp_path):
    rng = np.random.default_rng(1)
    lines = [LINES[0]]
    for k, line in enumerate(LINES[1:]):
        t, rest = line.split(",", 1)
        jitter = 0.0 if k == 0 else 0.015 * 0.5 * rng.uniform(-1, 1)  # +-1.5 % of 0.5 s
        lines.append(f"{float(t) + jitter!r},{rest}")
    dropped = lines[:300] + lines[302:]              # two rows missing
    with pytest.raises(LogError, match="non-uniform sample time .*2 dropped rows"):
        read_log(_write(tmp_path, dropped), MODEL)
    log = read_log(_write(tmp_path, dropped), MODEL, missing="fill")
    assert log.missing["rows"] == 2 and len(log.t) == len(CLEAN.t)
    assert np.max(np.abs(log.y - CLEAN.y)) < 0.5      # interpolated across 2 samples
    assert read_log(_write(tmp_path, lines, "jitter.csv"), MODEL).sample_time == \
        pytest.approx(0.5, rel=1e-3)


def test_a_long_outage_is_run_by_detect_and_refused_by_the_data_loop(tmp_path):
    lines = list(LINES)
    for row in range(1000, 1020):
        lines = _blank(lines, row, "L2")
    path = _write(tmp_path, lines)
    log = read_log(path, MODEL, missing="keep")
    assert np.isnan(log.y[1000 - 2:1020 - 2, 1]).all() and log.missing == {"L2": 20}
    with pytest.raises(LogError, match=r"column 'L2': missing samples from t = .* \(20 "
                                       r"samples in a row\)"):
        read_log(path, MODEL, missing="fill")


def test_units_in_the_header_time_in_ms_and_levels_in_mm_are_named(tmp_path):
    head = "t [s],u [V],L1 [cm],L2 [cm]"
    with pytest.raises(LogError, match=r"'t \[s\]' -> 't'.*'L2 \[cm\]' -> 'L2'"):
        read_log(_write(tmp_path, [head] + LINES[1:]), MODEL)
    ms = [LINES[0]] + [f"{1000 * float(l.split(',', 1)[0])!r},{l.split(',', 1)[1]}"
                       for l in LINES[1:]]
    with pytest.raises(LogError, match="looks like milliseconds"):
        read_log(_write(tmp_path, ms), MODEL, sample_time=0.5)
    mm = [LINES[0]]
    for line in LINES[1:]:
        t, u, l1, l2 = line.split(",")
        mm.append(f"{t},{u},{10 * float(l1)!r},{10 * float(l2)!r}")
    with pytest.raises(LogError, match=r"column 'L1': values look like the wrong unit .*"
                                       r"within 0 to 30 cm"):
        read_log(_write(tmp_path, mm), MODEL)


def test_a_missing_first_sample_holds_the_next_and_an_empty_column_is_named(tmp_path):
    """A missing first sample was run by detect as a dead sensor (its validity flag
    latched at 0 s: level sensor 1 "isolated", then unexplained) and refused by discover
    as a gap "from t = 0 s to 0 s"; a short gap at either end now holds the nearest
    measured value. A column with no number at all is named as such."""
    path = _write(tmp_path, _blank(LINES, 2, "L1"))
    for mode in ("keep", "fill"):
        log = read_log(path, MODEL, missing=mode)
        assert log.y[0, 0] == CLEAN.y[1, 0] and log.missing == {"L1": 1}
    empty = [LINES[0]] + [line.rsplit(",", 1)[0] + "," for line in LINES[1:]]
    path = _write(tmp_path, empty, "empty.csv")
    assert np.isnan(read_log(path, MODEL, missing="keep").y[:, 1]).all()
    with pytest.raises(LogError, match="column 'L2': holds no number"):
        read_log(path, MODEL, missing="fill")


def test_kept_extra_columns_get_the_dropped_rows_too(tmp_path):
    """A reference column kept beside the model's (``extra_columns``) lines up with the
    rows put back (it was dropped whenever a row was)."""
    lines = [LINES[0] + ",href"] + [f"{line},{k}" for k, line in enumerate(LINES[1:])]
    dropped = lines[:300] + lines[302:]
    log = read_log(_write(tmp_path, dropped), MODEL, missing="fill", extra_columns=("href",))
    assert log.missing["rows"] == 2 and len(log.extra["href"]) == len(log.t)
    ref = log.extra["href"]
    assert np.isnan(ref[299:301]).all() and ref[298] == 298 and ref[301] == 301


def _stamped(lines, offsets):
    """``lines`` with each data row's time moved by ``offsets[k]`` (seconds)."""
    out = [lines[0]]
    for k, line in enumerate(lines[1:]):
        t, rest = line.split(",", 1)
        out.append(f"{float(t) + float(offsets[k])!r},{rest}")
    return out


def test_a_loggers_stamp_jitter_is_read_as_the_grid_and_a_wandering_clock_is_not(tmp_path):
    """A user's drive rig stamped its 2 ms samples within +-0.1 ms (+-5 % of a sample
    time): the check of 5 % on each interval refused it, and half that jitter too, where
    two stamps 5 % off make an interval 10 % off. Now each stamp may lie 10 % of a sample
    time off the uniform grid; a clock whose rate wanders by as much over the log is still
    refused (its samples are not uniform), naming the row."""
    dt = float(CLEAN.sample_time)
    n = len(LINES) - 1
    rng = np.random.default_rng(3)
    for amp in (0.05, 0.09):
        jittered = _stamped(LINES, np.r_[0.0, amp * dt * rng.uniform(-1, 1, n - 1)])
        log = read_log(_write(tmp_path, jittered, f"j{amp}.csv"), MODEL, sample_time=dt)
        assert log.sample_time == pytest.approx(dt, rel=1e-3)
        assert np.array_equal(log.y, CLEAN.y)         # the samples, as on the grid
        dropped = jittered[:300] + jittered[302:]     # two rows dropped, 2 dt +- 10 %
        log = read_log(_write(tmp_path, dropped, "d.csv"), MODEL, missing="fill")
        assert log.missing["rows"] == 2 and len(log.t) == len(CLEAN.t)
    # every interval within 10 %, but the clock slows over the first half and catches up:
    # stamps up to 0.3 sample times off any uniform grid
    k = np.arange(n)
    wander = 0.3 * dt * np.sin(np.pi * k / (n - 1)) ** 2
    assert np.max(np.abs(np.diff(wander))) < 0.1 * dt
    with pytest.raises(LogError, match=r"column 't': non-uniform sample time \(timestamp "
                                       r".* sample times off the uniform grid"):
        read_log(_write(tmp_path, _stamped(LINES, wander), "w.csv"), MODEL)
    with pytest.raises(LogError, match=r"non-uniform sample time \(interval"):
        step = np.r_[np.zeros(100), np.full(n - 100, 0.25 * dt)]    # one interval 25 % off
        read_log(_write(tmp_path, _stamped(LINES, step), "s.csv"), MODEL)


def test_a_time_column_in_ms_is_converted_by_its_row_of_units_and_named_without(tmp_path):
    """The same rig's logger writes time in ms. Without a row of units the data loop took
    the log's own sample time (2 s for a plant sampled at 2 ms) and the error blamed
    jitter; a row of units giving 'ms' under 't' was refused with advice to declare the
    unit in the model file, which has no such key. Now the row of units converts the time
    column, and without it the data loop names the unit."""
    ms = [LINES[0]] + [f"{1000 * float(l.split(',', 1)[0])!r},{l.split(',', 1)[1]}"
                       for l in LINES[1:]]
    units = [ms[0], ",".join("ms" if c == "t" else "" for c in ms[0].split(","))] + ms[1:]
    log = read_log(_write(tmp_path, units, "units.csv"), MODEL)
    assert log.sample_time == pytest.approx(CLEAN.sample_time, rel=1e-9)
    assert np.allclose(log.t, CLEAN.t, rtol=0, atol=1e-9 * CLEAN.t[-1])
    assert np.array_equal(log.y, CLEAN.y)
    with pytest.raises(LogError, match=r"model's \[fdi\] sample_time is .*looks like "
                                       r"milliseconds.*'ms' under 't'"):
        read_log(_write(tmp_path, ms, "ms.csv"), MODEL, missing="fill",
                 nominal_sample_time=CLEAN.sample_time)
    # a MAT file has no row of units: the advice is to convert the variable
    from scipy.io import savemat

    names = ms[0].split(",")
    rows = np.array([[float(v) for v in line.split(",")] for line in ms[1:]])
    savemat(tmp_path / "ms.mat", {n: rows[:, j] for j, n in enumerate(names)})
    with pytest.raises(LogError, match=r"looks like milliseconds: time is in seconds "
                                       r"\(convert the variable 't'\)$"):
        read_log(tmp_path / "ms.mat", MODEL, nominal_sample_time=CLEAN.sample_time)
    fortnight = [units[0], units[1].replace("ms", "fortnight")] + units[2:]
    log = read_log(_write(tmp_path, fortnight, "f.csv"), MODEL)   # not a unit it compares
    with pytest.raises(LogError, match=r"time column 't' in 'ks', which fdigen does not "
                                       r"convert: one of 's', 'ms'"):
        read_log(_write(tmp_path, [units[0], units[1].replace("ms", "ks")] + units[2:],
                        "ks.csv"), MODEL)


def test_a_double_buffered_loggers_alternating_stamps_read_as_its_grid(tmp_path):
    """Every other stamp +a, the others -a of a sample time (a double-buffered logger):
    the median interval is one of the two lengths, and a +-2 % pattern was read as a
    sample time 4 % off and refused; +-8 % failed the interval check against it. The
    grid's step is now the span over its whole steps; a dropped row in such a log is
    still put back."""
    dt = float(CLEAN.sample_time)
    n = len(LINES) - 1
    for a in (0.02, 0.05, 0.099):
        sign = np.where(np.arange(n) % 2, 1.0, -1.0)
        lines = _stamped(LINES, a * dt * sign)
        log = read_log(_write(tmp_path, lines, f"a{a}.csv"), MODEL, sample_time=dt)
        assert log.sample_time == pytest.approx(dt, rel=1e-3)
        assert np.array_equal(log.y, CLEAN.y)
        dropped = lines[:301] + lines[302:]
        log = read_log(_write(tmp_path, dropped, f"d{a}.csv"), MODEL, missing="fill",
                       sample_time=dt)
        assert log.missing["rows"] == 1 and len(log.t) == len(CLEAN.t)


@pytest.mark.parametrize("row, refused", [
    ("s,bar,cm,cm", r"column 'u' in 'bar', another quantity than the model's 'V'"),
    ("s,V,ms,cm", r"column 'L1' in 'ms', another quantity than the model's 'cm'"),
    ("kg,V,cm,cm", r"time column 't' in 'kg', which fdigen does not convert"),
    ("s,V,\uff4d\uff4d,cm", r"column 'L1' in 'mm', the model's is 'cm'"),     # full width
    ("s,V,c\u200bm,cm", r"column 'L1' a unit with an invisible or control character"),
    ("s,V,\u202ecm,cm", r"invisible or control character"),
    ("s,V,counts,cm", None), ("\uff53,V,\uff43\uff4d,cm", None),
    # round 54: a percentage is a ratio, not a level (nor a command in V)
    ("-,V,%,cm", r"column 'L1' in '%', another quantity than the model's 'cm'"),
    ("s,%,cm,cm", r"column 'u' in '%', another quantity than the model's 'V'"),
])
def test_a_row_of_units_names_another_quantity_and_no_look_alike_passes(tmp_path, row,
                                                                         refused):
    """Attack round 7: only another scale of the model's unit was refused (mm for cm);
    a voltage column labelled in bar, a level in ms, the full-width twin of mm and a
    unit with an invisible character passed in silence. A unit fdigen cannot read as a
    physical dimension (counts) is still read as the model's; a percentage is a ratio
    (round 54: a heater command logged in V passed a model's "%")."""
    path = _write(tmp_path, [LINES[0], row] + LINES[1:])
    if refused is None:
        assert np.array_equal(read_log(path, MODEL).y, CLEAN.y)
        return
    with pytest.raises(LogError, match=refused):
        read_log(path, MODEL)

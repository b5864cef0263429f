"""Bad logs: every class of malformed input is a LogError naming row and column, or a
documented handling (extra columns ignored, BOM/CRLF/blank lines accepted)."""

import codecs
import re

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import RIG
from reliability_log import reporter
from fdigen.errors import LogError
from fdigen.sim.log import Log, read_log, write_log

COLUMNS = ["t", "u", "x", "x2", "pp", "pn", "xref"]
K = 300


def _base_columns(k=K, dt=1e-3):
    t = np.arange(k) * dt
    s = np.sin(2 * np.pi * 1.3 * t)
    return {"t": t, "u": 2.0 * s, "x": 0.1 + 0.03 * s, "x2": 0.1 + 0.03 * s + 1e-5,
            "pp": 3.5e5 + 2e4 * s, "pn": 3.5e5 - 2e4 * s, "xref": 0.1 + 0.031 * s}


def _lines(columns=None):
    """The base log as text lines (header first, no line endings)."""
    cols = columns or _base_columns()
    names = list(cols)
    rows = [",".join(names)]
    for k in range(len(cols["t"])):
        rows.append(",".join(f"{cols[n][k]:.4f}" if n == "t" else f"{cols[n][k]:.9g}"
                             for n in names))
    return rows


def _text(lines, end="\n"):
    return end.join(lines) + end


def _set(lines, row, column, value):
    """Replace one field; ``row`` is the 1-based file row (header = 1)."""
    out = list(lines)
    header = out[0].split(",")
    fields = out[row - 1].split(",")
    fields[header.index(column)] = value
    out[row - 1] = ",".join(fields)
    return out


def _reorder(lines, order):
    header = lines[0].split(",")
    idx = [header.index(c) for c in order]
    return [",".join(line.split(",")[i] for i in idx) for line in lines]


def _drop_column(lines, column):
    header = lines[0].split(",")
    keep = [i for i, c in enumerate(header) if c != column]
    return [",".join(line.split(",")[i] for i in keep) for line in lines]


def _scale(lines, columns, factor):
    header = lines[0].split(",")
    idx = [header.index(c) for c in columns]
    out = [lines[0]]
    for line in lines[1:]:
        f = line.split(",")
        for i in idx:
            f[i] = f"{float(f[i]) * factor:.9g}"
        out.append(",".join(f))
    return out


BASE = _lines()
report = reporter("logs")

# name -> file content (bytes)
GOOD = {
    "plain": _text(BASE).encode(),
    "reordered columns": _text(_reorder(BASE, ["pn", "x2", "t", "xref", "pp", "u", "x"])).encode(),
    "extra columns ignored": _text([BASE[0] + ",temperature,note"]
                                   + [line + ",21.5,ok" for line in BASE[1:]]).encode(),
    "optional xref absent": _text(_drop_column(BASE, "xref")).encode(),
    "UTF-8 BOM": codecs.BOM_UTF8 + _text(BASE).encode(),
    "CRLF line endings": _text(BASE, "\r\n").encode(),
    "CR line endings": _text(BASE, "\r").encode(),
    "trailing blank lines": (_text(BASE) + "\n\n  \n").encode(),
    "blank lines inside": _text(BASE[:50] + ["", " , , "] + BASE[50:]).encode(),
    "BOM, CRLF and trailing blank lines": (codecs.BOM_UTF8 + _text(BASE, "\r\n").encode()
                                           + b"\r\n\r\n"),
    "spaces around fields": _text([", ".join(f" {c} " for c in line.split(","))
                                   for line in BASE]).encode(),
    "quoted fields": _text(['"' + line.replace(",", '","') + '"' for line in BASE]).encode(),
    "UTF-16 with BOM": _text(BASE).encode("utf-16"),
    "sample-time jitter below 1 %": _text(_set(BASE, 10, "t", "0.008005")).encode(),
}

# name -> (file content, regex the message must match)
BAD = {
    "empty file": (b"", r"empty file"),
    "whitespace only": (b"\n  \n\r\n", r"empty file"),
    "header only": (_text(BASE[:1]).encode(), r"row 1: header only"),
    "single sample": (_text(BASE[:2]).encode(), r"row 2: a single sample"),
    "missing column": (_text(_drop_column(BASE, "x2")).encode(), r"row 1: missing column 'x2'"),
    "two missing columns": (_text(_drop_column(_drop_column(BASE, "pp"), "u")).encode(),
                            r"row 1: missing column 'u', 'pp'"),
    "required column twice": (_text([BASE[0] + ",pp"] + [line + ",1" for line in BASE[1:]]
                                    ).encode(), r"row 1: column 'pp' appears twice"),
    "semicolon separated": (_text([line.replace(",", ";") for line in BASE]).encode(),
                            r"row 1: missing column 't'.*separator looks like ';'"),
    "text in a number field": (_text(_set(BASE, 5, "pp", "3.5e5bar")).encode(),
                               r"row 5, column 'pp': not a number \('3.5e5bar'\)"),
    "empty field": (_text(_set(BASE, 9, "u", "")).encode(),
                    r"row 9, column 'u': not a number \(''\)"),
    "decimal comma": (_text(_set(BASE, 3, "x", '"0,1"')).encode(),
                      r"row 3, column 'x': not a number \('0,1'\)"),
    "NaN": (_text(_set(BASE, 7, "x", "nan")).encode(), r"row 7, column 'x': value is nan"),
    "Inf": (_text(_set(BASE, 8, "pn", "-inf")).encode(), r"row 8, column 'pn': value is -inf"),
    "overflow to Inf": (_text(_set(BASE, 4, "x2", "1e999")).encode(),
                        r"row 4, column 'x2': value is 1e999"),
    "earliest bad row reported": (_text(_set(_set(BASE, 20, "t", "?"), 6, "pn", "nan")).encode(),
                                  r"row 6, column 'pn'"),
    "row with too few fields": (_text(BASE[:11] + [BASE[11].rsplit(",", 1)[0]] + BASE[12:]
                                      ).encode(), r"row 12: 6 fields, the header \(row 1\) has 7"),
    "row with too many fields": (_text(BASE[:3] + [BASE[3] + ",1"] + BASE[4:]).encode(),
                                 r"row 4: 8 fields"),
    "duplicated row": (_text(BASE[:30] + [BASE[29]] + BASE[30:]).encode(),
                       r"row 31, column 't': duplicated sample \(the row repeats row 30\)"),
    "time going back": (_text(BASE[:40] + [BASE[41], BASE[40]] + BASE[42:]).encode(),
                        r"row 42, column 't': time does not increase \(0.04 then 0.039\)"),
    "time standing still": (_text(_set(BASE, 61, "t", BASE[59].split(",")[0])).encode(),
                            r"row 61, column 't': time does not increase"),
    "missing sample (gap)": (_text(BASE[:100] + BASE[101:]).encode(),
                             r"row 101, column 't': non-uniform sample time"),
    "not UTF-8": (_text(BASE[:5]).encode() + b"0.0042,\xff\xfe,1,1,1,1,1\n", r"row 6: not UTF-8"),
    "NUL byte": (_text(BASE[:3]).encode() + b"0.0\x00,1\n", r"row 4: NUL character"),
    "pressures in bar": (_text(_scale(BASE, ["pp", "pn"], 1e-5)).encode(),
                         r"column 'pp': values look like the wrong unit"),
    "pressures in kPa": (_text(_scale(BASE, ["pp", "pn"], 1e-3)).encode(),
                         r"column 'pp': values look like the wrong unit"),
    "pressure n in MPa": (_text(_scale(BASE, ["pn"], 1e-6)).encode(),
                          r"column 'pn': values look like the wrong unit"),
    "positions in mm": (_text(_scale(BASE, ["x", "x2"], 1e3)).encode(),
                        r"column 'x': values look like the wrong unit"),
    "redundant position in mm": (_text(_scale(BASE, ["x2"], 1e3)).encode(),
                                 r"column 'x2': values look like the wrong unit"),
}


def _write(tmp_path, content, name="log.csv"):
    path = tmp_path / name
    path.write_bytes(content)
    return path


@pytest.mark.parametrize("case", sorted(GOOD))
def test_accepted_logs(case, tmp_path, cylinder):
    log = read_log(_write(tmp_path, GOOD[case]), cylinder, sample_time=1e-3)
    ref = _base_columns()
    assert isinstance(log, Log)
    assert log.t.shape == (K,) and log.u.shape == (K, 1) and log.y.shape == (K, 4)
    np.testing.assert_allclose(log.y[:, 0], ref["x"], rtol=1e-8)
    np.testing.assert_allclose(log.y[:, 3], ref["pn"], rtol=1e-8)
    np.testing.assert_allclose(log.u[:, 0], ref["u"], rtol=1e-8)
    assert log.sample_time == pytest.approx(1e-3)
    report("test_accepted_logs", f"well-formed variant: {case}", 1, "pass",
           "read; every column equals the source")


def test_extra_columns_kept_only_if_numeric(tmp_path, cylinder):
    log = read_log(_write(tmp_path, GOOD["extra columns ignored"]), cylinder,
                   extra_columns="all")
    assert set(log.extra) == {"xref", "temperature"}
    assert read_log(_write(tmp_path, GOOD["extra columns ignored"]), cylinder).extra == {}
    kept = read_log(_write(tmp_path, GOOD["extra columns ignored"]), cylinder,
                    extra_columns=("temperature", "note"))
    assert set(kept.extra) == {"temperature"}
    assert np.all(log.extra["temperature"] == 21.5)


@pytest.mark.parametrize("case", sorted(BAD))
def test_rejected_logs(case, tmp_path, cylinder):
    content, pattern = BAD[case]
    path = _write(tmp_path, content)
    with pytest.raises(LogError) as info:
        read_log(path, cylinder)
    message = str(info.value)
    assert message.startswith(str(path))
    assert "\n" not in message
    assert re.search(pattern, message), message
    report("test_rejected_logs", f"malformed: {case}", 1, "pass",
           "LogError naming file, row and column: " + message[len(str(path)) + 2:][:90])


def test_missing_file_and_folder(tmp_path, cylinder):
    with pytest.raises(LogError, match="cannot read log"):
        read_log(tmp_path / "nope.csv", cylinder)
    with pytest.raises(LogError, match="cannot read log"):
        read_log(tmp_path, cylinder)


def test_sample_time_checked_when_asked(tmp_path, cylinder):
    path = _write(tmp_path, _text(_lines(_base_columns(dt=1e-2))).encode())
    assert read_log(path, cylinder).sample_time == pytest.approx(1e-2)
    with pytest.raises(LogError, match=r"column 't': sample time 0.01 s, the FDI design "
                                       r"expects 0.001 s"):
        read_log(path, cylinder, sample_time=1e-3)


def test_signal_loss_is_not_a_unit_error(tmp_path, cylinder):
    """A pressure sensor reading zero over part of a log is a fault, not a wrong unit."""
    cols = _base_columns()
    cols["pp"][K // 3:] = 0.0
    path = tmp_path / "loss.csv"
    write_log(path, cols)
    assert read_log(path, cylinder).y[-1, 2] == 0.0


def test_write_then_read_round_trip(tmp_path, cylinder):
    cols = _base_columns()
    write_log(tmp_path / "w.csv", cols)
    log = read_log(tmp_path / "w.csv", cylinder, extra_columns="all")
    np.testing.assert_allclose(log.y[:, 2], cols["pp"], rtol=1e-8)
    np.testing.assert_allclose(log.extra["xref"], cols["xref"], rtol=1e-8)


# -- the rig logs: all read, and converted to bar / kPa / mm they are caught --------------
RIG_LOGS = sorted((RIG / "logs").glob("*.csv")) if (RIG / "logs").is_dir() else []


@pytest.fixture(scope="module")
def rig_log(cylinder):
    path = RIG / "logs" / "fdi_healthy.csv"
    if not path.is_file():
        pytest.skip("reference rig logs not available")
    return read_log(path, cylinder, sample_time=1e-3)


@pytest.mark.skipif(not RIG_LOGS, reason="reference rig logs not available")
def test_every_rig_log_reads(cylinder):
    for path in RIG_LOGS:
        log = read_log(path, cylinder, sample_time=1e-3)
        assert log.t.shape == (20000,)


@pytest.mark.parametrize("columns,factor,named", [
    (("pp", "pn"), 1e-5, "pp"),      # bar
    (("pp", "pn"), 1e-3, "pp"),      # kPa
    (("pn",), 1e-3, "pn"),           # one sensor in kPa
    (("x", "x2"), 1e3, "x"),         # mm
    (("x2",), 1e3, "x2"),            # redundant sensor in mm
])
def test_rig_log_in_wrong_units(rig_log, cylinder, tmp_path, columns, factor, named):
    cols = {"t": rig_log.t, "u": rig_log.u[:, 0]}
    cols.update({c: rig_log.y[:, j] for j, c in enumerate(("x", "x2", "pp", "pn"))})
    for c in columns:
        cols[c] = cols[c] * factor
    path = tmp_path / "converted.csv"
    write_log(path, cols)
    with pytest.raises(LogError, match=rf"column '{named}': values look like the wrong unit"):
        read_log(path, cylinder)


# -- fdigen detect on a bad log: one line, exit status 2, no traceback ---------------------
def test_detect_cli_bad_log(tmp_path):
    from fdigen.cli import main

    path = _write(tmp_path, BAD["Inf"][0], "bad.csv")   # (NaN: a missing sample, run)
    result = CliRunner().invoke(main, ["detect", str(path)])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("fdigen: error: ") and "row 8, column 'pn'" in lines[0]
    assert "Traceback" not in result.output


# -- property tests: read_log returns a Log or raises LogError, nothing else ---------------
def _read_or_logerror(path, model):
    try:
        return read_log(path, model)
    except LogError as exc:
        assert str(exc) and "\n" not in str(exc)
        return None


FIELD = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["", " ", "nan", "inf", "-0", "1e999", "abc", '"', '"1"', "0,5", "\t",
                     "1_0", "\u0663", "\x00", "1e-3"]),
    st.text(max_size=6),
)
SETTINGS = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])


@SETTINGS
@given(header=st.lists(st.sampled_from(COLUMNS + ["", "T", "extra", "x x"]), max_size=9),
       rows=st.lists(st.lists(FIELD, max_size=9), max_size=6),
       end=st.sampled_from(["\n", "\r\n", "\r"]),
       bom=st.booleans())
def test_random_csv_never_crashes(tmp_path, cylinder, header, rows, end, bom):
    text = end.join([",".join(header)] + [",".join(r) for r in rows]) + end
    raw = (codecs.BOM_UTF8 if bom else b"") + text.encode("utf-8", "surrogatepass")
    path = tmp_path / "random.csv"
    path.write_bytes(raw)
    log = _read_or_logerror(path, cylinder)
    report("test_random_csv_never_crashes", "random CSV (headers, fields with NaN/Inf/text/"
           "NUL/unicode, line endings, BOM) (hypothesis)", 1, "pass",
           "read" if log is not None else "refused with LogError")


@SETTINGS
@given(data=st.data())
def test_mutated_valid_log_never_crashes(tmp_path, cylinder, data):
    """Start from a valid log and corrupt a few fields, rows or bytes."""
    lines = list(BASE[:40])
    for _ in range(data.draw(st.integers(1, 4))):
        kind = data.draw(st.sampled_from(["field", "drop", "dup", "swap", "byte", "trunc"]))
        k = data.draw(st.integers(0, len(lines) - 1))
        if kind == "field":
            fields = lines[k].split(",")
            j = data.draw(st.integers(0, len(COLUMNS) - 1))
            if j < len(fields):
                fields[j] = data.draw(FIELD).replace(",", ";")
            lines[k] = ",".join(fields)
        elif kind == "drop":
            lines = lines[:k] + lines[k + 1:]
        elif kind == "dup":
            lines = lines[:k] + [lines[k]] + lines[k:]
        elif kind == "swap" and k + 1 < len(lines):
            lines = lines[:k] + [lines[k + 1], lines[k]] + lines[k + 2:]
        elif kind == "trunc" and lines:
            lines[k] = lines[k][:data.draw(st.integers(0, len(lines[k])))]
    raw = bytearray(_text(lines).encode()) if lines else bytearray()
    if raw and data.draw(st.booleans()):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    path = tmp_path / "mutated.csv"
    path.write_bytes(bytes(raw))
    log = _read_or_logerror(path, cylinder)
    if log is not None:
        assert np.all(np.isfinite(log.t)) and np.all(np.diff(log.t) > 0)
        assert np.all(np.isfinite(log.y)) and np.all(np.isfinite(log.u))
    report("test_mutated_valid_log_never_crashes", "valid log with fields, rows or bytes "
           "corrupted, dropped, duplicated, swapped, truncated (hypothesis)", 1, "pass",
           "read (finite, increasing time)" if log is not None else "refused with LogError")


def test_log_larger_than_the_limit_is_refused_before_reading(tmp_path):
    """Memory stays bounded: a log over the documented size is refused from its size."""
    from fdigen.errors import LogError
    from fdigen.model.model_file import load_model
    from fdigen.sim.log import read_log
    path = tmp_path / "big.csv"
    with open(path, "wb") as fh:          # a sparse 300 MiB file: nothing is written
        fh.truncate(300 * 2**20)
    with pytest.raises(LogError, match="more than the 256 MiB"):
        read_log(path, load_model())
    with pytest.raises(LogError, match="split it"):
        read_log(path, load_model(), max_bytes=1024)
    report("test_log_larger_than_the_limit_is_refused_before_reading",
           "log over the documented 256 MiB limit (sparse 300 MiB file)", 1, "pass",
           "refused from its size before reading, message says to split it")

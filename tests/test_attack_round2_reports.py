"""Regressions of the second attack round: generated documents and JSON inputs.

* F5: ``fdigen experiments`` pasted rig-log file names and ground-truth text into the
  Markdown document raw (HTML tags, ``|`` splitting table rows, links, backticks);
* F6: a malformed ground truth beside a rig log (wrong shape, 100000-deep nesting) ended in
  "internal error" (exit 3); so did a 100000-deep ``.fdigen-stamp`` in a sibling folder of
  a build's ``--out``;
* F7: a log file name with control characters made ``fdigen report -o x.svg`` write XML
  that is not well-formed (and the raw characters reached the HTML page).
"""

from __future__ import annotations

import json
import re
import shutil
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.errors import FdigenError
from fdigen.experiments import ExperimentError, read_truth
from fdigen.report import display_text, markdown_code, markdown_text
from fdigen.stamp import STAMP, read_stamp

HOSTILE_LOG = "fdi_x|y<img src=x onerror=alert(1)>.csv"
HOSTILE_NOTE = "</td><script>alert(1)</script> | col | [link](javascript:alert(1)) {{7*7}}"
DEEP = "[" * 100000 + "]" * 100000


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_clean(res, code):
    assert res.exit_code == code, res.output
    assert "Traceback" not in res.output and "internal error" not in res.output, res.output


@pytest.fixture(scope="module")
def cylinder_log(tmp_path_factory):
    """A short log of the built-in (pneumatic cylinder) model, in the rig's format."""
    folder = tmp_path_factory.mktemp("cyl")
    res = run("simulate", "-o", folder / "log.csv", "--duration", "1")
    assert_clean(res, 0)
    return folder / "log.csv"


@pytest.fixture(scope="module")
def motor_log(tmp_path_factory):
    folder = tmp_path_factory.mktemp("motor")
    res = run("simulate", "--model", "dc_motor", "-o", folder / "log.csv", "--duration", "2")
    assert_clean(res, 0)
    return folder / "log.csv"


def _cells(row: str) -> list[str]:
    """Cells of a Markdown table row (``\\|`` does not split a cell)."""
    return re.split(r"(?<!\\)\|", row.strip().strip("|"))


# -- F5: Markdown injection -----------------------------------------------------------------
def test_markdown_text_is_literal():
    assert markdown_text("fdi_leak_p.csv") == "fdi_leak_p.csv"
    assert markdown_text("leak at 10.6 s (Cl 3e-10)") == "leak at 10.6 s (Cl 3e-10)"
    out = markdown_text(HOSTILE_LOG + " " + HOSTILE_NOTE + " `x` ![i](y) a\nb\x01c\u202e"
                        " https://evil.example www.evil.example me@evil.example _em_ *b*")
    for raw in ("<", ">", "\n", "\x01", "\u202e", "https://", "www.", "_em_", "*b*"):
        assert raw not in out, (raw, out)
    # every character Markdown could read as markup is backslash-escaped
    assert not re.search(r"(?<!\\)[|`@\[\]!*]", out.replace("\\\\", "")), out
    assert markdown_code("shared/rig/logs/fdi_*.csv") == "`shared/rig/logs/fdi_*.csv`"
    assert "`" not in markdown_code("a`b").replace("\\`", "")
    assert "<" not in markdown_code("<b>x</b>")


def test_experiments_document_escapes_rig_log_names_and_truth(tmp_path, cylinder_log):
    rig = tmp_path / "rig`x<b>|"
    rig.mkdir()
    log = rig / HOSTILE_LOG
    shutil.copyfile(cylinder_log, log)
    truth = {"case": "x", "truth": {"faults": [{"kind": "leak", "t0": 0.5, "Cl": 3e-10,
                                                "note": HOSTILE_NOTE}]}}
    log.with_suffix(".json").write_text(json.dumps(truth))
    out = tmp_path / "exp.md"
    res = run("experiments", "--rig-logs", rig, "--after", "0.2", "-o", out)
    assert_clean(res, 0)
    text = out.read_text()
    for raw in ("<img", "<script", "</td>", "<b>", "{{7*7}}"):
        assert raw not in text, raw
    assert "rig\\`x&lt;b&gt;\\|/fdi\\_\\*.csv" in text             # the folder, escaped
    assert not re.search(r"(?<!\\)\]\(javascript", text)          # no link
    # the payload is there, escaped
    assert "fdi_x\\|y&lt;img src=x onerror=alert(1)&gt;.csv" in text
    assert "&lt;script&gt;alert(1)&lt;/script&gt; \\| col \\|" in text
    table = text.split("## The reference rig's logs", 1)[1].splitlines()
    rows = [line for line in table if line.startswith("|")]
    header = _cells(rows[0])
    assert len(header) == 10
    hostile = [r for r in rows if "fdi_x" in r]
    assert len(hostile) == 1 and len(_cells(hostile[0])) == len(header), hostile
    assert _cells(hostile[0])[0].strip().startswith("fdi_x\\|y")
    # every line of the flag list and the remarks is one line, without raw markup
    items = [line for line in table if line.startswith("- fdi_x")]
    assert items and all("<" not in line for line in items)


# -- F6a: malformed ground truth -------------------------------------------------------------
BAD_TRUTHS = {
    "list": "[1,2]",
    "truth_list": '{"truth":[1]}',
    "fault_string": '{"truth":{"faults":["x"]}}',
    "no_kind": '{"truth":{"faults":[{"t0":11}]}}',
    "t0_string": '{"truth":{"faults":[{"kind":"leak_p","t0":"11"}]}}',
    "t0_nan": '{"truth":{"faults":[{"kind":"leak_p","t0":NaN}]}}',
    "deep": DEEP,
}


@pytest.mark.parametrize("case", sorted(BAD_TRUTHS))
def test_malformed_ground_truth_is_an_error_naming_the_file(tmp_path, case):
    log = tmp_path / "fdi_a.csv"
    log.write_text("t\n")
    log.with_suffix(".json").write_text(BAD_TRUTHS[case])
    with pytest.raises(ExperimentError, match=re.escape(str(log.with_suffix(".json")))):
        read_truth(log)
    assert issubclass(ExperimentError, FdigenError)


def test_good_ground_truth_still_read(tmp_path):
    log = tmp_path / "fdi_a.csv"
    assert read_truth(log) == {}
    doc = {"truth": {"faults": [{"kind": "leak", "t0": 10.6, "Cl": 3e-10}]}}
    log.with_suffix(".json").write_text(json.dumps(doc))
    assert read_truth(log) == doc
    log.with_suffix(".json").write_text('{"case": "healthy", "truth": {"faults": []}}')
    assert read_truth(log)["truth"]["faults"] == []


@pytest.mark.parametrize("case", ["deep", "t0_string"])
def test_experiments_cli_malformed_ground_truth_exit_2(tmp_path, cylinder_log, case):
    rig = tmp_path / "rig"
    rig.mkdir()
    shutil.copyfile(cylinder_log, rig / "fdi_a.csv")
    (rig / "fdi_a.json").write_text(BAD_TRUTHS[case])
    res = run("experiments", "--rig-logs", rig, "--after", "0.2", "-o", tmp_path / "x.md")
    assert_clean(res, 2)
    assert "fdi_a.json" in res.output and "ground truth" in res.output
    assert not (tmp_path / "x.md").exists()


# -- F6b: a deeply nested stamp in a sibling folder -----------------------------------------
def test_read_stamp_deeply_nested_is_not_fdigens(tmp_path):
    (tmp_path / STAMP).write_text(DEEP)
    assert read_stamp(tmp_path) is None


def test_build_beside_a_deeply_nested_stamp(tmp_path):
    out = tmp_path / "out"
    (out / "other").mkdir(parents=True)
    (out / "other" / STAMP).write_text(DEEP)
    res = run("build", "--model", "dc_motor", "--out", out)
    assert_clean(res, 0)
    assert (out / "dc_motor" / STAMP).is_file()
    assert (out / "other" / STAMP).read_text() == DEEP      # not fdigen's: left alone


# -- F7: control characters in the SVG and HTML report ---------------------------------------
CTL_NAME = "ctl\x01\x0bname.csv"


def test_display_text_is_legal_xml():
    s = display_text("a\x01\x0b\x00\x1b[2J\udcff\ufffe\u2028\u202eb\n")
    assert s == "a\\x01\\x0b\\x00\\x1b[2J\\udcff\\ufffe\\u2028\\u202eb\\n"
    assert display_text("plain name.csv") == "plain name.csv"


def test_report_svg_and_html_with_control_characters_in_the_log_name(tmp_path, motor_log):
    log = tmp_path / CTL_NAME
    shutil.copyfile(motor_log, log)
    shutil.copyfile(motor_log.with_suffix(".json"), log.with_suffix(".json"))
    svg, html = tmp_path / "ctl.svg", tmp_path / "ctl.html"
    assert_clean(run("report", log, "--model", "dc_motor", "-o", svg), 0)
    assert_clean(run("report", log, "--model", "dc_motor", "-o", html), 0)
    root = ElementTree.parse(svg).getroot()                 # well-formed XML 1.0
    texts = "".join(root.itertext())
    assert "ctl\\x01\\x0bname.csv" in texts
    page = html.read_text(encoding="utf-8")
    assert not re.search(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]", page)
    assert "<title>fdigen report: ctl\\x01\\x0bname.csv</title>" in page
    assert "<h1>FDI report: ctl\\x01\\x0bname.csv</h1>" in page


def test_report_html_escapes_markup_in_the_log_name(tmp_path, motor_log):
    log = tmp_path / "a<b>&c.csv"
    shutil.copyfile(motor_log, log)
    html = tmp_path / "r.html"
    assert_clean(run("report", log, "--model", "dc_motor", "-o", html), 0)
    page = html.read_text(encoding="utf-8")
    assert "<b>" not in page and "a&lt;b&gt;&amp;c.csv" in page
    assert Path(html).stat().st_size > 0

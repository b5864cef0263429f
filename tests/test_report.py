"""fdigen report: PNG and self-contained HTML, byte-for-byte reproducible."""

import base64
import re

import pytest
from click.testing import CliRunner

from fdigen.errors import LogError
from fdigen.report import ReportError, render_report
from fdigen.sim.log import write_log
from fdigen.sim.plant import FaultEvent, simulate

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def valve_log(cylinder, tmp_path_factory):
    """A short closed-loop run of fdigen's own simulator: control signal lost at 2 s."""
    sim = simulate(cylinder, 4.0, faults=[FaultEvent("valve", 2.0, -1.0)], seed=3)
    path = tmp_path_factory.mktemp("report") / "valve.csv"
    write_log(path, sim.columns())
    return path


@pytest.fixture(scope="module")
def reports(cylinder_design, valve_log):
    """Two PNG and two HTML renderings of the same log, and the decision."""
    folder = valve_log.parent
    summary = None
    for name in ("a.png", "b.png", "a.html", "b.html"):
        summary = render_report(cylinder_design, valve_log, folder / name)
    return folder, summary


def test_png(reports):
    folder, summary = reports
    data = (folder / "a.png").read_bytes()
    assert data.startswith(PNG_SIGNATURE)
    assert data == (folder / "b.png").read_bytes()        # deterministic
    assert b"tIME" not in data and b"matplotlib" not in data.lower()
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert width >= 800 and height >= 800
    assert summary["diagnosis"]["fault"] == "pneumatic_or_actuator"


def test_html_is_self_contained(reports):
    folder, _ = reports
    page = (folder / "a.html").read_text(encoding="utf-8")
    assert page.startswith("<!DOCTYPE html>")
    assert (folder / "b.html").read_text(encoding="utf-8") == page
    for ref in re.findall(r'(?:src|href)\s*=\s*"([^"]*)"', page):
        assert ref.startswith("data:"), ref
    assert "<script" not in page and "<link" not in page and "url(" not in page
    png = re.search(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page).group(1)
    assert base64.b64decode(png) == (folder / "a.png").read_bytes()
    assert "pneumatic_or_actuator" in page and "safety_stop" in page
    assert re.search(r'<tr class="raised"><td>R1</td>', page)


def test_errors(cylinder_design, valve_log, tmp_path):
    with pytest.raises(ReportError, match=r"unknown report format"):
        render_report(cylinder_design, valve_log, tmp_path / "r.jpg")
    with pytest.raises(ReportError, match=r"cannot write report"):
        render_report(cylinder_design, valve_log, tmp_path / "no" / "such" / "r.png")
    bad = tmp_path / "bad.csv"
    bad.write_text("t,u,x,x2,pp,pn\n0,0,0.1,0.1,3.5e5,3.5e5\n")
    with pytest.raises(LogError, match="single sample"):
        render_report(cylinder_design, bad, tmp_path / "r.png")


def test_cli(valve_log, tmp_path):
    from fdigen.cli import main

    out = tmp_path / "cli.png"
    result = CliRunner().invoke(main, ["report", str(valve_log), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "pneumatic_or_actuator" in result.output
    assert out.read_bytes().startswith(PNG_SIGNATURE)
    result = CliRunner().invoke(main, ["report", str(valve_log), "-o", str(tmp_path / "x.tiff")])
    assert result.exit_code == 2
    assert result.stderr.startswith("fdigen: error: ") and "Traceback" not in result.output

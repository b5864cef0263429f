"""What a person sees in ``fdigen report``: the PNG, PDF, SVG and the HTML page (in headless
Chromium) on a rig log with log-scale panels: every residual's label present, readable tick
labels (``10⁻³``), no raw mathtext markup, and user text never parsed as TeX."""

import shutil
import subprocess

import matplotlib
import numpy as np
import pytest

from conftest import RIG
from fdigen.report import _STYLE, analyse_log, draw_figure, figure_bytes, render_report

LOG = RIG / "logs" / "fdi_leak_p.csv"
MARKUP = ("$", "\\mathdefault", "\\times", "^{")

pytestmark = pytest.mark.skipif(not LOG.is_file(), reason=f"rig log {LOG} not available")


@pytest.fixture(scope="module")
def drawn(cylinder_design):
    """The report figure of the rig's leak log, drawn (tick labels exist after a draw)."""
    t, out, summary = analyse_log(cylinder_design, LOG)
    with matplotlib.rc_context(_STYLE):
        fig = draw_figure(cylinder_design, t, out, summary)
        figure_bytes(fig, "png")
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig).draw()
    return fig


def test_figure_text_is_plain_and_inside(cylinder_design, drawn):
    from matplotlib.text import Text

    fig = drawn
    renderer = fig.canvas.get_renderer()
    width = fig.bbox.width
    residuals = list(cylinder_design.evaluation.residuals)
    log_panels = 0
    for ax, name in zip(fig.axes, residuals):
        label = ax.yaxis.label
        assert label.get_text().split(" (")[0].split(" [")[0] == name
        box = label.get_window_extent(renderer)
        assert 0 <= box.x0 and box.x1 <= width, (name, box)   # visible, not cut off
        ticks = [t.get_text() for t in ax.get_yticklabels() if t.get_visible()]
        if ax.get_yscale() == "log":
            log_panels += 1
            shown = [s for s in ticks if s]
            assert shown and all(s.startswith(("10", "1×")) or "×10" in s for s in shown), ticks
            for tick in ax.get_yticklabels():
                tb = tick.get_window_extent(renderer)
                if tick.get_text() and ax.bbox.y0 <= tb.y0 <= ax.bbox.y1:
                    assert tb.x0 >= 0 and tb.x1 > box.x1, (name, tick.get_text(), tb)
    assert log_panels >= 5          # the leak log spans decades on R1-R3, R7-R9, w1-w3
    texts = [t.get_text() for t in fig.findobj(Text)]
    for text in texts:
        assert not any(m in text for m in MARKUP), text


def test_pdf_and_svg_text(cylinder_design, drawn, tmp_path):
    """``fdigen report LOG -o r.pdf``: the PDF's text holds every residual name and no
    mathtext source; the PDF and the SVG carry no date and no producer."""
    from click.testing import CliRunner

    from fdigen.cli import main

    if shutil.which("pdftotext") is None:
        pytest.skip("pdftotext (poppler-utils) not installed")
    res = CliRunner().invoke(main, ["report", str(LOG), "-o", str(tmp_path / "r.pdf")])
    assert res.exit_code == 0, res.output
    pdf = (tmp_path / "r.pdf").read_bytes()
    assert pdf.startswith(b"%PDF")
    assert b"/CreationDate" not in pdf and b"/Producer" not in pdf and b"Matplotlib" not in pdf
    text = subprocess.run(["pdftotext", str(tmp_path / "r.pdf"), "-"], capture_output=True,
                          text=True, check=True).stdout
    words = set(text.split())
    for name in cylinder_design.evaluation.residuals:
        assert name in words, name
    assert "10⁻³" in words and "time" in words
    assert not any(m in text for m in MARKUP)
    with matplotlib.rc_context(_STYLE):
        svg = figure_bytes(drawn, "svg").decode("utf-8")
    assert svg.lstrip().startswith("<?xml") and "mathdefault" not in svg
    assert "<dc:date>" not in svg and "Matplotlib" not in svg
    for name in cylinder_design.evaluation.residuals:
        assert f">{name}" in svg, name


def test_html_in_chromium(cylinder_design, tmp_path):
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("chromium not installed")
    page = tmp_path / "r.html"
    render_report(cylinder_design, LOG, page)
    shot = tmp_path / "shot.png"
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu",
                    "--hide-scrollbars", f"--screenshot={shot}", "--window-size=1000,2600",
                    page.as_uri()], capture_output=True, timeout=120, check=True)
    from matplotlib.image import imread

    pixels = imread(shot)[..., :3]
    assert pixels.shape[0] == 2600 and pixels.shape[1] == 1000
    dark = np.mean(pixels.mean(axis=2) < 0.5)          # text, lines, axes
    tinted = np.mean(np.ptp(pixels, axis=2) > 0.2)      # the flag shading, the curves
    assert 0.005 < dark < 0.5, dark
    assert tinted > 0.005, tinted
    # the embedded figure is displayed: its lower half (panels) is not blank
    assert np.mean(pixels[1300:].mean(axis=2) < 0.5) > 0.003


def test_user_text_is_not_tex(cylinder_design, tmp_path):
    """A log named like TeX (invalid TeX: mathtext would raise) is drawn as is."""
    log = tmp_path / "leak_$\\frac{x^2$.csv"
    log.write_text("".join(LOG.read_text().splitlines(keepends=True)[:3001]))
    render_report(cylinder_design, log, tmp_path / "r.pdf")
    if shutil.which("pdftotext"):
        text = subprocess.run(["pdftotext", str(tmp_path / "r.pdf"), "-"],
                              capture_output=True, text=True, check=True).stdout
        assert "leak_$\\frac{x^2$.csv" in text


def test_residual_axes_carry_the_compared_outputs_units(cylinder_design, drawn):
    """README: an output's `unit` labels residuals and reports. A user's press report had
    no unit on any residual axis."""
    from fdigen.design.residual_scale import residual_scales

    scales = residual_scales(cylinder_design)
    labels = {ax.get_ylabel().split(" ")[0]: ax.get_ylabel() for ax in drawn.axes}
    for name, sc in scales.items():
        if sc["unit"] in ("m", "Pa"):
            assert f"{name} [{sc['unit']}]" in labels[name], labels[name]
    assert any(f"[{u}]" in lab for lab in labels.values() for u in ("m", "Pa"))

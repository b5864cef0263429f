"""A report of the FDI decisions on one log, drawn like the paper's Figs 6-7.

One panel per residual: its moving RMS (eq 22) against its threshold ``J``, the time its
latched flag rose (marker and shading to the end of the log) and the isolation time (a
vertical line across all panels); the title gives the diagnosis. The output is a PNG, a PDF
or an SVG (text kept as text), or a self-contained HTML page (the PNG embedded as base64,
a table of the flags and the diagnosis, no external resources). The same input gives the
same bytes: the figure carries no date and no software version.

Names from the model and the log are never parsed as mathtext (a ``$`` in them is no TeX);
the log-scale tick labels are plain Unicode (``10⁻³``, :func:`power_of_ten`), so no text
of the figure needs mathtext at all. A log's file name is input: it reaches the figure's
title and the HTML page through :func:`display_text` (no control character, so the SVG stays
well-formed XML 1.0) and the page's autoescape. :func:`markdown_text` does the same for
Markdown documents (``fdigen experiments``).
"""

from __future__ import annotations

import base64
import io
import re
from pathlib import Path

import jinja2
import numpy as np

from fdigen.design.fdi_design import FdiDesign
from fdigen.errors import FdigenError
from fdigen.files.atomic import write_bytes

#: Output formats by file suffix.
FORMATS = {".png": "png", ".pdf": "pdf", ".svg": "svg", ".html": "html", ".htm": "html"}

#: A panel is drawn on a log scale when its RMS spans more than this ratio.
LOG_SCALE_SPAN = 100.0

#: Fixed metadata by format: no matplotlib version, no date.
#: The PNG text chunk that marks a figure fdigen wrote (fixed text: the bytes stay
#: deterministic); :func:`fdigen.files.outputs.check_sidecars` trusts such files only.
PNG_MARK = "fdigen report"
METADATA = {"png": {"Software": PNG_MARK},
            "pdf": {"Creator": None, "Producer": None, "CreationDate": None},
            "svg": {"Creator": None, "Date": None}}
PNG_METADATA = METADATA["png"]

#: Superscript digits for the tick labels of log-scale panels (``10⁻³``): plain Unicode
#: text, so no label needs mathtext (which is off: user text is never parsed as TeX).
_SUPERSCRIPT = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")

_DPI = 100
_STYLE = {"font.family": "DejaVu Sans", "font.size": 8, "axes.titlesize": 9,
          "figure.titlesize": 10, "path.simplify": True, "svg.hashsalt": "fdigen",
          "text.parse_math": False,   # names and paths are text: "$", "_", "^" stay as is
          "pdf.fonttype": 42, "svg.fonttype": "none"}   # text stays text (searchable)

_HTML = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>fdigen report: {{ log }}</title>
<style>
body { font-family: sans-serif; margin: 1.5em; color: #222; }
table { border-collapse: collapse; margin: 1em 0; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
tr.raised td { background: #fde8e8; }
img { max-width: 100%; }
</style>
</head>
<body>
<h1>FDI report: {{ log }}</h1>
<p>Model <code>{{ model }}</code>, {{ samples }} samples at {{ sample_time }} s,
FDI backend {{ backend }}.</p>
<h2>Diagnosis</h2>
<table>
<tr><th>fault class</th><td>{{ diagnosis.fault }}</td></tr>
<tr><th>isolated at [s]</th><td>{{ isolated }}</td></tr>
<tr><th>action</th><td>{{ diagnosis.action }}</td></tr>
<tr><th>candidate faults</th><td>{{ candidates }}</td></tr>
</table>
<h2>Flags</h2>
<table>
<tr><th>residual</th><th>threshold J</th><th>max RMS</th><th>flag raised at [s]</th>
<th>in the signature of {{ diagnosis.fault }}</th></tr>
{% for row in rows %}
<tr{% if row.raised != "-" %} class="raised"{% endif %}><td>{{ row.residual }}</td>
<td>{{ row.threshold }}</td><td>{{ row.max_rms }}</td><td>{{ row.raised }}</td>
<td>{{ row.expected }}</td></tr>
{% endfor %}
</table>
<h2>Moving RMS of the residuals</h2>
<img alt="moving RMS of each residual against its threshold" src="data:image/png;base64,{{ png }}">
</body>
</html>
"""


class ReportError(FdigenError):
    """A report cannot be written (unknown output format, unwritable file)."""


# -- text from inputs in generated documents ----------------------------------------------
def display_text(text) -> str:
    """``text`` (a log's file name...) as one line of visible text for a figure title or
    an HTML page: every control or format character, line break and tab written as its
    escape (:func:`fdigen.errors.shown` keeping none), so the text is legal in XML 1.0
    (SVG) and cannot break a line or reorder what is shown. HTML-escaping is the page
    template's job (autoescape)."""
    from fdigen.errors import shown

    return shown(text, keep="")


#: ASCII punctuation that Markdown may read as markup anywhere in a line (code spans,
#: emphasis, links and images, table cells, strikethrough, math, headings, autolinked
#: e-mail addresses), written backslash-escaped by :func:`markdown_text`.
_MD_ESCAPED = set("\\`*[]|!~$#@{}")
#: Written as HTML entities: no raw tag, comment or entity can reach the document.
_MD_ENTITIES = {"<": "&lt;", ">": "&gt;", "&": "&amp;"}


def markdown_text(text) -> str:
    """``text`` from an input (a log's file name, a ground truth's note) as literal text of
    a generated Markdown document, on one line and inside a table cell.

    * control and format characters, line breaks and tabs are written as escapes
      (:func:`display_text`): the text stays in its cell or list item;
    * ``<``, ``>`` and ``&`` become ``&lt;``, ``&gt;``, ``&amp;``: no raw HTML;
    * ``\\ ` * [ ] | ! ~ $ # @ { }`` are backslash-escaped: ``|`` cannot split a table
      row, a backtick cannot open or close inline code, ``[...](...)`` is no link nor
      image, ``@`` no e-mail autolink;
    * ``_`` is escaped unless it is inside a word (``leak_p`` stays as is: an underscore
      between letters is never emphasis); ``:`` before ``/`` and the ``.`` of ``www.``
      are escaped, so no URL is autolinked.

    Text without any of these characters (``fdi_leak_p.csv``, ``leak at 10.6 s (Cl
    3e-10)``) is returned unchanged.
    """
    s = display_text(text)
    out = []
    for i, ch in enumerate(s):
        if ch in _MD_ENTITIES:
            out.append(_MD_ENTITIES[ch])
        elif ch in _MD_ESCAPED:
            out.append("\\" + ch)
        elif ch == "_":
            inner = 0 < i < len(s) - 1 and s[i - 1].isalnum() and s[i + 1].isalnum()
            out.append(ch if inner else "\\_")
        elif ch == ":" and s[i + 1:i + 2] == "/":
            out.append("\\:")
        else:
            out.append(ch)
    return re.sub(r"(?i)\b(www)\.", r"\1\\.", "".join(out))


#: Characters allowed in an inline code span of :func:`markdown_code`.
_CODE_SAFE = re.compile(r"[A-Za-z0-9_./*+\-,:=() ]*")


def markdown_code(text) -> str:
    """``text`` as inline code (`` `text` ``) when it holds only plain characters
    (letters, digits, ``_ . / * + - , : = ( )`` and spaces: a relative path, a glob),
    else as escaped plain text (:func:`markdown_text`): inside a code span no escape
    works, so a backtick, ``|``, ``<`` or a control character must not go there."""
    s = str(text)
    if s and _CODE_SAFE.fullmatch(s) and s == s.strip():
        return f"`{s}`"
    return markdown_text(s)


def output_format(path: str | Path) -> str:
    """``"png"``, ``"pdf"``, ``"svg"`` or ``"html"`` from the file suffix.

    Raises
    ------
    ReportError
        For any other suffix.
    """
    fmt = FORMATS.get(Path(path).suffix.lower())
    if fmt is None:
        raise ReportError(f"{path}: unknown report format (use a .png, .pdf, .svg or .html file name)")
    return fmt


def analyse_log(design: FdiDesign, log_path: str | Path, backend: str = "auto"):
    """Read a log and run the FDI core over it.

    Returns
    -------
    tuple
        ``(t, out, summary)``: time (K,), the runner's outputs (``rms`` (K, n_r),
        ``flags``...) and the decision of :func:`fdigen.detect.summarise_run`.
    """
    from fdigen.detect import run_log

    # read and run as `fdigen detect` does (a logger's dropped rows put back, outages
    # run as such): a user's figure of a log detect had just run was refused
    summary, out, log = run_log(design, log_path, backend)
    summary["log"] = Path(log_path).name
    return log.t, out, summary


def class_signature(design: FdiDesign, fault_class: str) -> set[str]:
    """Residuals that respond to at least one fault of ``fault_class`` (Table 1)."""
    return set().union(*[design.signature_table[f.name] for f in design.model.faults
                         if f.fault_class == fault_class])


def diagnosis_text(summary: dict) -> str:
    """One line: class, time and action of the diagnosis."""
    d = summary["diagnosis"]
    if d["t_isolated"] is None:
        flags = "flags raised but no class isolated" if summary["flags"] else "no flag raised"
        return f"no fault isolated ({flags})"
    named = f"; faults: {d['fault_set']}" if d.get("fault_set", "none") != "none" else ""
    return f"{d['fault']} isolated at {d['t_isolated']:.3f} s, action: {d['action']}{named}"


def envelope(t: np.ndarray, y: np.ndarray, bins: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """Min/max envelope of ``y`` over ``bins`` equal slices of the samples, for drawing.

    A figure a thousand pixels wide cannot show more; peaks (a flag's cause) are kept.
    Returns the input unchanged when it has fewer than ``2 * bins`` samples.
    """
    if len(t) < 2 * bins:
        return t, y
    start = np.linspace(0, len(t), bins, endpoint=False).astype(int)
    lo, hi = np.minimum.reduceat(y, start), np.maximum.reduceat(y, start)
    tt = np.repeat(t[start], 2)
    yy = np.column_stack([lo, hi]).ravel()
    return np.append(tt, t[-1]), np.append(yy, y[-1])


def _use_log_scale(rms: np.ndarray, threshold: float) -> bool:
    positive = rms[rms > 0]
    if positive.size == 0:
        return False
    lo = max(float(np.percentile(positive, 1)), threshold * 1e-3)
    hi = max(float(positive.max()), threshold)
    return hi / lo > LOG_SCALE_SPAN


def power_of_ten(value: float, _pos=None) -> str:
    """A log-axis tick label in plain Unicode: ``10⁻³``, ``2×10⁴``, ``0`` (no mathtext)."""
    if not np.isfinite(value) or value <= 0:
        return ""
    exponent = int(np.floor(np.log10(value) + 1e-9))
    mantissa = value / 10.0 ** exponent
    power = "10" + str(exponent).translate(_SUPERSCRIPT)
    if abs(mantissa - round(mantissa)) > 1e-6 * mantissa:
        return f"{mantissa:.2g}×{power}"
    return power if round(mantissa) == 1 else f"{round(mantissa)}×{power}"


def _log_axis(ax) -> None:
    """Log-scale y axis whose tick labels are plain text (:func:`power_of_ten`)."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(FuncFormatter(power_of_ten))
    ax.yaxis.set_minor_formatter(NullFormatter())


def residual_units(design: FdiDesign) -> dict:
    """Residual -> the unit of its axis (the compared output's ``unit``; empty for an
    expression of several units, a weight or a flag, whose unit is not one word)."""
    from fdigen.design.residual_scale import residual_scales

    try:
        scales = residual_scales(design)
    except Exception:  # noqa: BLE001 - a label never breaks a report
        return {}
    return {n: sc["unit"] for n, sc in scales.items()
            if sc.get("unit") and sc["unit"] != "(no unit given)"
            and not sc["unit"].startswith("that of") and len(sc["unit"]) <= 16}


def _panel(ax, t, rms, threshold, name, t_raised, t_isolated, unit=""):
    log_scale = _use_log_scale(rms, threshold)
    if log_scale:
        _log_axis(ax)
        rms = np.maximum(rms, threshold * 1e-3)
    ax.plot(*envelope(t, rms), color="C0", lw=0.8, label="moving RMS")
    ax.axhline(threshold, color="C3", ls="--", lw=0.9, label="threshold J")
    if t_raised is not None:
        ax.axvspan(t_raised, t[-1], color="C3", alpha=0.12, lw=0, label="flag raised")
        ax.plot([t_raised], [threshold], marker="v", color="C3", ms=6, ls="none")
        ax.annotate(f"{t_raised:.3f} s", (t_raised, threshold), xytext=(4, 4),
                    textcoords="offset points", color="C3", fontsize=7,
                    bbox={"fc": "white", "ec": "none", "alpha": 0.7, "pad": 0.5})
    if t_isolated is not None:
        ax.axvline(t_isolated, color="k", lw=1.0, ls="-.", label="isolated")
    ax.set_ylabel(name + (f" [{unit}]" if unit else "") + (" (log)" if log_scale else ""))
    ax.grid(True, which="major", lw=0.3, alpha=0.6)
    ax.margins(x=0)


def draw_figure(design: FdiDesign, t: np.ndarray, out: dict, summary: dict):
    """The figure (Figs 6-7 of the paper): one panel per residual.

    Returns
    -------
    matplotlib.figure.Figure
        Not attached to pyplot (no display, no global state).
    """
    from matplotlib.figure import Figure

    ev = design.evaluation
    raised = {f["residual"]: f["t_raised"] for f in summary["flags"]}
    t_iso = summary["diagnosis"]["t_isolated"]
    n = len(ev.residuals)
    height = 1.15 * n + 1.3
    fig = Figure(figsize=(10, height), dpi=_DPI)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.55 / height, top=1 - 0.6 / height,
                        hspace=0.3)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    rms = np.asarray(out["rms"], dtype=float)
    units = residual_units(design)
    for i, name in enumerate(ev.residuals):
        _panel(axes[i], t, rms[:, i], float(ev.thresholds[i]), name, raised.get(name), t_iso,
               display_text(units.get(name, "")))
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    axes[0].legend(handles, labels, loc="upper left", ncol=len(labels), fontsize=7,
                   framealpha=0.9)
    axes[-1].set_xlabel("time [s]")
    # the log's file name is input: no control character in the title (illegal in SVG's XML)
    fig.suptitle(display_text(f"{summary['log']}: {diagnosis_text(summary)}"),
                 y=1 - 0.2 / height)
    fig.align_ylabels(axes)
    return fig


def plain_text(fig):
    """Turn off mathtext in every text of ``fig`` (names, paths, class names are plain
    text: a ``$`` or ``^`` in them is no TeX to parse); returns ``fig``."""
    from matplotlib.text import Text

    for text in fig.findobj(Text):
        text.set_parse_math(False)
    return fig


def figure_bytes(fig, fmt: str = "png") -> bytes:
    """The figure as PNG, PDF or SVG bytes (text plain, no mathtext), without date or
    software metadata."""
    plain_text(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=_DPI, metadata=METADATA[fmt])
    return buf.getvalue()


def png_bytes(fig) -> bytes:
    """The figure as PNG bytes (:func:`figure_bytes`)."""
    return figure_bytes(fig, "png")


def _flag_rows(design: FdiDesign, out: dict, summary: dict) -> list[dict]:
    ev = design.evaluation
    raised = {f["residual"]: f["t_raised"] for f in summary["flags"]}
    fault = summary["diagnosis"]["fault"]
    expected = class_signature(design, fault) if fault != "none" else set()
    peak = np.max(np.asarray(out["rms"], dtype=float), axis=0)
    rows = []
    for i, name in enumerate(ev.residuals):
        rows.append({"residual": name, "threshold": f"{ev.thresholds[i]:.4g}",
                     "max_rms": f"{peak[i]:.4g}",
                     "raised": f"{raised[name]:.3f}" if name in raised else "-",
                     "expected": ("yes" if name in expected else "no") if expected else "-"})
    return rows


def html_page(design: FdiDesign, out: dict, summary: dict, png: bytes) -> str:
    """A self-contained HTML page: diagnosis, flag table, the figure as a data URI."""
    env = jinja2.Environment(undefined=jinja2.StrictUndefined, autoescape=True,
                             trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)
    d = summary["diagnosis"]
    return env.from_string(_HTML).render(
        log=display_text(summary["log"]), model=display_text(design.model.name),
        samples=summary["samples"],
        sample_time=f"{summary['sample_time']:g}", backend=summary.get("backend", "?"),
        diagnosis=d, isolated="-" if d["t_isolated"] is None else f"{d['t_isolated']:.3f}",
        candidates=", ".join(d["candidates"]) or "-", rows=_flag_rows(design, out, summary),
        png=base64.b64encode(png).decode("ascii"))


def render_report(design: FdiDesign, log_path: str | Path, output_path: str | Path,
                  backend: str = "auto") -> dict:
    """Run the FDI over a log and write the report (PNG, PDF, SVG or HTML, by the suffix).

    Parameters
    ----------
    design : FdiDesign
    log_path : str or Path
        A log in the rig format.
    output_path : str or Path
        ``*.png``, ``*.pdf``, ``*.svg`` or ``*.html``.
    backend : str
        FDI backend of :func:`fdigen.detect.fdi_runner`.

    Returns
    -------
    dict
        The decision (as ``fdigen detect --json``).

    Raises
    ------
    LogError
        If the log is malformed.
    ReportError
        On an unknown output format or a file that cannot be written.
    """
    import matplotlib

    fmt = output_format(output_path)
    folder = Path(output_path).resolve().parent
    if not folder.is_dir():
        raise ReportError(f"{output_path}: cannot write report (no folder {folder})")
    t, out, summary = analyse_log(design, log_path, backend)
    with matplotlib.rc_context(_STYLE):
        fig = draw_figure(design, t, out, summary)
        data = figure_bytes(fig, "png" if fmt == "html" else fmt)
    if fmt == "html":
        data = html_page(design, out, summary, data).encode("utf-8")
    try:
        write_bytes(output_path, data)   # atomic, symbolic links followed
    except OSError as exc:
        raise ReportError(f"{output_path}: cannot write report ({exc.strerror or exc})") from None
    return summary

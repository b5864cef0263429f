"""Proof of absence of run-time errors in the generated C: Frama-C EVA over the declared
input domain.

:func:`render_eva_driver` renders the analysis driver (``templates/verify/eva_driver.c.j2``)
that calls every function of the generated core over the declared input domain: any
sample (every finite value, NaN and the infinities: the step's validity checks replace a
sample beyond its validity bound), every parameter within its bounds, whatever state the
caller's memory holds before ``_init`` and then any number of steps, and one step from any
bytes at all (a corrupted state). :func:`prove` runs EVA (abstract interpretation: a sound
over-approximation of every execution) on the driver and the core and reports each alarm
(a possible undefined behaviour: out-of-bounds access, signed overflow, uninitialised read,
invalid float-to-integer conversion, invalid pointer, division by zero of integers) with its
line, and the coverage. 0 alarms is the proof.

Floating point follows IEEE 754 (``-warn-special-float none``): NaN and the infinities are
values the step is designed to take (a non-finite sample or residual raises its flag, see
:class:`~fdigen.design.evaluation.Evaluation`), not errors.
"""

from __future__ import annotations

import re
import subprocess
import tempfile
import time
from pathlib import Path

from fdigen.backends.c.emit import c_context, render_c_sources
from fdigen.backends.render import render
from fdigen.design.fdi_design import FdiDesign
from fdigen.model.model_file import model_hash
from fdigen.verify.tools import require_tool

#: The largest finite value of each real type, as a C literal.
REAL_MAX = {"double": "1.7976931348623157e308", "float": "3.40282347e38f"}
#: EVA's precision (0..11) of `fdigen prove` by default: 0 alarms on every shipped model.
DEFAULT_PRECISION = 1
#: Frama-C's machine model per variant: the double core for a 64-bit host; the float core
#: for the Cortex-M4F target's data model (ILP32: int, long and pointers of 32 bits). Frama-C
#: has no Arm machine model; x86_32 differs from the Arm EABI in the signedness of plain
#: char and the alignment of 64-bit types, neither of which the float core uses (no
#: arithmetic on char, no 64-bit type; counters and masks are int32_t/uint32_t).
MACHDEP = {"double": "x86_64", "float": "x86_32"}
_ALARM = re.compile(r"^\[eva:alarm\] ([^:\n]+):(\d+): Warning: *\n((?:  .*\n?)+)", re.M)
_FUNCTIONS = re.compile(r"(\d+) functions? analyzed \(out of (\d+)\)")
_STATEMENTS = re.compile(r"(\d+) statements? reached \(out of (\d+)\)")


def render_eva_driver(design: FdiDesign, float_type: str = "double") -> str:
    """The EVA analysis driver of a design's generated C core (a C file).

    Parameters
    ----------
    design : FdiDesign
    float_type : {"double", "float"}

    Returns
    -------
    str
    """
    ctx = c_context(design, float_type)
    sizes = ctx["sizes"]
    real_max = REAL_MAX[float_type]
    params = [{"field": q["field"],
               "lo": q["bounds"][0] if q["bounds"] else f"-{real_max}",
               "hi": q["bounds"][1] if q["bounds"] else real_max} for q in ctx["params"]]
    return render("verify/eva_driver.c.j2", comment="//", model_name=design.name,
                  model_source=Path(design.model.source or design.name).name,
                  model_hash=model_hash(design.model), prefix=ctx["prefix"],
                  macro=ctx["macro"], header=ctx["header"], real_type=float_type,
                  real_max=real_max, params=params,
                  **{f"n{k}": max(n, 1) for k, n in sizes.items()})


def parse_eva_output(text: str) -> dict:
    """Alarms (file, line, assertion) and coverage from EVA's log.

    Returns
    -------
    dict
        ``alarms`` (list of ``{"file", "line", "message"}``), ``functions`` and
        ``statements`` (``[reached, total]``).
    """
    alarms = [{"file": Path(f).name, "line": int(line),
               "message": " ".join(msg.split())} for f, line, msg in _ALARM.findall(text)]
    functions = _FUNCTIONS.search(text)
    statements = _STATEMENTS.search(text)
    if functions is None or statements is None:
        raise RuntimeError("Frama-C printed no analysis summary:\n" + text[-2000:])
    return {"alarms": alarms, "functions": [int(functions[1]), int(functions[2])],
            "statements": [int(statements[1]), int(statements[2])]}


def run_eva(sources: dict[str, str], core: str, *, precision: int = DEFAULT_PRECISION,
            machdep: str = "x86_64", timeout: float = 600.0) -> dict:
    """Run EVA on ``sources`` (file name -> text: the core, its header and
    ``eva_driver.c``) and parse its log (:func:`parse_eva_output`), plus ``seconds``."""
    frama_c = require_tool("frama-c")
    with tempfile.TemporaryDirectory(prefix="fdigen-prove-") as tmp:
        folder = Path(tmp)
        for name, text in sources.items():
            (folder / name).write_text(text)
        cmd = [frama_c, "-eva", "-eva-precision", str(int(precision)),
               "-warn-special-float", "none", "-machdep", machdep,
               "-kernel-warn-key", "parser:decimal-float=inactive",
               "-eva-no-show-progress", f"-cpp-extra-args=-I{folder}",
               str(folder / "eva_driver.c"), str(folder / core)]
        start = time.perf_counter()
        proc = subprocess.run(cmd, cwd=folder, capture_output=True, text=True,
                              timeout=timeout)
        seconds = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"frama-c failed (exit {proc.returncode}):\n"
                           + (proc.stdout + proc.stderr)[-2000:])
    res = parse_eva_output(proc.stdout)
    res["seconds"] = round(seconds, 2)
    return res


def prove_variant(design: FdiDesign, float_type: str = "double", *,
                  precision: int = DEFAULT_PRECISION) -> dict:
    """Run EVA on the generated core of one float type.

    Returns
    -------
    dict
        ``float_type``, ``alarms`` (count), ``alarm_list``, ``coverage``
        (``{"functions": [reached, total], "statements": [reached, total]}``),
        ``seconds`` (wall time of the analysis) and ``precision``.
    """
    rendered = render_c_sources(design, float_type=float_type,
                                model_source=Path(design.model.source or design.name).name,
                                model_hash=model_hash(design.model))
    core, header = f"{design.name}_fdi.c", f"{design.name}_fdi.h"
    res = run_eva({core: rendered[core], header: rendered[header],
                   "eva_driver.c": render_eva_driver(design, float_type)}, core,
                  precision=precision, machdep=MACHDEP[float_type])
    return {"float_type": float_type, "alarms": len(res["alarms"]),
            "alarm_list": res["alarms"],
            "coverage": {"functions": res["functions"], "statements": res["statements"]},
            "seconds": res["seconds"], "precision": int(precision),
            "machdep": MACHDEP[float_type]}


def prove(design: FdiDesign, float_types=("double", "float"), *,
          precision: int = DEFAULT_PRECISION) -> dict:
    """EVA on every float type of a design's generated C core.

    Returns
    -------
    dict
        ``model``, ``alarms`` (total count), ``coverage`` (the smallest statement
        coverage of the variants, a fraction), ``variants`` (:func:`prove_variant` each),
        ``assumptions`` (the analysed domain, in words).
    """
    variants = [prove_variant(design, ft, precision=precision) for ft in float_types]
    return {"model": design.name,
            "alarms": sum(v["alarms"] for v in variants),
            "coverage": min(v["coverage"]["statements"][0] / v["coverage"]["statements"][1]
                            for v in variants),
            "variants": variants,
            "assumptions": ["every input and output sample any value of the real type, "
                            "NaN and infinities included",
                            "every parameter within its declared bounds (any finite value "
                            "where none are declared)",
                            "any caller memory as the state before _init, then any number "
                            "of steps; one step from any bytes (corrupted state)",
                            "IEEE 754 floating point (-warn-special-float none); machine "
                            "model x86_64 for the double core, x86_32 (ILP32, as the "
                            "Cortex-M4F) for the float core"]}

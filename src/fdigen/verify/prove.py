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

import os
import re
import subprocess
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from fdigen.backends.c.emit import c_context, render_c_sources
from fdigen.backends.render import render
from fdigen.design.fdi_design import FdiDesign
from fdigen.model.model_file import model_hash
from fdigen.verify.tools import ToolFailedError, require_tool

#: The largest finite value of each real type, as a C literal.
REAL_MAX = {"double": "1.7976931348623157e308", "float": "3.40282347e38f"}
#: The smallest positive normal value of each real type, as a C literal.
REAL_MIN = {"double": "2.2250738585072014e-308", "float": "1.17549435e-38f"}
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


def render_eva_platform_driver(design: FdiDesign, float_type: str = "double") -> str:
    """The EVA analysis driver of the six-leg bank (``<m>_platform_step``), a C file."""
    from fdigen.platform.codegen import platform_names

    ctx = c_context(design, float_type)
    names = platform_names(design.name)
    real_max = REAL_MAX[float_type]
    params = [{"field": q["field"],
               "lo": q["bounds"][0] if q["bounds"] else f"-{real_max}",
               "hi": q["bounds"][1] if q["bounds"] else real_max} for q in ctx["params"]]
    return render("verify/eva_platform_driver.c.j2", comment="//", model_name=design.name,
                  model_source=Path(design.model.source or design.name).name,
                  model_hash=model_hash(design.model), prefix=names["prefix"],
                  macro=names["macro"], header=names["header"], real=ctx["real"],
                  real_type=float_type, real_max=real_max, real_min=REAL_MIN[float_type],
                  params=params)


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
        raise ToolFailedError("Frama-C printed no analysis summary:\n" + text[-2000:])
    return {"alarms": alarms, "functions": [int(functions[1]), int(functions[2])],
            "statements": [int(statements[1]), int(statements[2])]}


def run_eva(sources: dict[str, str], cores, *, precision: int = DEFAULT_PRECISION,
            machdep: str = "x86_64", timeout: float = 1200.0) -> dict:
    """Run EVA on ``sources`` (file name -> text: the analysed C files ``cores`` (a name or
    a list), their headers and ``eva_driver.c``) and parse its log
    (:func:`parse_eva_output`), plus ``seconds``."""
    cores = [cores] if isinstance(cores, str) else list(cores)
    frama_c = require_tool("frama-c")
    with tempfile.TemporaryDirectory(prefix="fdigen-prove-") as tmp:
        folder = Path(tmp)
        for name, text in sources.items():
            (folder / name).write_text(text)
        cmd = [frama_c, "-eva", "-eva-precision", str(int(precision)),
               "-warn-special-float", "none", "-machdep", machdep,
               "-kernel-warn-key", "parser:decimal-float=inactive",
               "-eva-no-show-progress", f"-cpp-extra-args=-I{folder}",
               str(folder / "eva_driver.c"), *(str(folder / c) for c in cores)]
        start = time.perf_counter()
        proc = subprocess.run(cmd, cwd=folder, capture_output=True, text=True,
                              timeout=timeout)
        seconds = time.perf_counter() - start
    if proc.returncode != 0:
        raise ToolFailedError(f"frama-c failed (exit {proc.returncode}):\n"
                           + (proc.stdout + proc.stderr)[-2000:])
    res = parse_eva_output(proc.stdout)
    res["seconds"] = round(seconds, 2)
    return res


def _variant_sources(design: FdiDesign, float_type: str, platform: bool):
    """The files EVA analyses for one float type, and the cores among them."""
    src, digest = Path(design.model.source or design.name).name, model_hash(design.model)
    if platform:
        from fdigen.platform.codegen import render_platform_sources

        files = render_platform_sources(design, float_type=float_type, model_source=src,
                                        model_hash=digest)
        driver = render_eva_platform_driver(design, float_type)
    else:
        files = render_c_sources(design, float_type=float_type, model_source=src,
                                 model_hash=digest)
        driver = render_eva_driver(design, float_type)
    files = {n: t for n, t in files.items() if n.startswith(design.name)}
    files["eva_driver.c"] = driver
    cores = sorted(n for n in files if n.endswith(".c") and n != "eva_driver.c")
    return files, cores


def _variant_report(float_type: str, res: dict, precision: int) -> dict:
    return {"float_type": float_type, "alarms": len(res["alarms"]),
            "alarm_list": res["alarms"],
            "coverage": {"functions": res["functions"], "statements": res["statements"]},
            "seconds": res["seconds"], "precision": int(precision),
            "machdep": MACHDEP[float_type]}


def prove_variant(design: FdiDesign, float_type: str = "double", *,
                  precision: int = DEFAULT_PRECISION, platform: bool = False) -> dict:
    """Run EVA on the generated core of one float type (with ``platform``: the six-leg
    bank and the leg core it calls).

    Returns
    -------
    dict
        ``float_type``, ``alarms`` (count), ``alarm_list``, ``coverage``
        (``{"functions": [reached, total], "statements": [reached, total]}``),
        ``seconds`` (wall time of the analysis), ``precision`` and ``machdep``.
    """
    files, cores = _variant_sources(design, float_type, platform)
    res = run_eva(files, cores, precision=precision, machdep=MACHDEP[float_type])
    return _variant_report(float_type, res, precision)


def prove(design: FdiDesign, float_types=("double", "float"), *,
          precision: int = DEFAULT_PRECISION, platform: bool = False) -> dict:
    """EVA on every float type of a design's generated C core.

    Returns
    -------
    dict
        ``model``, ``alarms`` (total count), ``coverage`` (the smallest statement
        coverage of the variants, a fraction), ``variants`` (:func:`prove_variant` each),
        ``assumptions`` (the analysed domain, in words).
    """
    # the sources are rendered here, one after the other (sympy's printing is not
    # thread-safe); the analyses, separate Frama-C processes, run side by side
    sources = [_variant_sources(design, ft, platform) for ft in float_types]
    with ThreadPoolExecutor(max_workers=max(1, min(len(sources), os.cpu_count() or 1))) as ex:
        results = list(ex.map(lambda fc, ft: run_eva(fc[0], fc[1], precision=precision,
                                                     machdep=MACHDEP[ft]),
                              sources, float_types))
    variants = [_variant_report(ft, res, precision) for ft, res in zip(float_types, results)]
    return {"model": design.name, "platform": bool(platform),
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

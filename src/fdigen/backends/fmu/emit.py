"""Render the FMI 2.0 co-simulation wrapper of the generated C core and its model
description.

The FMU's variables (value references unique across types, in this order):

* inputs (Real; continuous, so that importers sample them at the communication points
  without events): the model's inputs (commands) and measured outputs, named by their
  log columns;
* parameters (Real, fixed): the model's parameters (defaults from the model file) and the
  RMS thresholds ``J_<residual>`` (defaults from the design);
* outputs: residuals ``r_<residual>`` and their moving RMS ``rms_<residual>`` (Real),
  ``flag_<residual>`` (Boolean), ``flags``, ``fault_class``, ``action``, ``faults`` and
  ``status`` (Integer; the C core's codes).

Each ``fmi2DoStep`` from ``t`` to ``t + h`` runs the C core's ``_step`` once per sample
time that ends in ``(t, t + h]`` on the inputs set before the call; the outputs are then
those of the last sample. ``t`` must be the FMU's time (its start time, then where the
previous step ended, to half a sample; FMI 2.0): a step back in time, or one that skips
ahead, is refused with ``fmi2Error`` and a logged message (a step back returned
``fmi2OK`` and did nothing). One call runs at most :data:`MAX_STEP_SAMPLES` samples (the
C's ``<MODEL>_FDI_FMU_MAX_STEP_SAMPLES``): a longer step is refused the same way, so that
one call is bounded in time (2e9 samples, some 5 minutes, were accepted).
"""

from __future__ import annotations

import hashlib
import uuid

from fdigen.backends.c.emit import c_context
from fdigen.backends.escape import comment_text
from fdigen.backends.render import environment, render
from fdigen.design.config import ACTIONS
from fdigen.design.fdi_design import FdiDesign
from fdigen.errors import BuildError

#: Samples one ``fmi2DoStep`` runs at most (the wrapper's
#: ``<MODEL>_FDI_FMU_MAX_STEP_SAMPLES``): about 0.1 to 1 s of a core step of 0.1 to 1 us,
#: 1000 s of a 1 ms sample time in one call.
MAX_STEP_SAMPLES = 1_000_000

#: Templates of the FMU: output name -> (template, comment leader or None for XML).
TEMPLATES = {"modelDescription.xml": ("fmu/modelDescription.xml.j2", None),
             "fmi2.c": ("fmu/fmi2.c.j2", "//")}


def _text(text) -> str:
    """Free text for an XML attribute: one line, no control characters (escaped by the
    template's ``e`` filter)."""
    return comment_text(text, "/*").replace("--", "- -")


def xml_real(value: float) -> str:
    """A real as ``xs:double`` text: ``repr`` of a finite value, ``INF``, ``-INF``, ``NaN``."""
    value = float(value)
    if value != value:
        return "NaN"
    if value in (float("inf"), float("-inf")):
        return "INF" if value > 0 else "-INF"
    return repr(value)


def fmu_variables(design: FdiDesign, ctx: dict) -> list[dict]:
    """The FMU's scalar variables in value-reference order, each with the C expression
    that reads it (``get``) and, for inputs and parameters, the lvalue that sets it."""
    model, ev = design.model, design.evaluation
    out: list[dict] = []

    def add(name, typ, causality, variability, get, set_=None, start=None, description=""):
        out.append({"name": name, "type": typ, "causality": causality,
                    "variability": variability, "read": get, "write": set_,
                    "start": start, "description": _text(description), "vr": len(out)})

    for i, s in enumerate(model.inputs):
        add(s.column or s.name, "Real", "input", "continuous", f"inst->u[{i}]", f"inst->u[{i}]",
            "0", f"command {s.name} [{s.unit}]")
    for i, o in enumerate(model.outputs):
        add(o.column or o.name, "Real", "input", "continuous", f"inst->y[{i}]", f"inst->y[{i}]",
            "0", f"measurement {o.name} [{o.unit}]")
    for q, p in zip(model.parameters, ctx["params"]):
        field = f"inst->p.params.{p['field']}"
        add(q.name, "Real", "parameter", "fixed", field, field, xml_real(q.value),
            f"{q.description} [{q.unit}]")
    for i, name in enumerate(ev.residuals):
        add(f"J_{name}", "Real", "parameter", "fixed", f"inst->p.thresholds[{i}]",
            f"inst->p.thresholds[{i}]", xml_real(ev.thresholds[i]),
            f"RMS threshold of residual {name}")
    for i, name in enumerate(ev.residuals):
        add(f"r_{name}", "Real", "output", "discrete", f"inst->out.r[{i}]",
            description=f"residual {name}")
    for i, name in enumerate(ev.residuals):
        add(f"rms_{name}", "Real", "output", "discrete", f"inst->out.rms[{i}]",
            description=f"moving RMS of residual {name}")
    for i, name in enumerate(ev.residuals):
        add(f"flag_{name}", "Boolean", "output", "discrete",
            f"(fmi2Boolean)((inst->out.flags >> {i}) & 1u)",
            description=f"latched flag of residual {name}")
    classes = ", ".join(f"{k} {c}" for k, c in enumerate(ev.classes))
    actions = ", ".join(f"{k} {a}" for k, a in enumerate(ACTIONS))
    add("flags", "Integer", "output", "discrete", "(fmi2Integer)inst->out.flags",
        description="latched flags, bit i = residual i")
    add("fault_class", "Integer", "output", "discrete", "(fmi2Integer)inst->out.fault_class",
        description=f"isolated fault class: {classes}")
    add("action", "Integer", "output", "discrete", "(fmi2Integer)inst->out.action",
        description=f"action: {actions}")
    add("faults", "Integer", "output", "discrete", "(fmi2Integer)inst->out.faults",
        description="faults consistent with the flags, bit k = "
                    + ", ".join(ev.fault_names))
    add("status", "Integer", "output", "discrete", "(fmi2Integer)inst->status",
        description="status of the last step: 0 ok, 1 a state or residual not finite")
    names = [v["name"] for v in out]
    clash = sorted({n for n in names if names.count(n) > 1})
    if clash:
        raise BuildError(f"the FMU of {model.name} would have two variables named "
                         f"{', '.join(map(repr, clash))} (log columns, parameters and the "
                         "FMU's outputs need distinct names)")
    return out


def fmu_guid(model_hash: str, text: str) -> str:
    """A GUID that changes with the FMU's interface and code (deterministic)."""
    digest = hashlib.sha256((model_hash + "\n" + text).encode()).digest()
    return "{" + str(uuid.UUID(bytes=digest[:16], version=5)) + "}"


def render_fmu_sources(design: FdiDesign, *, model_source: str, model_hash: str,
                       core_files: dict[str, str]) -> dict[str, str]:
    """The FMU's text files: ``modelDescription.xml`` and the wrapper
    ``<model>_fdi_fmi2.c`` (double precision, over the C backend's ``core_files``).

    Returns
    -------
    dict of str to str
        File name -> text.
    """
    ctx = c_context(design, "double")
    variables = fmu_variables(design, ctx)
    identifier = ctx["prefix"]
    wrapper_name = f"{identifier}_fmi2.c"
    wrapper = render(TEMPLATES["fmi2.c"][0], comment="//", model_name=design.name,
                     model_source=model_source, model_hash=model_hash,
                     variables=variables, core_file=f"{identifier}.c",
                     max_step_samples=MAX_STEP_SAMPLES, **ctx)
    guid = fmu_guid(model_hash, wrapper + "".join(core_files[k] for k in sorted(core_files)))
    xml = environment().get_template(TEMPLATES["modelDescription.xml"][0]).render(
        model_name=design.name, model_hash=model_hash, identifier=identifier, guid=guid,
        variables=variables, sample_time=xml_real(design.config.sample_time),
        sources=[wrapper_name], description=_text(
            f"fault detection and isolation of {design.name}: residuals, moving RMS, "
            f"latched flags and isolation, one sample every {design.config.sample_time!r} s"))
    return {"modelDescription.xml": xml, wrapper_name: wrapper}

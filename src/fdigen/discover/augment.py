"""Add: write the augmented model file and rebuild the generated code from it.

The augmented file is the original TOML *text*, edited in place line by line (comments,
layout and every other table kept):

* the chosen effect's term is appended to the string of each equation it changes
  (``xdot = "A/M*(Pp - Pn) - Ff/M*xdot - Fc/M*tanh(xdot/0.005)"``), an output offset to
  the output's ``expr``;
* the effect's parameter is added to ``[parameters]`` with its estimate, unit, bounds and
  the estimate's standard deviation in its description;
* the model's ``uncertain`` parameters get their calibrated values (``calibrated=True``);
* if the effect makes the model stiff (largest Jacobian eigenvalue ``|lambda|`` over the
  log), ``[fdi] substeps`` is raised so that the parallel model's RK4 step keeps
  ``|lambda| dt / substeps <= 1.5`` (RK4 is stable up to 2.8 on the real axis);
* a comment at the top says where it came from.

The text is parsed back with :func:`fdigen.model.model_file.parse_model_text` and checked:
every changed equation must equal the original plus the term (symbolically). The file is
then built with :func:`fdigen.pipeline.build` into its own folder (never the repository's
``generated/``).
"""

from __future__ import annotations

import ast
import json
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import sympy as sp

from fdigen.backends.escape import comment_text
from fdigen.errors import FdigenError, ModelFileError
from fdigen.files.atomic import write_text
from fdigen.model.model import Model
from fdigen.model.model_file import parse_model_text
from fdigen.safe_lambdify import safe_lambdify

#: Largest RK4 step times stiffness accepted in the generated parallel model.
RK4_MARGIN = 1.5


def _sections(lines: list[str]) -> dict[str, tuple[int, int]]:
    """Table name -> (first line after its header, line of the next header)."""
    heads = []
    for i, line in enumerate(lines):
        m = re.match(r"^\s*\[\s*([^\[\]]+?)\s*\]\s*(#.*)?$", line)
        if m:
            heads.append((m.group(1), i))
    out = {}
    for j, (name, i) in enumerate(heads):
        end = heads[j + 1][1] if j + 1 < len(heads) else len(lines)
        out.setdefault(name, (i + 1, end))
    return out


def _key_line(lines, span, key) -> int:
    lo, hi = span
    for i in range(lo, hi):
        if re.match(rf"^\s*{re.escape(key)}\s*=", lines[i]):
            return i
    return -1


def _toml_string(text: str) -> str:
    return json.dumps(text)  # a valid TOML basic string for these ASCII expressions


def _append_term(expr_text: str, term: str) -> str:
    body = ast.parse(term.strip(), mode="eval").body
    if isinstance(body, ast.BinOp) and isinstance(body.op, (ast.Add, ast.Sub)):
        return f"{expr_text} + ({term.strip()})"
    if term.strip().startswith("-"):
        return f"{expr_text} - {term.strip()[1:].lstrip()}"
    return f"{expr_text} + {term.strip()}"


def _replace_string_value(line: str, key: str, new_value: str, source: str, field: str) -> str:
    """Replace the basic/literal string after ``key =`` on one line."""
    m = re.search(rf"(\b{re.escape(key)}\s*=\s*)(\"(?:[^\"\\\\]|\\\\.)*\"|'[^']*')", line)
    if not m:
        raise ModelFileError("cannot edit this equation in place (expected a one-line "
                             "string)", source=source, field=field)
    return line[:m.start(2)] + _toml_string(new_value) + line[m.end(2):]


def _fmt(v: float) -> str:
    s = f"{float(v):.6g}"
    return s if any(c in s for c in ".en") else s + ".0"


def augmented_text(text: str, model: Model, effects, params: dict, std: dict | None = None,
                   *, calibrated: dict | None = None, substeps: int | None = None,
                   origin: str = "") -> str:
    """The model file text with the effects added (see the module docstring).

    Parameters
    ----------
    text : str
        The original model file.
    model : Model
        Its parsed model.
    effects : sequence of LibraryEffect
    params : dict
        Effect parameter name -> estimate.
    std : dict, optional
        Standard deviations of the estimates (written in the descriptions).
    calibrated : dict, optional
        Calibrated values of the model's own parameters to write.
    substeps : int, optional
        New ``[fdi] substeps`` (only raised, never lowered).
    origin : str
        Where the estimates come from (the log), for the comments.
    """
    std = std or {}
    src = model.source
    doc = tomllib.loads(text)
    lines = text.split("\n")
    secs = _sections(lines)
    # 1. equations and outputs
    for e in effects:
        for state in e.states:
            span = secs.get("dynamics")
            i = _key_line(lines, span, state) if span else -1
            if i < 0:
                raise ModelFileError("equation not found in [dynamics]", src,
                                     f"dynamics.{state}")
            new = _append_term(doc["dynamics"][state], e.text(state))
            lines[i] = _replace_string_value(lines[i], state, new, src, f"dynamics.{state}")
            doc["dynamics"][state] = new
        for out in e.outputs:
            span = secs.get("outputs")
            i = _key_line(lines, span, out) if span else -1
            if i < 0 or "expr" not in lines[i]:
                raise ModelFileError("output not found as an inline table in [outputs]", src,
                                     f"outputs.{out}")
            new = _append_term(doc["outputs"][out]["expr"], e.text(out))
            lines[i] = _replace_string_value(lines[i], "expr", new, src, f"outputs.{out}")
    # 2. calibrated values of existing parameters
    pspan = secs.get("parameters")
    for name, value in (calibrated or {}).items():
        i = _key_line(lines, pspan, name)
        if i < 0:
            raise ModelFileError("parameter not found", src, f"parameters.{name}")
        lines[i], count = re.subn(r"(\bvalue\s*=\s*)([-+0-9.eE_]+)",
                                  lambda m: m.group(1) + _fmt(value), lines[i], count=1)
        if not count:
            raise ModelFileError("cannot edit this parameter's value in place", src,
                                 f"parameters.{name}")
    # 3. new parameters, after the last entry of [parameters]
    last = max(i for i in range(pspan[0], pspan[1])
               if re.match(r"^\s*[A-Za-z_][A-Za-z0-9_]*\s*=", lines[i]))
    new_lines = []
    for e in effects:
        for p in e.parameters:
            v = min(max(float(params[p.name]), p.bounds[0]), p.bounds[1])
            s = std.get(p.name)
            desc = p.description + (f" (fdigen discover: {_fmt(v)} +- {float(s):.2g}"
                                    f"{' from ' + origin if origin else ''})"
                                    if s is not None and math.isfinite(s) else "")
            new_lines.append(
                f"{p.name} = {{ value = {_fmt(v)}, unit = {_toml_string(p.unit)}, "
                f"description = {_toml_string(desc)}, "
                f"bounds = [{_fmt(p.bounds[0])}, {_fmt(p.bounds[1])}] }}")
    lines[last + 1:last + 1] = new_lines
    # 4. sub-steps of the parallel model
    if substeps is not None:
        secs = _sections(lines)
        span = secs.get("fdi")
        if span is None:
            raise ModelFileError("no [fdi] table to set substeps in", src, "fdi")
        i = _key_line(lines, span, "substeps")
        if i >= 0:
            lines[i] = re.sub(r"(\bsubsteps\s*=\s*)(\d+)", lambda m: m.group(1) + str(substeps),
                              lines[i], count=1)
        else:
            lines.insert(span[0], f"substeps = {substeps}")
    origin = comment_text(origin, "#")    # a log's name: one line, no TOML can follow
    found = (", ".join(e.name for e in effects) + " added" if effects
             else "no effect found, none added")
    head = [f"# Augmented by `fdigen discover`{' from ' + origin if origin else ''}: "
            + found
            + ("; uncertain parameters calibrated (" + ", ".join(calibrated) + ")"
               if calibrated else "") + "."]
    return "\n".join(head + lines)


def check_augmented(text: str, model: Model, effects, source: str) -> Model:
    """Parse the augmented text and check each changed equation is original + its terms.

    Several effects may act on one equation (Coulomb friction and a load on the force
    balance): each changed equation or output is compared with the original plus the sum
    of *all* the terms added to it,

    .. math:: f_i^{aug} - f_i - \\sum_{e\\ \\text{acting on}\\ i} t_{e,i} = 0 .
    """
    new = parse_model_text(text, source=source)
    from fdigen.derive.budget import BudgetExceeded, symbolic_budget, time_budget

    def is_zero(diff) -> bool:
        """``simplify(diff) == 0`` within the symbolic budget, else at random points."""
        try:
            with time_budget(symbolic_budget(), "check of the augmented equations"):
                return sp.simplify(diff) == 0
        except BudgetExceeded:
            return _zero_at_random_points(diff)

    added: dict[str, list] = {}
    names: dict[str, list] = {}
    for e in effects:
        for target, term in e.terms(model).items():
            added.setdefault(target, []).append(term)
            names.setdefault(target, []).append(e.name)
    states = {s.name for s in model.states}
    for target, terms in added.items():
        if target in states:
            k = model.state_index(target)
            diff = (new.expand(new.dynamics[k]) - model.expand(model.dynamics[k])
                    - model.expand(sp.Add(*terms)))
            what = "equation"
        else:
            k = model.output_index(target)
            diff = new.outputs[k].expr - model.outputs[k].expr - sp.Add(*terms)
            what = "output"
        if not is_zero(diff):
            raise FdigenError(f"augmented {what} {target} is not the original plus the "
                              f"term(s) of {', '.join(names[target])} (difference {diff})")
    return new


def _zero_at_random_points(expr, points: int = 5, seed: int = 0) -> bool:
    """Whether ``expr`` vanishes at random points (every symbol uniform in [0.5, 2])."""
    syms = sorted(expr.free_symbols, key=sp.default_sort_key)
    fn = sp.lambdify(syms, expr, modules="numpy")
    rng = np.random.default_rng(seed)
    for _ in range(points):
        args = rng.uniform(0.5, 2.0, len(syms))
        with np.errstate(all="ignore"):
            v = complex(fn(*args))
        if np.isfinite(v) and abs(v) > 1e-9:
            return False
    return True


def stiffness(model: Model, data, values: dict | None = None, points: int = 2000) -> float:
    """Largest ``|eigenvalue|`` of ``df/dx`` over (a subsample of) the reconstructed states.

    Parameters
    ----------
    model : Model
        With its parameter values (or ``values`` overriding them).
    data : EquationData
    """
    from fdigen.derive.nonsmooth import jacobian

    f = model.f()
    J = jacobian(f, model.x)
    vals = {q.symbol: float(q.value) for q in model.parameters}
    vals.update({sp.Symbol(k, real=True): float(v) for k, v in (values or {}).items()})
    J = J.xreplace(vals)
    fn = safe_lambdify([*model.x, *model.u], J, modules="numpy")
    step = max(len(data.xs) // points, 1)
    xs = data.xs[::step]
    us = data.u[::step]
    n = len(model.states)
    mats = np.empty((len(xs), n, n))
    for k in range(len(xs)):
        mats[k] = np.asarray(fn(*xs[k], *us[k]), dtype=float)
    ev = np.linalg.eigvals(mats)
    return float(np.max(np.abs(ev)))


def required_substeps(model: Model, data, current: int = 1) -> int | None:
    """Sub-steps the parallel model needs for ``model`` (``None`` if ``current`` suffices)."""
    lam = stiffness(model, data)
    dt = float(model.fdi.get("sample_time", data.dt))
    need = int(math.ceil(lam * dt / RK4_MARGIN))
    return need if need > current else None


def write_augmented(model_path, out_dir, model: Model, effects, params: dict, std: dict,
                    data=None, *, calibrated: dict | None = None, origin: str = "",
                    file_name: str | None = None) -> tuple[Path, Model]:
    """Write the augmented model file into ``out_dir`` and check it parses back.

    Returns
    -------
    (Path, Model)
        The file and its parsed model.
    """
    text = Path(model_path).read_text()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / (file_name or f"{model.name}_discovered.toml")
    aug = augmented_text(text, model, effects, params, std, calibrated=calibrated,
                         origin=origin)
    new = check_augmented(aug, model, effects, str(path))
    if data is not None:
        current = int(model.fdi.get("substeps", 1))
        sub = required_substeps(new, data, current)
        if sub is not None:
            aug = augmented_text(text, model, effects, params, std, calibrated=calibrated,
                                 origin=origin, substeps=sub)
            new = check_augmented(aug, model, effects, str(path))
    write_text(path, aug)   # atomic; a symlinked model file: its target, mode kept
    from fdigen.model.model_file import load_model

    return path, load_model(path)


def rebuild(model_file, out_dir):
    """Build the augmented model into ``out_dir`` (refuses ``generated/`` of the current
    folder and of the source checkout: the built-in models' output).

    Returns
    -------
    fdigen.pipeline.BuildResult
    """
    from fdigen.pipeline import DEFAULT_OUT, build

    from fdigen.resources import SOURCE_ROOT

    out = Path(out_dir).resolve()
    protected = {DEFAULT_OUT.resolve()}
    if SOURCE_ROOT is not None:
        protected.add((SOURCE_ROOT / DEFAULT_OUT).resolve())
    for folder in protected:
        if out == folder or folder in out.parents:
            raise FdigenError(f"refusing to build a discovered model into {folder}: that "
                              "folder holds the built-in model's generated code; choose --out")
    return build(model_file, out)

"""Add: write the augmented model file and rebuild the generated code from it.

The augmented file is the original TOML *document*, edited with tomlkit (comments, layout
and every other table kept; values are set as TOML values, never by text substitution, so
a description reading "value = 100" is never touched and any text is escaped):

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
import math
from pathlib import Path

import numpy as np
import sympy as sp

from fdigen.backends.escape import comment_text
from fdigen.errors import FdigenError, ModelFileError
from fdigen.files.model_write import write_model_text
from fdigen.model.model import Model
from fdigen.model.model_file import parse_model_text
from fdigen.safe_lambdify import safe_lambdify

#: Largest RK4 step times stiffness accepted in the generated parallel model.
RK4_MARGIN = 1.5


def _append_term(expr_text: str, term: str) -> str:
    body = ast.parse(term.strip(), mode="eval").body
    if isinstance(body, ast.BinOp) and isinstance(body.op, (ast.Add, ast.Sub)):
        return f"{expr_text} + ({term.strip()})"
    if term.strip().startswith("-"):
        return f"{expr_text} - {term.strip()[1:].lstrip()}"
    return f"{expr_text} + {term.strip()}"


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
    import tomlkit

    std = std or {}
    src = model.source
    origin = comment_text(origin, "#")    # a log's name: one line, no TOML can follow
    try:
        doc = tomlkit.parse(text)
    except tomlkit.exceptions.ParseError as exc:
        raise ModelFileError(f"invalid TOML ({exc})", src) from None
    # 1. equations and outputs
    for e in effects:
        for state in e.states:
            dyn = doc.get("dynamics", {})
            if not isinstance(dyn.get(state), str):
                raise ModelFileError("equation not found in [dynamics]", src,
                                     f"dynamics.{state}")
            _set_value(dyn, state, _append_term(str(dyn[state]), e.text(state)))
        for out in e.outputs:
            entry = doc.get("outputs", {}).get(out)
            if not hasattr(entry, "get") or not isinstance(entry.get("expr"), str):
                raise ModelFileError("output not found as a table with expr in [outputs]",
                                     src, f"outputs.{out}")
            _set_value(entry, "expr", _append_term(str(entry["expr"]), e.text(out)))
    # 2. calibrated values of existing parameters (the value, never text on its line)
    params_table = doc.get("parameters")
    for name, value in (calibrated or {}).items():
        entry = params_table.get(name) if params_table is not None else None
        if entry is None:
            raise ModelFileError("parameter not found", src, f"parameters.{name}")
        if hasattr(entry, "get") and "value" in entry:
            _set_value(entry, "value", float(_fmt(value)))
        elif isinstance(entry, (int, float)) and not isinstance(entry, bool):
            _set_value(params_table, name, float(_fmt(value)))
        else:
            raise ModelFileError("cannot edit this parameter's value", src,
                                 f"parameters.{name}")
    # 3. new parameters, after the last entry of [parameters]
    for e in effects:
        for p in e.parameters:
            v = min(max(float(params[p.name]), p.bounds[0]), p.bounds[1])
            s = std.get(p.name)
            desc = p.description + (f" (fdigen discover: {_fmt(v)} +- {float(s):.2g}"
                                    f"{' from ' + origin if origin else ''})"
                                    if s is not None and math.isfinite(s) else "")
            entry = tomlkit.inline_table()
            entry.update({"value": float(_fmt(v)), "unit": p.unit, "description": desc,
                          "bounds": [float(_fmt(p.bounds[0])), float(_fmt(p.bounds[1]))]})
            params_table.append(p.name, entry)
    # 4. sub-steps of the parallel model
    if substeps is not None:
        if "fdi" not in doc:
            raise ModelFileError("no [fdi] table to set substeps in", src, "fdi")
        if "substeps" in doc["fdi"]:
            _set_value(doc["fdi"], "substeps", int(substeps))
        else:
            doc["fdi"]["substeps"] = int(substeps)
    found = (", ".join(e.name for e in effects) + " added" if effects
             else "no effect found, none added")
    head = [f"# Augmented by `fdigen discover`{' from ' + origin if origin else ''}: "
            + found
            + ("; uncertain parameters calibrated (" + ", ".join(calibrated) + ")"
               if calibrated else "") + "."]
    return "\n".join(head + [tomlkit.dumps(doc)])


def _set_value(table, key: str, value) -> None:
    """``table[key] = value`` as a TOML document edit: the line's indentation and
    comment are kept (tomlkit), nothing else on the line is touched."""
    import tomlkit

    old = table[key]
    item = tomlkit.item(value)
    if hasattr(old, "trivia"):
        t, n = old.trivia, item.trivia
        n.indent, n.comment_ws, n.comment, n.trail = t.indent, t.comment_ws, t.comment, t.trail
    table[key] = item


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
    from fdigen.safe_lambdify import safe_lambdify

    syms = sorted(expr.free_symbols, key=sp.default_sort_key)
    fn = safe_lambdify(syms, expr, "numpy")
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


def undetermined(model: Model, calibrated: dict, std: dict) -> dict:
    """Calibrated values the log does not determine well enough to write: ``name ->
    reason``. One whose interval reaches zero (``|value| <= std``) or whose sign is the
    opposite of its datasheet value is another plant, not a calibration of this one: a
    user's greenhouse was commissioned with a ventilation capacity of -1.85 +- 3.4 m^3/s
    (datasheet 3, truth 3)."""
    sheet = {q.name: float(q.value) for q in model.parameters}
    out = {}
    for k, v in calibrated.items():
        v0, sd = sheet.get(k), std.get(k)
        if v0 and v * v0 < 0:
            out[k] = (f"{k} calibrated to {v:.4g}, the opposite sign of its datasheet value "
                      f"{v0:.4g}")
        elif sd is not None and np.isfinite(sd) and v0 and abs(v) <= sd:
            out[k] = f"{k} calibrated to {v:.4g} +- {sd:.2g}, an interval that reaches 0"
    return out


def write_augmented(model_path, out_dir, model: Model, effects, params: dict, std: dict,
                    data=None, *, calibrated: dict | None = None, origin: str = "",
                    file_name: str | None = None,
                    notes: list | None = None) -> tuple[Path, Model]:
    """Write the augmented model file into ``out_dir`` and check it parses back.

    Calibrated values the log does not determine (:func:`undetermined`) keep their
    datasheet value in the file; each is said in ``notes``.

    Returns
    -------
    (Path, Model)
        The file and its parsed model.
    """
    if calibrated:
        kept = undetermined(model, calibrated, std)
        for reason in kept.values():
            if notes is not None:
                notes.append(reason + ": the log does not determine it, so the written "
                             "model keeps the datasheet value")
        calibrated = {k: v for k, v in calibrated.items() if k not in kept}
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
    write_model_text(path, aug)   # atomic, parsed back; a symlinked file: its target
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

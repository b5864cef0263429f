"""``discover()``: from a measured log to the missing effect, the augmented model and code.

calibrate (first part of the log) -> locate (which equation) -> explain (which effect,
checked on the held-back part) -> add (augmented model file, rebuilt) -> report (errors
before and after, FDI residuals, figure). See ``docs/discover.md``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import sympy as sp

from fdigen.discover.calibrate import calibrate, uncertain_parameters
from fdigen.discover.diagnostics import diagnose_fit
from fdigen.discover.fit_report import (MIN_REINIT_SAMPLES, free_run_judge,
                                        free_run_verdict, honest_error, too_short,
                                        validate_equation_loop)
from fdigen.discover.settings import DiscoverSettings, DiscoveryResult  # noqa: F401
from fdigen.errors import FdigenError
from fdigen.discover.explain import explain
from fdigen.discover.locate import locate, prepare


def _clean(v):
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, (np.floating, float)):
        return float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def _output_loop(model_path, mdl, lg, val_log, s, out_dir, reason, build, say,
                 plot=True):
    import json

    from fdigen.discover.output_loop import run_output_loop
    from fdigen.files.atomic import write_text

    out_dir.mkdir(parents=True, exist_ok=True)
    info = run_output_loop(model_path, mdl, lg, val=val_log, settings=s, out_dir=out_dir,
                           reason=reason, build=build, say=say, plot=plot)
    info["out"] = str(out_dir)
    _say_unconfirmed(info, mdl)
    info = _clean(info)
    write_text(out_dir / "discover.json", json.dumps(info, indent=1) + "\n")
    return DiscoveryResult(info, None, None)


def _say_unconfirmed(info: dict, mdl) -> None:
    """A warning, and the headline, when the effects are not confirmed
    (:func:`fdigen.discover.fit_report.unconfirmed_effects`), on either path: a user's pump
    rig's effects cut the equation error and doubled the current's free-run error, and
    nothing said so; a user's axis read "effect found: coulomb_friction" above the
    warning that it was not confirmed, and the output-error loop said neither."""
    from fdigen.discover.fit_report import unconfirmed_effects

    worse = unconfirmed_effects(info, mdl)
    if not worse:
        return
    info["warnings"].append("the effects are NOT confirmed: " + "; ".join(worse)
                            + ": they explain the equations' error, not the outputs; "
                            "`fdigen commission` does not commit them")
    for head in ("effect found:", "effects:"):
        if info["message"].startswith(head):
            info["message"] = head[:-1] + ", NOT confirmed:" + info["message"][len(head):]
            break


def static_parameter_outputs(model) -> list[str]:
    """Why the output-error loop calibrates ``model``: each output that reads no state
    (a static relation) and depends on an uncertain parameter, or depends on an uncertain
    parameter no state equation holds; the equation test, built from the state equations,
    uses neither."""
    states = {s.symbol for s in model.states}
    uncertain = {sp.Symbol(q.name, real=True) for q in model.parameters if q.uncertain}
    in_dynamics = set().union(*(e.free_symbols for e in model.f())) if model.states else set()
    out = []
    for o, expr in zip(model.outputs, model.h()):
        if not expr.free_symbols & states and expr.free_symbols & uncertain:
            names = sorted(str(p) for p in expr.free_symbols & uncertain)
            out.append(f"output {o.name} reads no state and depends on the uncertain "
                       f"{', '.join(names)}: the equation test would not use it")
        elif (expr.free_symbols & uncertain) - in_dynamics:
            # a parameter only a sensor's map holds (a thrust stand's load cell,
            # kT w^2: the equation test held kT at its datasheet value, 7 % off)
            names = sorted(str(p) for p in (expr.free_symbols & uncertain) - in_dynamics)
            out.append(f"output {o.name} depends on the uncertain {', '.join(names)}, which "
                       "no state equation holds: the equation test would not calibrate "
                       + ("it" if len(names) == 1 else "them"))
    return out


def _noted(res: DiscoveryResult, notes: list) -> DiscoveryResult:
    """``res`` with what is said of the logs themselves (missing samples, a state never
    reversed) first among its warnings."""
    res.info["warnings"] = list(notes) + list(res.info.get("warnings", []))
    return res


def output_names(model_name: str) -> tuple[str, ...]:
    """The files discover writes into its output folder (its generated code goes to the
    folder ``<model>_discovered/``, which the build's own rule protects)."""
    return ("discover.json", "discover.png", f"{model_name}_discovered.toml",
            f"{model_name}_calibrated.toml")


def discover(log, model=None, *, out=None, settings: DiscoverSettings | None = None,
             build: bool = True, fdi: bool = True, backend: str = "c", plot: bool = True,
             progress=None, validate=None, force: bool = False) -> DiscoveryResult:
    """Find the effect a measured log shows and the model lacks; add it; report.

    Parameters
    ----------
    log : str or Path
        Measured log (rig CSV format).
    model : str or Path, optional
        Model file or built-in model name [pneumatic_cylinder].
    out : str or Path, optional
        Output folder for the augmented model file, its generated code, the figure and
        ``discover.json``; default a new temporary folder. Never the repository's
        ``generated/``.
    settings : DiscoverSettings, optional
    build : bool
        Rebuild the generated code (Python/CasADi and C) from the augmented model.
    fdi : bool
        Run the FDI cores of the original and augmented designs over the log.
    backend : str
        FDI backend for that run (``"c"``, ``"casadi"``, ``"reference"``, ``"auto"``).
    plot : bool
        Write ``discover.png``.
    progress : callable, optional
        Receives progress messages.
    validate : str or Path, optional
        A second log: the free-run error of the model before and after on it is reported
        (``validation: {log, error_before, error_after}``).
    force : bool
        Overwrite files in ``out`` under the names discover writes that fdigen did not
        write (refused otherwise, before any work).

    Returns
    -------
    DiscoveryResult
        ``as_dict()`` holds at least ``equation``, ``effect``, ``parameters``,
        ``error_before``, ``error_after`` (output-error RMS per measured signal) and
        ``validation`` (``[t_start, t_end]``).
    """
    from fdigen.discover.report import fdi_residual_rms, output_error
    from fdigen.discover.report import plot as draw
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.sim.log import read_log

    s = settings or DiscoverSettings()
    say = progress or (lambda msg: None)
    model_path = resolve_model_path(model)
    mdl = load_model(model_path)
    nominal = mdl.fdi.get("sample_time")
    lg = read_log(log, mdl, missing="fill", nominal_sample_time=nominal)   # short gaps filled
    from fdigen.discover.windows import discover_windows

    val_log = (read_log(validate, mdl, missing="fill", nominal_sample_time=nominal)
               if validate is not None else None)
    from fdigen.discover.coverage import coverage_warning

    gaps = [n + (": interpolated for the fit (gaps of at most a few samples)"
                 if "missing samples" in n else "")
            for n in (lg.missing_note(), val_log and val_log.missing_note()) if n]
    gaps += [w for w in [coverage_warning(mdl, lg.y, float(lg.sample_time))] if w]
    if out is not None:
        from fdigen.files.outputs import check_own_outputs

        check_own_outputs([Path(out) / n for n in output_names(mdl.name)], "--out", force)
    out_dir = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="fdigen-discover-"))
    window, smooth = discover_windows(mdl, lg.t, s.window, s.smooth)
    if s.method == "output-error":
        return _noted(_output_loop(model_path, mdl, lg, val_log, s, out_dir,
                                   "--method output-error", build, say, plot), gaps)
    if s.method != "auto":
        raise FdigenError(f"unknown discover method {s.method!r} (auto, output-error)")
    static = static_parameter_outputs(mdl)
    if static:
        # the equation test reads the state equations only: a sensor of a static relation
        # (a heater's power meter, Pel = Pmax u/100) would be ignored by the calibration
        # (a user's Pmax came out 2.4 sigma low with the meter on the log)
        return _noted(_output_loop(model_path, mdl, lg, val_log, s, out_dir,
                                   "; ".join(static), build, say, plot), gaps)
    try:
        data = prepare(mdl, lg.t, lg.u, lg.y, window=window, smooth=smooth)
        cal, val, t_split = data.split(s.fraction)
    except FdigenError as exc:
        from fdigen.discover.output_loop import hidden_states

        hidden = hidden_states(mdl)
        if hidden:
            exc = FdigenError(f"state {hidden[0]} is neither measured nor the derivative "
                              "of a measured state: the equation error cannot be formed")
        elif "neither measured" not in str(exc):  # too short for even one window
            need = 30 * window / min(s.fraction, 1 - s.fraction) * 0.5 + window
            raise FdigenError(f"{log}: {exc}: the equation test needs a log of at least "
                              f"about {need:.4g} s (or a shorter --window)") from None
        # a hidden state: the equation error cannot be formed
        return _noted(_output_loop(model_path, mdl, lg, val_log, s, out_dir, str(exc),
                                   build, say, plot), gaps)
    resplit = None
    if cal.sum() < 20 or val.sum() < 10:
        from fdigen.discover.locate import split_valid

        cal2, val2, t2 = split_valid(data, s.fraction)
        if cal2.sum() >= 20 and val2.sum() >= 10:
            resplit = (f"the log after {t_split:g} s holds only {int(val.sum())} usable "
                       f"windows (states at their limits or a sensor out of range): the "
                       f"calibration/validation split is moved to {t2:g} s, "
                       f"{s.fraction:g} of the usable windows")
            say(resplit)
            cal, val, t_split = cal2, val2, t2
    reason = too_short(data, cal, val, s, window, lg.t)
    if reason is not None:
        raise FdigenError(f"{log}: {reason}")
    say(f"calibrating {', '.join(uncertain_parameters(data)[0]) or 'nothing'} on "
        f"{lg.t[0]:g}-{t_split:g} s")
    base = calibrate(data, cal)
    loc_opts = {"alpha": s.alpha, "min_structure": s.min_structure}
    tests = locate(data, base.E, cal, **loc_opts)
    for t in tests:
        say(f"  {t.equation}: structure {t.structure:.3f}, p {t.p:.2g}"
            + (" (located)" if t.located else ""))
    samples_val = lg.t >= t_split
    ex = explain(data, base, tests, cal, val, alpha=s.alpha,
                 alpha_validation=s.alpha_validation, consistency=s.consistency,
                 bic_margin=s.bic_margin,
                 min_gain=s.min_gain, max_effects=s.max_effects, locate_options=loc_opts,
                 free_run=free_run_judge(mdl, data, lg, samples_val), log=say)
    say(ex.message)
    final = ex.fit
    unc = [q.name for q in mdl.parameters if q.uncertain]
    eff_params = [p for e in ex.effects for p in e.parameter_names]

    located = [t for t in tests if t.located]
    equation = max(located, key=lambda t: t.Q).equation if located else None
    if ex.effects:
        fp = set().union(*(e.footprint(mdl) for e in ex.effects)) & set(data.equations)
        eqs = [q for q in data.equations if q in fp]
        # the equation the chosen effect acts in (its own term first)
        own = [q for q in data.equations if q in ex.effects[0].states]
        equation = (own or eqs or [equation])[0]

    # never a one-step prediction presented as the error: at least MIN_REINIT samples
    reinit = max(1.0 if s.reinit is None else float(s.reinit), MIN_REINIT_SAMPLES * data.dt)
    err_before = output_error(data, (), base.params, samples_val, reinit=reinit)
    err_after = output_error(data, ex.effects, final.params, samples_val, reinit=reinit)
    err_nominal = output_error(data, (), {q.name: q.value for q in mdl.parameters},
                               samples_val, reinit=reinit)
    honesty = honest_error(mdl, lg, err_after["rms"], reinit if s.reinit is None
                           else s.reinit, reinit, data.dt,
                           hint="; the equation error's calibration differentiates the "
                                f"measurements: `fdigen {s.command} --method output-error` "
                                "calibrates on the free-run error itself")
    free = free_run_verdict(mdl, data, samples_val, ex.effects, final.params, honesty,
                            reinit)

    info = {
        "log": str(log),
        "model": str(model_path),
        "equation": equation,
        "equations": [t.equation for t in located],
        "effect": ex.effects[0].name if ex.effects else None,
        "effects": [e.name for e in ex.effects],
        # the sensors each effect reads through, when it acts on no state's equation
        "sensor_effects": {e.name: sorted(e.outputs) for e in ex.effects
                           if e.outputs and not e.states},
        "parameters": {k: final.params[k] for k in eff_params + unc},
        "uncertainty": {k: final.std.get(k, float("nan")) for k in eff_params + unc},
        "conditional_uncertainty": {k: final.conditional_std.get(k, float("nan"))
                                    for k in eff_params + unc},
        "calibrated": {k: base.params[k] for k in unc},
        "calibrated_std": {k: base.std.get(k, float("nan")) for k in unc},
        "calibrated_conditional_std": {k: base.conditional_std.get(k, float("nan"))
                                       for k in unc},
        "error_nominal": err_nominal["rms"],
        "error_before": err_before["rms"],
        "error_after": err_after["rms"],
        "reinit": reinit,
        "calibration": [float(lg.t[0]), float(t_split)],
        "validation": [float(t_split), float(lg.t[-1])], "log_end": float(lg.t[-1]),
        "tests_before": [t.as_dict() for t in tests],
        "tests_after": [t.as_dict() for t in ex.tests],
        "tests_validation_before": [t.as_dict() for t in locate(data, base.E, val, **loc_opts)],
        "tests_validation_after": [t.as_dict() for t in locate(data, final.E, val,
                                                               **loc_opts)],
        "equation_error_before": {q: float(np.sqrt(np.mean(base.E[val, i] ** 2)))
                                  for i, q in enumerate(data.equations)},
        "equation_error_after": {q: float(np.sqrt(np.mean(final.E[val, i] ** 2)))
                                 for i, q in enumerate(data.equations)},
        "candidates": [c.as_dict() for c in ex.candidates],
        # the equation test's verdict and the free-run error's, never contradicting: a
        # log without structure is "explained" only when its output error says so too
        "message": ex.message + (honesty["message"] or (
            ": the calibrated model explains the log"
            if ex.message.startswith("no unexplained structure") else "")),
        "warnings": ([resplit] if resplit else []) + honesty["warnings"],
        "noise": honesty["noise"], "noise_ratio_after": honesty["ratio"],
        "noise_ratio_free_run": free,
        "explains": honesty["explains"],
        "settings": dict(s.__dict__),
        "output_error_substeps": {"nominal": err_nominal["substeps"],
                                  "before": err_before["substeps"],
                                  "after": err_after["substeps"]},
    }
    diagnose_fit(info, data, lg, ex, final, base, cal, s, say)
    from fdigen.discover.noise import rail_warnings

    info["warnings"].extend(rail_warnings(mdl, lg.y))
    from fdigen.discover.effects_physics import assumed_ambient_notes

    info["warnings"].extend(assumed_ambient_notes(ex.effects))
    stiff = max((e for e in (err_nominal, err_before, err_after)),
                key=lambda e: e["substeps"])
    if stiff["substeps"] > 4:
        info["warnings"].append(
            f"the model is stiff (largest |eigenvalue| of df/dx over the log "
            f"{stiff['stiffness']:.3g} 1/s, {stiff['stiffness'] * data.dt:.3g} per sample): "
            f"the output-error simulation uses {stiff['substeps']} RK4 sub-steps per sample"
            + (" (capped: the errors may be those of an unstable simulation)"
               if stiff["substeps"] >= 400 else ""))

    out_dir.mkdir(parents=True, exist_ok=True)
    info["out"] = str(out_dir)
    aug_model = None
    if ex.effects:
        from fdigen.discover.augment import rebuild, write_augmented

        path, aug_model = write_augmented(
            model_path, out_dir, mdl, ex.effects, final.params, final.std, data,
            calibrated={k: final.params[k] for k in unc}, origin=Path(log).name,
            notes=info["warnings"])
        info["model_file"] = str(path)
        say(f"wrote {path}")
        if build or fdi:
            from fdigen.discover.design_check import ensure_design

            aug_model, _, notes = ensure_design(path, aug_model, say, (lg.u, lg.y))
            info["warnings"].extend(notes)
        if build:
            res = rebuild(path, out_dir)
            info["build"] = str(res.folder)
            say(f"built {res.folder}")

    fdi_b = fdi_a = None
    if fdi:
        from fdigen.design.cache import cached_design

        from fdigen.discover.design_check import design_on_the_log

        d0 = design_on_the_log(mdl, lg.u, lg.y, say, info["warnings"])
        info["fdi_before"], fdi_b, info["fdi_flags_before"] = fdi_residual_rms(
            d0, lg.u, lg.y, samples_val, backend)
        if aug_model is not None:
            say("deriving the augmented FDI design")
            d1 = cached_design(aug_model)
            info["fdi_after"], fdi_a, info["fdi_flags_after"] = fdi_residual_rms(
                d1, lg.u, lg.y, samples_val, backend)
        else:
            info["fdi_after"], fdi_a = dict(info["fdi_before"]), fdi_b
            info["fdi_flags_after"] = list(info["fdi_flags_before"])
        info["fdi_residuals"] = list(d0.residual_names)
        if aug_model is not None and list(d1.residual_names) != list(d0.residual_names):
            # the augmented design may derive other residuals (an output offset changes
            # the derived ones): align its columns on the original's for the figure
            cols = {n: i for i, n in enumerate(d1.residual_names)}
            fdi_a = np.column_stack([fdi_a[:, cols[n]] if n in cols
                                     else np.full(len(fdi_a), np.nan)
                                     for n in d0.residual_names])
            info["fdi_residuals_after"] = list(d1.residual_names)
        worse = [k for k in info["fdi_before"] if k in info["fdi_after"]
                 and info["fdi_after"][k] > 1.2 * info["fdi_before"][k]]
        if worse and aug_model is not None:
            info["warnings"].append(
                "the augmented design's residual(s) " + ", ".join(worse) + " grew on the "
                "validation part (the augmented design's Kalman filters predict through "
                "the nonlinear model, the parity residuals too: a residual that grows "
                "points at an effect or parameter the augmented model still lacks, or at "
                "thresholds tuned for the original plant)")
    if plot:
        title = f"{Path(log).name}: " + (", ".join(info["effects"]) or "no effect")
        p = draw(out_dir / "discover.png", data, base.E, final.E, t_split,
                 fdi_before=fdi_b, fdi_after=fdi_a,
                 residual_names=info.get("fdi_residuals", ()), title=title)
        info["plot"] = str(p)
    if val_log is not None:
        info["validation"] = validate_equation_loop(mdl, val_log, ex, base, final, s)
    _say_unconfirmed(info, mdl)
    info = _clean(info)
    import json

    from fdigen.files.atomic import write_text

    write_text(out_dir / "discover.json", json.dumps(info, indent=1) + "\n")
    return _noted(DiscoveryResult(info, ex, data), gaps)

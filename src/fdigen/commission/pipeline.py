"""``commission()``: one healthy log in, a commissioned model file and its built FDI out.

discover (calibrate, effects) -> commissioned model file (augmented or calibrated, effect
parameters uncertain) -> threshold campaign on that plant (:func:`fdigen.tune.tune`,
healthy runs only) -> check against the measured healthy log
(:mod:`~fdigen.commission.healthy_check`) -> validation and fault campaigns with the final
thresholds (:mod:`~fdigen.commission.faults`) -> build -> report. See
``docs/commission.md``.
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from pathlib import Path

from fdigen.commission.spread import (MAX_TOLERANCE, campaign_tolerance,  # noqa: F401
                                     campaign_tolerances, conditional_or_marginal,
                                     declared_floors, floor_bound, round_up, spread_text,
                                     spreads_without_interval, wide_intervals)
from fdigen.commission.healthy_check import (early_start_warning, hidden_starts_away,
                                             short_log_warning, startup_note,
                                             stateless_residuals)
from fdigen.commission.model_text import (_horizon_table,  # noqa: F401 (re-exported)
                                          commissioned_text, mark_refusal,
                                          with_values)
from fdigen.commission.settings import (DEFAULT_RUN, CommissionSettings,  # noqa: F401
                                       campaign_duration)
from fdigen.commission.verdict import campaign_delays
from fdigen.tune.fault_sensitivity import measured_sensitivity


def _say(log):
    return log or (lambda msg: None)


def commission(log, model=None, *, out=None, settings: CommissionSettings | None = None,
               workers: int = 2, scheduler: str | None = None, build: bool = True,
               progress=None, force: bool = False, validate=()) -> dict:
    """Commission FDI on a rig from one healthy log (see the module docstring).

    Parameters
    ----------
    log : str or Path
        The healthy log recorded on the rig.
    model : str or Path, optional
        Model file or built-in name [pneumatic_cylinder].
    out : str or Path, optional
        Output folder [a new temporary folder]: ``discover/`` (discover's output),
        ``<model>_commissioned.toml``, ``<model>/`` (generated code), ``commission.json``.
    settings : CommissionSettings, optional
    workers, scheduler
        Dask workers of the campaigns (``scheduler="synchronous"``: in-process).
    build : bool
        Build the commissioned model's code.
    progress : callable, optional
        Receives progress messages.
    force : bool
        Overwrite files in ``out`` under the names commission writes that fdigen did not
        write (refused otherwise, before any work).
    validate : sequence of str or Path
        Other healthy logs of the rig: the first confirms discover's effects (its
        ``--validate``), and the final design must raise no flag on any of them
        (:mod:`fdigen.commission.validation_logs`); they never set a threshold.

    Returns
    -------
    dict
        JSON-able: ``model_file``, ``effects``, ``parameters``, ``uncertainty``,
        ``thresholds`` (final), ``thresholds_before`` (the model file's),
        ``thresholds_campaign``, ``raised``, ``delays`` (per fault), ``false_alarm``,
        ``healthy_check``, ``warnings``, ``build``, ``timing``.
    """
    from fdigen.files.outputs import check_output_folder
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    s = settings or CommissionSettings()
    say = _say(progress)
    clock = {}
    t_all = time.perf_counter()

    if out is not None:               # before minutes of work, not after them
        check_output_folder(out, "--out")
    model_path = resolve_model_path(model)
    original = load_model(model_path)
    if out is not None:
        from fdigen.discover.pipeline import output_names
        from fdigen.files.outputs import check_own_outputs

        check_own_outputs([Path(out) / n for n in ("commission.json",
                                                   f"{original.name}_commissioned.toml")]
                          + [Path(out) / "discover" / n for n in output_names(original.name)],
                          "--out", force)
        # the build folder too: a user's folder named like the model was refused after
        # 37 s of discovery and campaigns, with their files already written
        from fdigen.pipeline import check_build_target

        check_build_target(Path(out), original.name)
    from fdigen.commission.validation_logs import refuse_unusable_logs

    validate = [Path(v) for v in validate]
    refuse_unusable_logs(original, validate, log)     # before minutes of work, and a folder
    out_dir = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="fdigen-comm-"))
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    try:
        return _commission(log, original, model_path, out_dir, s, validate, say, clock,
                           t_all, workers, scheduler, build, force)
    except BaseException:
        if created and out_dir.is_dir() and not any(out_dir.iterdir()):
            out_dir.rmdir()          # a refused log leaves the file system as it was
        raise


def _commission(log, original, model_path, out_dir, s, validate, say, clock, t_all,
                workers, scheduler, build, force) -> dict:
    """:func:`commission` once its inputs are checked and ``out_dir`` exists."""
    from fdigen.commission.faults import fault_campaign
    from fdigen.commission.healthy_check import check_thresholds
    from fdigen.design.cache import cached_design
    from fdigen.commission.ambiguity import measured_ambiguity_time
    from fdigen.commission.class_choice import choose_class_decision
    from fdigen.commission.withhold import bound_decided, not_committed
    from fdigen.discover.design_check import PLACEHOLDER_NOTE, ensure_design
    from fdigen.discover.pipeline import DiscoverSettings, discover
    from fdigen.model.model_file import load_model
    from fdigen.sim.log import read_log
    from fdigen.tune import TuneSettings, tune
    from fdigen.files.atomic import write_text
    from fdigen.files.model_write import write_model_text

    if s.duration is None:
        s = dataclasses.replace(s, duration=campaign_duration(original))
    warnings: list[str] = []

    # 1. discover: calibration and effects
    say("1/5 discover: calibration and effects")
    t0 = time.perf_counter()
    res = discover(log, model_path, out=out_dir / "discover",
                   settings=DiscoverSettings(fraction=s.fraction, method=s.method,
                                             command="commission"),
                   build=False, fdi=False, plot=True, progress=say, force=force,
                   validate=validate[0] if validate else None)
    info = res.as_dict()
    warnings.extend(info.get("warnings", []))
    clock["discover"] = time.perf_counter() - t0
    effects = list(info["effects"])
    params = dict(info["parameters"])
    std = dict(info["uncertainty"])
    # what each parameter alone may move on the log (correlated ones, known only in
    # combination, are not spread apart): the campaign's spread reads these
    alone = dict(info.get("conditional_uncertainty") or {})
    # (the equation path's ties; the output-error loop's say what they are in its warnings)
    tied, faulty, notes = not_committed(info, res.explanation is not None, original)
    warnings.extend(notes)
    if tied or faulty:
        effects = []
        params = dict(info["calibrated"])
        std = dict(info["calibrated_std"])
        alone = dict(info.get("calibrated_conditional_std") or {})
        info = {**info, "effects": [], "model_file": None, "calibrated_model_file": None}
    if info.get("model_file"):
        base_text = Path(info["model_file"]).read_text()
    elif info.get("calibrated_model_file"):  # the output-error loop found no effect
        base_text = Path(info["calibrated_model_file"]).read_text()
    else:
        from fdigen.discover.augment import write_augmented

        unc = [q.name for q in original.parameters if q.uncertain]
        withholding = bool(tied or faulty)
        if res.explanation is not None:
            fit_params, fit_std = res.explanation.fit.params, res.explanation.fit.std
        else:                            # the output-error loop: its calibrated values
            fit_params = {**{q.name: q.value for q in original.parameters}, **params}
            fit_std = std
        calibrated = ({k: params[k] for k in unc if k in params} if withholding
                      else {k: fit_params[k] for k in unc})
        p, _ = write_augmented(model_path, out_dir / "discover", original, [], fit_params,
                               std if withholding else fit_std, res.data,
                               calibrated=calibrated,
                               origin=Path(log).name,
                               file_name=f"{original.name}_calibrated.toml",
                               notes=warnings)
        base_text = p.read_text()
    decided = bound_decided(info, original)
    if decided:
        # the bound, not the log, decided them: the datasheet value is committed
        base_text = with_values(base_text, {k: v[1] for k, v in decided.items()})
        warnings.append(
            "not committed: " + ", ".join(f"{k} = {v[0]:.4g} (at its search bound)"
                                          for k, v in decided.items())
            + ": the bound, not the log, decided "
            + ("it" if len(decided) == 1 else "them") + "; the commissioned model keeps "
            + ", ".join(f"{k} = {v[1]:.4g}" for k, v in decided.items())
            + " from the datasheet, spread by the declared tolerance (a longer log, or one "
            "that moves the plant through more of its range, determines it)")
    path = out_dir / f"{original.name}_commissioned.toml"
    # refused until the verdict (mark_refusal) replaces the mark: a run stopped on the way
    # leaves a file every command says is unfinished
    from fdigen.design.refusal_marks import COMMISSION_UNFINISHED
    from fdigen.tune.model_update import updated_model_text

    write_model_text(path, updated_model_text(base_text, {},
                                              fdi_values={"refused": COMMISSION_UNFINISHED}))
    cmodel = load_model(path)
    datasheet = {q.name: q.value for q in original.parameters}
    # the values the written model keeps from the datasheet (the log did not determine
    # them, or their search bound did) are what the campaign spreads and the summary
    # prints (a user's stand printed b0 = 0.0017 fitted, the file held 0.005)
    kept = set(decided) | {
        q.name for q in cmodel.parameters if q.name in params and
        q.value == datasheet.get(q.name) and
        abs(params[q.name] - q.value) > 1e-9 * max(abs(q.value), 1e-300)}
    for name in kept:
        params[name], std[name] = datasheet[name], None
    # a model never tuned: its missing thresholds read from the log for now (the campaign
    # below designs them)
    lg = read_log(log, cmodel, missing="fill",      # (the commissioned model's columns)
                  nominal_sample_time=cmodel.fdi.get("sample_time"))
    cmodel, _, notes = ensure_design(path, cmodel, say, data=(lg.u, lg.y))
    warnings.extend(n for n in notes if not n.startswith(PLACEHOLDER_NOTE))
    short = short_log_warning(float(lg.t[-1] - lg.t[0]) + float(lg.sample_time),
                              float(s.duration))
    if short:
        warnings.append(short)

    # 2. threshold campaign on the commissioned plant
    effect_params = [k for k in params if k not in
                     {q.name for q in original.parameters}]
    floors = declared_floors(original, s.min_tolerance)
    spread_std = conditional_or_marginal(std, alone)
    tol = campaign_tolerance(params, spread_std, s.sigmas, s.min_tolerance, floors)
    per = campaign_tolerances(params, spread_std, s.sigmas, s.min_tolerance, floors)
    # a value without an interval of the log's (its bound decided it, the log does not
    # determine it, or it is held on a direction the log cannot see) is spread by its
    # declared tolerance, else tune's: the largest interval of the others put a building
    # zone's slab capacity and conductances +-80.9 % apart, each on its own, and the room
    # threshold above the sensor's span
    without = spreads_without_interval(original, params, per)
    per.update({k: v for k, (v, _) in without.items()})
    without = {k: why for k, (_, why) in without.items()}
    warnings.extend(wide_intervals(params, std, s.sigmas))
    design0 = cached_design(cmodel)
    keep = tuple(design0.config.voter.names) if design0.config.voter else ()
    tset = TuneSettings(runs=s.runs, duration=s.duration, false_alarm_rate=s.false_alarm_rate,
                        margin=s.margin, tolerance=tol, tolerances=tuple(sorted(per.items())),
                        validation_runs=0, faults=(),
                        seed=s.seed, keep=keep, horizon_runs=min(s.horizon_runs, s.runs),
                        fault_factors=tuple(s.fault_factors), fault_starts=s.fault_starts)
    # the effect parameters are spread too: mark them uncertain before the campaign
    uncertain = [q.name for q in cmodel.parameters if q.uncertain] + effect_params
    write_model_text(path, commissioned_text(path.read_text(), effect_params, {}, {},
                                             Path(log).name, "model calibrated and "
                                             "augmented; thresholds below",
                                             tolerances={k: per.get(k, tol)
                                                         for k in uncertain}))
    cmodel = load_model(path)
    bare = sorted(set(uncertain) - set(per))
    say(f"2/5 threshold campaign: {s.runs} healthy runs of {s.duration:g} s, parameters "
        "spread " + spread_text(per, floors, s.min_tolerance, without)
        + f" (each by its {s.sigmas:g}-sigma calibration interval with the others at their "
          "values, at least the floor)"
        + (f"; {', '.join(bare)} +-{100 * tol:.3g} % (no interval of its own)"
           if bare else ""))
    t0 = time.perf_counter()
    rep = tune(path, tset, workers=workers, scheduler=scheduler, progress=False,
               log=lambda m: say("  " + m))
    clock["threshold_campaign"] = time.perf_counter() - t0
    from fdigen.tune.run_notes import early_peak_text, growing_text

    warnings.extend("the campaign: " + early_peak_text(n, e)
                    for n, e in rep["false_alarm"].get("early_peaks", {}).items())
    if rep["false_alarm"].get("growing"):
        warnings.append("the campaign: " + growing_text(rep["false_alarm"]["growing"],
                                                        rep["false_alarm"]["run_duration"]))
    startup = (rep.get("startup") or {}).get("seconds")
    if startup:          # the campaign's runs start their hidden states across an interval
        say("  " + rep["startup"]["text"])
    campaign = dict(rep["thresholds"])
    if rep.get("left_domain"):
        from fdigen.tune.pipeline import left_domain_text

        warnings.append(left_domain_text(rep["left_domain"]))

    # 3. check against the measured healthy log
    say(f"3/5 check against the measured log (each threshold >= {s.data_margin:g} x its "
        "max RMS)")
    t0 = time.perf_counter()
    # (the equation path's held-back part, named "validation" until a --validate log's
    # result takes that key; the output-error loop's split)
    t_split = float(info["validation"][0] if isinstance(info.get("validation"), list)
                    else info.get("validation_split", info["calibration"][1]))
    check = check_thresholds(dataclasses.replace(cmodel, fdi={**cmodel.fdi, "startup": startup})
                             if startup else cmodel, campaign, lg.t, lg.u, lg.y, t_split,
                             s.data_margin)
    startup = check["startup"] or startup
    final = check["thresholds"]
    for name, r in check["raised"].items():
        msg = (f"threshold {name} raised from {r['from']:.3g} to {r['to']:.3g}: "
               f"{s.data_margin:g} x the measured healthy log's max RMS {r['log_max']:.3g}")
        say("  " + msg)
        warnings.append(msg)
    if check["startup"]:
        msg = startup_note(check)
        say("  " + msg)
        warnings.append(msg)
    away = hidden_starts_away(cmodel, info.get("initial_state") or {})
    started = [n for n, p in check["peaks"].items() if n in check["raised"] and (
        n in check["early"] or (away and p["first_third"]))]
    if started:
        warnings.append(early_start_warning(check["peaks"], started, away,
                                            stateless_residuals(cached_design(cmodel))))
    if not check["quiet"]:
        warnings.append("the final design still raises " + ", ".join(check["flags"])
                        + " on the measured healthy log")
    from fdigen.tune.thresholds import _literal

    text = commissioned_text(
        path.read_text().split("\n", 1)[1], [], final,
        {n: _literal(v) for n, v in final.items()}, Path(log).name,
        f"effects {', '.join(effects) or 'none'}; thresholds from {s.runs} simulated "
        f"healthy runs, >= {s.data_margin:g} x the log's max RMS", rep["residual_keys"],
        # measured at the campaign's thresholds: one raised by the log is crossed later
        **_horizon_table(rep, tol, s.duration),
        fdi_values={"startup": startup} if startup else None)
    write_model_text(path, text)
    cmodel = load_model(path)
    from fdigen.commission.validation_logs import check_validation_logs

    checked = check_validation_logs(cmodel, validate, say)
    clock["healthy_check"] = time.perf_counter() - t0

    # 4. validation and fault campaigns with the final thresholds
    fset = dataclasses.replace(tset, validation_runs=s.validation_runs, faults=None)
    say(f"4/5 validation and fault campaigns: {s.validation_runs} healthy runs, every "
        f"fault at {', '.join(f'{k:g}' for k in s.fault_factors)} x its test size")
    t0 = time.perf_counter()
    camp = fault_campaign(cmodel, {}, fset, workers=workers, scheduler=scheduler)
    cmodel, camp, note = choose_class_decision(
        path, cmodel, camp, lambda m: fault_campaign(m, {}, fset, workers=workers,
                                                     scheduler=scheduler), say)
    if note:
        warnings.append(note)
    cmodel, note = measured_ambiguity_time(path, cmodel, camp)
    if note:
        say("  " + note)
        warnings.append(note)

    clock["fault_campaign"] = time.perf_counter() - t0

    # 5. build
    result = {
        "log": str(log), "model": str(model_path), "model_file": str(path),
        "effects": effects, "parameters": params, "uncertainty": std,
        "effect_parameters": effect_params,
        "calibration": info["calibration"], "validation": info.get("validation"),
        "discover_message": info["message"],
        "explains": info.get("explains"),
        # the worse of the re-initialised and the free-run error (discover judged both)
        "noise_ratio": {k: max(v, (info.get("noise_ratio_free_run") or {}).get(k, v))
                        for k, v in (info.get("noise_ratio_after") or {}).items()},
        "error_before": info["error_before"], "error_after": info["error_after"],
        # the file's own (a model never tuned has none, or not all)
        "thresholds_before": {n: float(v) for n, v in
                              original.fdi.get("thresholds", {}).items()},
        "thresholds_campaign": campaign,
        "thresholds": final,
        "raised": check["raised"],
        "healthy_check": {k: check[k] for k in ("data_margin", "log_max",
                                                 "log_max_held_back", "ratio", "flags",
                                                 "flags_held_back", "quiet")},
        "validation_logs": checked,
        "false_alarm": {
            "target_per_run": s.false_alarm_rate, "run_duration": s.duration,
            "fitted_campaign_thresholds": rep["false_alarm"]["fitted"],
            "basis": rep["false_alarm"]["basis"],
            "validation_runs": camp["validation_runs"],
            "validation_false_alarms": camp["validation_false_alarms"],
            "validation_upper_95": camp["validation_upper_95"],
            "validation_flags": camp["validation_flags"],
        },
        "delays": campaign_delays(camp),
        "substeps_accuracy": camp.get("substeps_accuracy"),
        "sensitivity": measured_sensitivity(cmodel, camp["faults"]),
        "campaign": {"runs": s.runs, "duration": s.duration, "tolerance": tol,
                     "tolerances": per,
                     "seed": s.seed, "kept": list(keep),
                     "fault_factors": list(s.fault_factors),
                     "fault_starts": s.fault_starts, "fault_runs": camp["fault_runs"]},
        "warnings": warnings,
        "settings": dataclasses.asdict(s),
    }
    from fdigen.commission.verdict import design_verdict

    result["declared_faults_found"] = faulty
    result["verdict"] = design_verdict(cmodel, final, result["delays"], lg.y, tol,
                                       result["false_alarm"], faulty_log=faulty,
                                       validation_logs=checked,
                                       converged=info.get("converged", True),
                                       floor_spread=floor_bound(params, spread_std,
                                                                s.sigmas,
                                                                s.min_tolerance, floors))
    result["warnings"].extend(result["verdict"]["warnings"])
    mark_refusal(path, result["verdict"])
    for f in result["verdict"]["failures"]:
        say("  REFUSED: " + f)
    if build:
        say("5/5 build")
        t0 = time.perf_counter()
        from fdigen.discover.augment import rebuild

        result["build"] = str(rebuild(path, out_dir).folder)
        clock["build"] = time.perf_counter() - t0
    clock["total"] = time.perf_counter() - t_all
    result["timing"] = clock
    result["out"] = str(out_dir)
    write_text(out_dir / "commission.json", json.dumps(result, indent=1, default=float) + "\n")
    return result

"""``fdigen tune``: Monte Carlo design of the residual thresholds.

Holds the command; its text view of the tuning report is :mod:`fdigen.cli.tune_view`.
"""

from __future__ import annotations

import dataclasses
import json

import click

from fdigen.cli.errors import echo
from fdigen.cli.tune_view import _print_tune, realign_text
from fdigen.cli.types import COUNT, POSITIVE_SECONDS, RUNS, SCHEDULER, WORKERS


@click.command()
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--runs", default=40, show_default=True, type=RUNS, help="Healthy Monte Carlo runs.")
@click.option("--duration", default=None, type=POSITIVE_SECONDS,
              help="Seconds per run (the false-alarm rate is per run of this length) "
                   "[default: the model's [simulation] duration, else 6 RMS windows or 5 "
                   "slowest time constants, at most 20000 samples]; a run must outlast "
                   "two RMS windows.")
@click.option("--false-alarm-rate", "false_alarm_rate", default=0.01, show_default=True,
              help="Target probability that a healthy run raises any flag.")
@click.option("--margin", default=1.25, show_default=True,
              help="Safety factor on the fitted quantile.")
@click.option("--tolerance", default=0.10, show_default=True,
              help="Relative spread of the uncertain parameters (uniform, +-); a "
                   "parameter's own `tolerance` in the model file (a commissioned model's "
                   "calibrated spread) is kept.")
@click.option("--validation-runs", "validation_runs", default=10, show_default=True,
              help="Fresh healthy runs checked with the tuned core.")
@click.option("--fault-sizes", "fault_sizes", default="0.25,0.5,1,2", show_default=True,
              help="Fault sizes relative to each fault's test_size (comma separated). "
                   "Every fault runs as a step of test_size x factor; additive sensor "
                   "faults also as a drift of factor x their test_rate (sensor units per "
                   "second; default test_size over the plant's slowest time constant).")
@click.option("--fault-starts", "fault_starts", default=2, show_default=True,
              help="Onset times per fault and size.")
@click.option("--keep", default="",
              help="Residuals whose thresholds stay as in the model file (comma separated).")
@click.option("--horizon-runs", "horizon_runs", default=10, show_default=True,
              type=click.IntRange(0), help="Healthy runs on which the validity horizons of "
              "frozen residuals are measured ([fdi.frozen_horizon]; 0: not measured).")
@click.option("--horizon-fault-runs", "horizon_fault_runs", default=0, show_default=True,
              type=click.IntRange(0), help="With --horizon-runs: runs per fault (at its "
              "test size; sensor offsets also as drifts) whose flags outside the fault's "
              "signature after the first flag shorten the horizons too (0: healthy runs "
              "only).")
@click.option("--seed", default=0, show_default=True, help="Master seed.")
@click.option("--filter-search/--no-filter-search", "filter_search", default=True,
              show_default=True,
              help="When the design derives Kalman residuals and a class-isolable fault is "
                   "isolated in fewer than 90 % of its runs at its test size, run the "
                   "campaign again with their innovation low-passed over half an RMS "
                   "window ([fdi] innovation_filter) and take it (and write it with "
                   "--write) when it isolates in more runs, detects no less and adds no "
                   "wrong isolation or false alarm.")
@click.option("--class-search/--no-class-search", "class_search", default=True,
              show_default=True,
              help="When the design has structural residuals that name faults only and a "
                   "fault that would be class-isolable with them deciding classes is "
                   "isolated in fewer than 90 % of its runs at its test size, run the "
                   "campaign again with them deciding classes too "
                   "([fdi] structural_classes = true) and take it (and write it with "
                   "--write) when it isolates in more runs, detects no less and adds no "
                   "wrong isolation or false alarm.")
@click.option("--hold-search/--no-hold-search", "hold_search", default=True,
              show_default=True,
              help="When the validity horizons were measured (--horizon-runs), a frozen "
                   "residual crossed its threshold and a class-isolable fault is isolated "
                   "in fewer than 90 % of its runs at its test size, run the campaign again "
                   "with the held correction ([fdi] hold_windows = 1) and take it (and "
                   "write it with --write) when it isolates in more runs, detects no less "
                   "and adds no wrong isolation or false alarm.")
@click.option("--realign-search/--no-realign-search", "realign_search", default=True,
              show_default=True,
              help="When a fault is missed at its test size by the design's fault (not "
                   "masked by the parameter spread) and the design has parallel models, "
                   "run the campaign again with stronger realignments ([fdi] "
                   "realign_noise_scale 0.05, 0.2, 1 above the current one, until one is "
                   "better) and take it (and write it with --write) when it detects more, "
                   "isolates no less and adds no false alarm.")
@click.option("--workers", default=2, show_default=True, type=WORKERS,
              help="Local Dask worker processes (one thread each).")
@click.option("--scheduler", default=None, type=SCHEDULER,
              help="Address of a running Dask scheduler (tcp://HOST:PORT), or "
                   "'synchronous' (in-process).")
@click.option("--write", is_flag=True,
              help="Write the tuned thresholds into the model file's [fdi.thresholds].")
@click.option("--report", "report", default=None, type=click.Path(dir_okay=False),
              help="Write the full report (all numbers, per run) as JSON.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
def tune(model, runs, duration, false_alarm_rate, margin, tolerance, validation_runs,
         fault_sizes, fault_starts, keep, horizon_runs, horizon_fault_runs, seed, filter_search,
         class_search, hold_search, realign_search, workers, scheduler, write, report,
         as_json):
    """Design the residual thresholds by Monte Carlo for a target false-alarm rate.

    Healthy runs (noise, demand and +-tolerance parameter spread) give each residual's
    per-run maximum RMS; a Gumbel/GEV fit gives the quantile for the false-alarm rate,
    times the margin. The design is then rebuilt with those thresholds and checked on
    fresh healthy runs and on every fault over a range of sizes (detection and isolation
    delays). Without --write the TOML snippet and the diff --write would apply are
    printed. Runs last the model's [simulation] duration unless --duration is given.
    On the cylinder, the defaults with 10 s runs (1.16e6 simulated samples) took 4.5-9
    minutes on a shared, loaded 2-core machine (about 2 minutes on 2 idle cores); its
    default 20 s runs take twice that; a full campaign (--runs 500 --duration 20, 1.15e7
    samples) takes 10-15 minutes on 2 idle cores, 45-90 loaded.
    """
    from pathlib import Path

    from fdigen.pipeline import resolve_model_path
    from fdigen.tune import TuneSettings, thresholds_snippet, tune as run_tune, write_thresholds
    from fdigen.tune.model_update import horizon_note, threshold_note

    try:
        factors = tuple(float(v) for v in fault_sizes.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"expected numbers separated by commas, got {fault_sizes!r}",
                                 param_hint="--fault-sizes")
    settings = TuneSettings(runs=runs, duration=duration, false_alarm_rate=false_alarm_rate,
                            margin=margin, tolerance=tolerance,
                            validation_runs=validation_runs, fault_factors=factors,
                            fault_starts=fault_starts, seed=seed,
                            horizon_runs=min(horizon_runs, runs),
                            horizon_fault_runs=min(horizon_fault_runs, runs),
                            keep=tuple(k.strip() for k in keep.split(",") if k.strip()))
    from fdigen.files.outputs import check_output_file

    path = resolve_model_path(model)
    if report:                                    # before the campaign, not after it
        check_output_file(report, "--report")
    digest = None
    if write:
        from fdigen.files.model_write import file_digest

        _check_writable_model(model, path)
        check_output_file(path, "--write (the model file)")
        digest = file_digest(path)     # the file the campaign reads; checked at the write
    log = (lambda msg: None) if as_json else (lambda msg: echo(msg, err=True))
    rep = run_tune(model, settings, workers=workers, scheduler=scheduler,
                   progress=not as_json, log=log)
    fdi_values = None

    def rerun(alt):        # the same campaign on another model file
        return run_tune(alt, settings, workers=workers, scheduler=scheduler,
                        progress=not as_json, log=log)

    from fdigen.model.model_file import load_model

    def take(rep, key, search, text, values):
        """Record a search under ``key``; when it was taken, its report (carrying the
        earlier searches' records) replaces ``rep`` and its ``[fdi]`` values join
        ``fdi_values``."""
        nonlocal fdi_values
        if search is None:
            return rep
        alt = search.pop("report")
        rep[key] = search
        log(text(search))
        if not search["taken"]:
            return rep
        alt.update({k: rep[k] for k in ("realign_search", "innovation_filter_search",
                                        "hold_search", "class_search") if k in rep})
        alt["model_file"] = rep["model_file"]
        fdi_values = {**(fdi_values or {}), **values(search)}
        return alt

    if realign_search:
        from fdigen.tune.realign_search import search_realignment

        from fdigen.tune.realign_search import slow_drift_probe

        # the campaign's own run length (tune chose it when --duration was not given)
        probe_settings = dataclasses.replace(settings, duration=float(
            rep["settings"].get("duration") or rep.get("run_duration")))

        def probe(m, thresholds):      # slow sensor drifts on a design (realign_search)
            return slow_drift_probe(m, thresholds, probe_settings, workers=workers,
                                    scheduler=scheduler)

        rep = take(rep, "realign_search",
                   search_realignment(path, rep, load_model(path), rerun, say=log,
                                      probe=probe),
                   realign_text, lambda s: {"realign_noise_scale": s["scale"]})
    filtered = sorted(k for k in settings.keep if str((rep.get("residual_keys") or {})
                                                        .get(k, "")).startswith("Kalman"))
    if filter_search and filtered:
        # the filter changes those residuals (and their keys): a kept threshold cannot
        # stand for the filtered residual (the search's campaign had ended in exit 2)
        log(f"innovation filter search skipped: --keep holds the thresholds of "
            f"{', '.join(filtered)}, which the filter would change")
        filter_search = False
    if filter_search:
        from fdigen.tune.filter_search import filter_text, search_innovation_filter

        rep = take(rep, "innovation_filter_search",
                   search_innovation_filter(path, rep, load_model(path), rerun, say=log,
                                            fdi_values=fdi_values),
                   filter_text, lambda s: {"innovation_filter": s["tau"]})
    if hold_search and horizon_runs:
        from fdigen.tune.hold_search import hold_text, search_held_correction

        rep = take(rep, "hold_search",
                   search_held_correction(path, rep, load_model(path), rerun, say=log,
                                          fdi_values=fdi_values),
                   hold_text, lambda s: {"hold_windows": s["windows"]})
    if class_search:
        from fdigen.tune.class_search import class_text, search_structural_classes

        rep = take(rep, "class_search",
                   search_structural_classes(path, rep, load_model(path), rerun, say=log,
                                             fdi_values=fdi_values),
                   class_text, lambda s: {"structural_classes": True})
    from fdigen.tune.ambiguity_time import ambiguity_text, measured_ambiguity_time

    ambiguity = measured_ambiguity_time(rep, load_model(path), fdi_values)
    if ambiguity is not None:
        rep["ambiguity_time"] = ambiguity
        if (ambiguity["seconds"] is not None or ambiguity["never_isolated"]
                or ambiguity["held_back"]):
            log(ambiguity_text(ambiguity))
        if ambiguity["seconds"] is not None:
            fdi_values = {**(fdi_values or {}), "ambiguity_time": ambiguity["seconds"]}
    if rep.get("startup"):          # the start-up the final campaign measured
        fdi_values = {**(fdi_values or {}), "startup": rep["startup"]["seconds"]}
    from fdigen.tune.refusal import KEEP, refusal_value

    mark = refusal_value(rep, str(load_model(path).fdi.get("refused", "")))
    rep["refused"] = mark if isinstance(mark, str) else ""
    if mark is not KEEP:
        fdi_values = {**(fdi_values or {}), "refused": mark}
    diff = write_thresholds(path, rep["thresholds"], rep["threshold_text"], dry_run=not write,
                            horizons=(rep["frozen_horizon"] or {}).get("horizons")
                            if rep["frozen_horizon"] else None,
                            keys=rep["residual_keys"],
                            expected_digest=digest if write else None,
                            horizon_note=horizon_note(
                                rep["frozen_horizon"], tolerance,
                                rep["settings"].get("duration"))
                            if rep["frozen_horizon"] else None,
                            threshold_note=threshold_note(rep["settings"],
                                                          rep["false_alarm"]),
                            fdi_values=fdi_values)
    rep["written"] = bool(write)
    rep["diff"] = diff
    if report:
        from fdigen.files.atomic import write_text

        write_text(report, json.dumps(rep, indent=1, default=float) + "\n")
    if as_json:
        echo(json.dumps(rep, indent=1, default=float))
        return
    _print_tune(rep)
    if write:
        echo(f"wrote the tuned thresholds to {path}; `fdigen build` puts them into "
             "the generated code")
    else:
        echo(thresholds_snippet(rep["thresholds"], rep["current_thresholds"],
                                rep["threshold_text"]))
        echo(f"--write would change {path}:" if diff else "--write would change nothing")
        echo(diff, nl=False)
    if rep["refused"]:
        echo(f"warning: these thresholds FAILED their checks, and --write "
             f"{'marked' if write else 'would mark'} the design refused ([fdi] refused = "
             f"\"{rep['refused']}\"): detect, build and inspect say so first",
             err=True)
    if report:
        echo(f"report written to {report}")


def _check_writable_model(model, path) -> None:
    """``--write`` writes only a model file the user named: never a built-in model chosen
    by name or by default (in an editable install that is the repository's file), nor
    any file inside an installed fdigen package."""
    from pathlib import Path

    from fdigen.pipeline import resolve_model_path
    from fdigen.resources import PACKAGE_DIR, SOURCE_ROOT

    named = model is not None and resolve_model_path(model) == Path(model)
    if not named:
        raise click.UsageError(
            f"--write needs --model FILE: without it the model is fdigen's built-in "
            f"{path.stem!r} ({path.name}); copy it to your project and pass --model FILE "
            f"(or --model {path} to edit the built-in file itself)")
    if SOURCE_ROOT is None and PACKAGE_DIR in path.resolve().parents:
        raise click.UsageError(f"--write: {path.name} is a built-in model of the installed "
                               "fdigen; copy it to your project and pass --model FILE")

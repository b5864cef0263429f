"""``fdigen tune``: Monte Carlo design of the residual thresholds.

Holds the command and ``_print_tune``, its rich table view of the tuning report.
"""

from __future__ import annotations

import dataclasses
import json

import click

from fdigen.cli.errors import echo
from fdigen.cli.types import COUNT, POSITIVE_SECONDS, RUNS, SCHEDULER, WORKERS


def realign_text(search: dict) -> str:
    """One paragraph on the realignment search (:mod:`fdigen.tune.realign_search`)."""
    def cases(score):
        return ", ".join(f"{f} {k}" for f, k in score["detected"]) or "none"

    from fdigen.tune.realign_search import WIDE, drifts_absorbed

    b = search["before"]

    def slower(score):
        late = drifts_absorbed(b, score)
        lost = score.get("slow_drifts_lost") or []
        wide = score.get("wide_thresholds") or []
        return ((f", drifts detected later (absorbed): {', '.join(late)}" if late else "")
                + (f", slow drifts lost: {', '.join(lost)}" if lost else "")
                + (f", thresholds of {100 * WIDE:g} % of their span or more: "
                   f"{', '.join(wide)}" if wide else ""))

    tried = "; ".join(
        f"{t['scale']:g}: detected {cases(t['score'])}, isolated "
        f"{len(t['score']['isolated'])} cases, wrong isolations "
        f"{t['score']['wrong_isolations']}, validation false alarms "
        f"{t['score']['validation_false_alarms']}{slower(t['score'])}"
        for t in search["tried"])
    reason = (search.get("reason")
              or "a fault was missed at its test size, not masked by the parameter "
              "spread")
    return (f"realignment search: {reason}; the campaign again with [fdi] "
            f"realign_noise_scale = {tried} (now {search['current_scale']:g}: detected "
            f"{cases(b)}, isolated {len(b['isolated'])} cases, wrong isolations {b['wrong_isolations']}, "
            f"validation false alarms {b['validation_false_alarms']}): "
            + (f"{search['scale']:g} taken (the thresholds below are that design's; "
               "--write writes the scale too)" if search["taken"] else
               "none taken (none detects every case detected now and detects or isolates "
               "more, or has fewer wide thresholds, with no more wrong isolations, false "
               "alarms or wide thresholds and no drift absorbed)"))


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
         class_search, realign_search, workers, scheduler, write, report, as_json):
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
                                        "class_search") if k in rep})
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


def _print_tune(rep):
    from fdigen.tune.pipeline import left_domain_text

    from fdigen.console import NBSP, console, print_table, say

    def g(v, fmt=".3g"):
        return "-" if v is None else format(v, fmt)

    con = console()
    st = rep["threshold_statistics"]
    s = rep["settings"]
    say(con, f"{rep['model']}: thresholds from {st['runs']} healthy runs of "
             f"{s['duration']:g}{NBSP}s (alpha {s['false_alarm_rate']:g}/run, "
             f"{st['alpha_per_residual']:.2g}/residual, margin {st['margin']:g}; run "
             f"length: {s.get('duration_source', '--duration')})")
    for warning in s.get("warnings", ()):
        say(con, warning)
    rows = []
    for name in rep["residuals"]:
        f = st["residuals"][name]
        gev = f.get("gev")
        rows.append((name, g(f["current"]), g(f["empirical_max"]), g(f["empirical_quantile"]),
                     g((f.get("gumbel") or {}).get("quantile")),
                     "-" if not gev else f"{gev['quantile']:.3g} ({gev['xi']:+.2f})",
                     f["basis"], rep["threshold_text"][name], g(f["ratio_to_current"], ".2f")))
    print_table(con, [(col, "left" if col in ("residual", "basis") else "right")
                      for col in ("residual", "current", "healthy max", "empirical q",
                                  "Gumbel q", "GEV q (xi)", "basis", "tuned", "x current")],
                rows)
    fa = rep["false_alarm"]
    from fdigen.tune.settings import NO_FLAG

    unset = all(st["residuals"][n]["current"] is None or st["residuals"][n]["current"]
                >= NO_FLAG for n in rep["residuals"])
    say(con, f"false alarms per {fa['run_duration']:g}{NBSP}s run: target "
             f"{fa['target_per_run']:g}; fitted {g(fa['fitted'])} ({fa['basis']}); validation "
             f"{fa['validation_false_alarms']}/{fa['validation_runs']} (95{NBSP}% upper bound "
             f"{fa['validation_upper_95']:.2g}); "
             + ("the model had no thresholds before this tune" if unset else
                f"healthy runs exceeding the current thresholds: "
                f"{fa['healthy_runs_current_thresholds_exceeded']}/{st['runs']}"))
    from fdigen.tune.sensor_span import span_warning, wide_warning

    for text in (span_warning(rep.get("thresholds_beyond_span") or {}),
                 wide_warning(rep.get("thresholds_wide") or {})):
        if text:
            say(con, "warning: " + text)
    for name, e in fa.get("early_peaks", {}).items():
        say(con, f"warning: {name}'s healthy maximum comes early (median at "
                 f"{e['median_t_max']:.4g}{NBSP}s) and is {e['ratio']:.3g} times its maximum "
                 "over the second half of the runs: its threshold is set by how the FDI "
                 "core starts, not by the running plant. The core starts the states it "
                 "does not measure (and its parallel models) at [operating_point]; a plant "
                 "that starts elsewhere ([simulation] initial, or the equilibrium of the "
                 "campaign's drawn parameters) takes that long to be followed. Make them "
                 "agree, measure those states, or accept a design that is this much less "
                 "sensitive for the whole run")
    say(con, "Fault campaign with the tuned thresholds (delays in s: median [max])")
    rows = []
    for name, f in rep["faults"].items():
        dd, idl = f["detection_delay"], f["isolation_delay"]
        sizes = ", ".join(f"{b['size']:.3g}" + ("/s" if b.get("kind") == "ramp" else "")
                          for b in f["by_size"])
        rows.append((name, sizes, str(f["runs"]), str(f["detected"]), str(f["missed"]),
                     "-" if not dd["n"] else f"{dd['median']:.3f} [{dd['max']:.3f}]",
                     str(f["isolated_correct"]), str(f["false_isolations"]),
                     str(f["not_isolated"]),
                     "-" if not idl["n"] else f"{idl['median']:.3f} [{idl['max']:.3f}]",
                     str(f["false_alarms_before_onset"]),
                     ", ".join(f"{r} ({n})" for r, n in
                               f["off_signature_before_isolation"].items()) or "-"))
    print_table(con, [(col, "left" if col in ("fault", "off-signature before isolation")
                       else "right")
                      for col in ("fault", "sizes", "runs", "detected", "missed",
                                  "detection delay", "class ok", "class wrong", "no class",
                                  "isolation delay", "FA before",
                                  "off-signature before isolation")], rows)
    say(con, "class ok / class wrong / no class: runs in which the core's class decision "
             "named the fault's class / another class / no class (the flags never singled "
             "out one class, e.g. two classes share a signature); FA before: runs that "
             "raised a flag before their fault started")
    if fa.get("validation_false_alarms"):
        say(con, f"warning: {fa['validation_false_alarms']} of {fa['validation_runs']} fresh "
                 "healthy runs raised a flag with the tuned thresholds (target "
                 f"{100 * rep['settings']['false_alarm_rate']:g} % per run): they do not hold "
                 "yet; more healthy runs (--runs) give thresholds that do")
    if rep.get("left_domain"):
        say(con, "warning: " + left_domain_text(rep["left_domain"]))
    early = sum(f["false_alarms_before_onset"] for f in rep["faults"].values())
    runs = sum(f["runs"] for f in rep["faults"].values())
    if early:
        say(con, f"warning: {early} of {runs} fault runs raised a flag before their fault "
                 "started: false alarms of the tuned thresholds that the validation runs "
                 f"({fa['validation_false_alarms']}/{fa['validation_runs']}) did not show; "
                 "more healthy runs (--runs) and validation runs (--validation-runs) "
                 "give thresholds that hold")
    rows = [(name, b.get("kind", "step"),
             f"{b['size']:.3g}" + ("/s" if b.get("kind") == "ramp" else ""),
             f"{b['factor']:g}", str(b["runs"]), f"{100 * b['detected'] / b['runs']:.0f} %",
             f"{100 * b['isolated_correct'] / b['runs']:.0f} %", str(b["false_isolations"]))
            for name, f in rep["faults"].items() for b in f["by_size"]]
    if rows:
        say(con, "Detection and isolation per fault, kind and size (ramps in units per second)")
        print_table(con, [(col, "left" if col in ("fault", "kind") else "right")
                          for col in ("fault", "kind", "size", "x test", "runs", "detected",
                                      "class ok", "class wrong")], rows)
    for name, rate in (rep.get("poorly_isolated") or {}).items():
        say(con, f"warning: {name} is class-isolable but isolated in {100 * rate:.0f} % of "
                 "its runs at its test size (< 90 %)")
    for entry in rep.get("parameter_masking") or ():
        say(con, "warning: missed at its test size: " + entry["text"])
    def narrowest(n, f):   # a set of several faults is no isolation (a user's quarter car)
        best = [g for g in f.get("fault_set_best") or () if g != n]
        return f" (to {n} or {' or '.join(best)})" if best else ""

    iso = {n: f"{f['fault_isolated']}/{f['runs']}{narrowest(n, f)}"
           for n, f in rep["faults"].items()}
    if iso:
        say(con, "consistent faults narrowed to the fault's signature (the set of faults "
                 "the flags allow is as narrow as the signature table allows, which may "
                 "hold other faults; not the class decision): "
                 + ", ".join(f"{n} {v}" for n, v in iso.items()))
    if rep.get("sensitivity"):
        say(con, "Fault sensitivity (campaign: smallest size detected / isolated in every "
                 "run, largest isolation delay at that size):")
        for entry in rep["sensitivity"].values():
            say(con, f"  {entry['text']}")
    wrong = rep.get("wrong_isolations_by_class") or {}
    if wrong:
        say(con, "warning: wrong isolations (class isolated while another "
                 "class's fault was injected): "
                 + ", ".join(f"{c} {n}" for c, n in wrong.items()))
    else:
        say(con, "wrong isolations: 0 in every class")
    hz = rep.get("frozen_horizon")
    if hz:
        never = [n for n, e in hz["earliest"].items() if e is None]
        say(con, f"validity horizons of frozen residuals ({hz['trials']} healthy freezes"
                 + (f", {hz['fault_runs']} fault runs" if "fault_runs" in hz else "")
                 + "; the campaign above used them): "
                 + (", ".join(f"{n} {v:g}{NBSP}s" for n, v in hz["horizons"].items())
                    or "none crossed")
                 + (f"; never crossed: {', '.join(never)}" if never else ""))
    if rep.get("short_horizons"):
        say(con, "warning: validity horizons shorter than one RMS window ("
                 + ", ".join(f"{n} {v:g}{NBSP}s" for n, v in rep["short_horizons"].items())
                 + "): once any flag freezes the parallel models, these residuals' flags "
                 "are no evidence for the class decision almost at once; a stronger "
                 "realignment ([fdi] realign_noise_scale) or a more accurate model keeps "
                 "them useful longer")
    for name in rep["residuals"]:
        f = st["residuals"][name]
        if f.get("warning") or f.get("note"):
            say(con, f"{name}: {f.get('note') or ''} {f.get('warning') or ''}".strip())
    t = rep["timing"]
    say(con, f"{rep['executor']}: {t['samples']} samples in {t['total']:.0f}{NBSP}s "
             f"({g(t['samples_per_second_per_core'], '.3g')} simulated samples/s per core)")

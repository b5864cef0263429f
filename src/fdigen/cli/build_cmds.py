"""The code-generation commands: ``fdigen build``, ``fdigen inspect`` and ``fdigen verify``.

``build`` derives the FDI design and regenerates every backend, ``inspect`` prints the
derived artefacts (``_print_inspect`` is its rich table view), ``verify`` compares every
backend with the symbolic reference.
"""

from __future__ import annotations

import json
import sys

import click

from fdigen.cli.errors import echo
from fdigen.cli.isolability_view import print_isolability
from fdigen.cli.types import COUNT, POSITIVE_SECONDS


@click.command()
@click.option("--model", "model", default=None,
              help="Model file (TOML) or built-in model name [default: pneumatic_cylinder].")
@click.option("--out", "out", default=None, type=click.Path(file_okay=False),
              help="Output folder; the model's files go to DIR/<model>/ "
                   "[default: ./generated, in the current folder].")
@click.option("--check", is_flag=True, help="Write nothing; exit 1 if generated code is stale.")
@click.option("--force", is_flag=True, help="Rebuild even if nothing changed.")
@click.option("--fmu", is_flag=True,
              help="Also write DIR/<model>/fmu/<model>_fdi.fmu: an FMI 2.0 co-simulation FMU "
                   "of the C core for linux64 (Simulink, OpenModelica, Dymola; needs fmpy "
                   "and gcc).")
def build(model, out, check, force, fmu):
    """Derive the FDI design and regenerate all backends' code."""
    from fdigen.errors import FdigenError
    from fdigen.pipeline import build as run_build

    try:
        result = run_build(model, out, check=check, force=force, fmu=fmu)
    except FdigenError as exc:
        more = _every_missing_threshold(model, exc)
        if more:
            exc.args = (f"{exc.args[0]}; with them, the design also derives "
                        f"{more}: `fdigen tune --model FILE --write` designs them all",
                        *exc.args[1:])
        raise
    if check:
        if result.changed:
            echo(f"{result.folder} is stale; files that would change:")
            for rel in result.changed:
                echo(f"  {rel}")
            sys.exit(1)
        echo(f"{result.folder} is up to date ({len(result.files)} files)")
        return
    for msg in result.warnings:
        echo(f"warning: {msg}", err=True)
    if result.up_to_date:
        echo(f"{result.folder} is up to date (nothing to do)")
    else:
        echo(f"wrote {len(result.files)} files to {result.folder}")


@click.command()
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--json", "as_json", is_flag=True, help="Print the derived artefacts as JSON.")
@click.option("--sensitivity", is_flag=True,
              help="Also estimate, per fault, the smallest size detected and isolated at "
                   "the design's thresholds (one simulated run per fault at its test size, "
                   "scaled by each residual's ratio to its threshold).")
def inspect(model, as_json, sensitivity):
    """Print the derived artefacts: linearisation, reductions, gains, signature table."""
    from fdigen.design.describe import describe_design
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    design, missing, refused = _design_before_tuning(load_model(resolve_model_path(model)))
    info = describe_design(design)
    info["thresholds_missing"] = list(missing)
    info["thresholds_refused"] = refused
    info["unkeyed_thresholds"] = [n for n in info["unkeyed_thresholds"] if n not in missing]
    for name in missing:                   # a never-flagging stand-in, not a threshold
        info["isolation"]["thresholds"][name] = None
    from fdigen.design.design_warnings import (domain_warnings, idle_fault_warnings,
                                               linear_driver_warnings,
                                               parameter_bound_warnings,
                                               unread_sensor_warnings)
    from fdigen.pipeline import (detection_warnings, open_loop_warnings,
                                 operating_point_warnings, refusal_warning)

    from fdigen.design.ambiguity_exposure import ambiguity_warnings, hold_warnings
    from fdigen.design.residual_scale import spread_dominated_thresholds

    info["warnings"] = [*refusal_warning(design), *detection_warnings(design),
                        *open_loop_warnings(design),
                        *operating_point_warnings(design), *domain_warnings(design),
                        *idle_fault_warnings(design), *linear_driver_warnings(design),
                        *parameter_bound_warnings(design),
                        *unread_sensor_warnings(design),
                        *spread_dominated_thresholds(
                            info["residual_scales"], info["isolation"]["thresholds"],
                            parity=tuple(design.config.parity),
                            realign_noise_scale=design.config.realign_noise_scale),
                        *ambiguity_warnings(design), *hold_warnings(design)]
    if sensitivity and missing:
        # scaled against a never-flagging stand-in, the sizes read 1e30 (a user's press)
        info["sensitivity"] = None
        info["sensitivity_needs"] = list(missing)
    elif sensitivity:
        from fdigen.tune.fault_sensitivity import estimated_sensitivity

        info["sensitivity"] = estimated_sensitivity(design)
    if as_json:
        echo(json.dumps(info, indent=1, sort_keys=True))
        return
    from fdigen.console import console, say

    err = console(stderr=True)
    first = refusal_warning(design)      # a refused design is said first (README)
    for msg in first:
        say(err, f"warning: {msg}")
    _print_inspect(info, design)
    for msg in info["warnings"]:
        if msg not in first:
            say(err, f"warning: {msg}")


def _every_missing_threshold(model, exc) -> str:
    """The derived residuals a model without thresholds would also need thresholds for
    ("R4 (T2 balance ...), R5 (...)"), when ``exc`` is the refusal of declared residuals
    without one; else "". The design derives them only once the declared ones have a
    threshold, so the refusal alone listed R1-R3 and a user met R4 after tuning those."""
    if not getattr(exc, "missing_thresholds", ()):
        return ""
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    try:
        design, missing, _ = _design_before_tuning(load_model(resolve_model_path(model)))
    except Exception:  # noqa: BLE001 - the original refusal stands on its own
        return ""
    derived = {e["residual"]: e["description"] for e in design.extra_residuals}
    extra = [n for n in missing if n in derived and n not in exc.missing_thresholds]
    return ", ".join(f"{n} ({derived[n]})" for n in extra)


def _design_before_tuning(model):
    """``(design, missing, refused)``: the model's design; a model whose thresholds are not
    designed yet (or were written for other residuals) gets a never-flagging stand-in for
    them, named in ``missing``, so that its structure and signature table can be shown
    before ``fdigen tune``; ``refused`` is the refusal of stale thresholds, or ``""``."""
    from fdigen.design.cache import cached_design
    from fdigen.errors import FdigenError

    try:
        return cached_design(model), (), ""
    except FdigenError as exc:
        if not (getattr(exc, "missing_thresholds", ()) or getattr(exc, "stale_residuals", ())):
            raise
        refused = str(exc) if getattr(exc, "stale_residuals", ()) else ""
    from fdigen.tune.model_update import fill_missing_thresholds
    from fdigen.tune.settings import NO_FLAG

    filled, missing = fill_missing_thresholds(model, NO_FLAG)
    return cached_design(filled), missing, refused


def _print_inspect(info, design=None):
    from fdigen.console import NBSP, console, print_table, say

    con = console()
    say(con, f"{info['model']} ({info['source']}), states {info['states']}, "
             f"sample time {info['sample_time']}{NBSP}s", bold=len(info["model"]))
    for k in info["kalman"]:
        say(con, f"Kalman filter {k['residual']}: measurement {k['measurement']}, "
                 f"coordinates {k['coordinates']}, |poles| "
                 + ", ".join(f"{p:.4f}" for p in k["poles_discrete_abs"]))
        say(con, f"  reduced A = {_readable_A(design, k)}")
        if k.get("scheduled_on"):
            say(con, "  prediction scheduled on " + ", ".join(
                f"{s} = {sig}" for s, sig in k["scheduled_on"].items()))
    say(con, "Fault signature table (derived): 1 = the residual responds")
    residuals = list(info["signature_table"])
    print_table(con, [("fault", "left"), ("class", "left"), *((r, "center") for r in residuals)],
                [[f, spec["class"], *(str(info["signature_table"][r][f]) for r in residuals)]
                 for f, spec in info["faults"].items()])
    for f, spec in info["faults"].items():
        if "targets" in spec:
            say(con, f"fault {f} enters {', '.join(spec['targets'])} (one fault)")
    for e in info["extra_residuals"]:
        say(con, f"derived residual {e['residual']}: {e['description']}")
    _print_sensor_maps(con, info.get("sensor_maps", {}))
    _print_residual_scales(con, info)
    if info["unresolved_pairs_within_class"]:
        say(con, "fault pairs not isolable from each other: "
                 + ", ".join("/".join(p) for p in info["unresolved_pairs_within_class"]))
    if info.get("unresolved_pairs_across_classes"):
        say(con, "fault pairs of different classes not strongly isolated (one signature "
                 "contains the other): "
                 + ", ".join("/".join(p) for p in info["unresolved_pairs_across_classes"]))
    print_isolability(con, info["isolability"])
    _print_actions(con, info, design)
    _print_sensitivity(con, info)


def _print_actions(con, info, design):
    """Each class's action; what ``accommodate`` does without a voter."""
    from fdigen.console import say
    from fdigen.design.config import ACCOMMODATE_WITHOUT_VOTER

    actions = {c: a for c, a in info["isolation"]["actions"].items() if c != "none"}
    say(con, "actions: " + ", ".join(f"{c} -> {a}" for c, a in actions.items()))
    if "accommodate" in actions.values() and design is not None \
            and design.config.voter is None:
        say(con, ACCOMMODATE_WITHOUT_VOTER)


def _print_residual_scales(con, info):
    """Each residual's compared quantity, unit, noise-only level and threshold; missing,
    refused or unkeyed thresholds."""
    from fdigen.console import print_table, say

    thresholds = info["isolation"]["thresholds"]
    rows = []
    for name, sc in info["residual_scales"].items():
        thr, level = thresholds.get(name), sc["noise_level"]
        rows.append([name, sc["compares"], sc["unit"],
                     "-" if level is None else f"{level:.3g}",
                     "missing" if thr is None else f"{thr:.3g}",
                     "-" if thr is None or not level else f"{thr / level:.3g}"])
    say(con, "Residuals: what each compares, its unit, its level on noise alone and its "
             "threshold (RMS, same unit)")
    print_table(con, [("residual", "left"), ("compares", "left"), ("unit", "left"),
                      ("noise level", "right"), ("threshold", "right"),
                      ("threshold / noise", "right")], rows)
    bases = sorted({sc["basis"] for sc in info["residual_scales"].values()
                    if sc["noise_level"] is not None})
    if bases:
        say(con, "noise level: " + "; ".join(bases))
    if info.get("thresholds_refused"):
        say(con, "thresholds refused: " + info["thresholds_refused"])
    if info.get("thresholds_missing"):
        say(con, "no thresholds yet for " + ", ".join(info["thresholds_missing"])
                 + ": the table and isolability above do not need them; `fdigen tune "
                 "--model FILE --write` designs them (flags and detection need them)")
    if info.get("unkeyed_thresholds"):
        say(con, "warning: the thresholds of derived residuals "
                 + ", ".join(info["unkeyed_thresholds"]) + " carry no residual key "
                 "([fdi.residual_keys]): nothing tells which residual they were written "
                 "for; `fdigen tune --model FILE --write` designs them and writes the keys")


def _print_sensor_maps(con, maps):
    """Sensors read through a map (volts, an offset) and outputs that measure no state."""
    from fdigen.console import say

    for out, m in maps.get("measures", {}).items():
        if m.get("with"):
            say(con, f"sensor {out} measures {m['state']} once {', '.join(m['with'])} "
                     f"{'is' if len(m['with']) == 1 else 'are'} known: {m['inverse']} "
                     "drives sub-models")
            continue
        say(con, f"sensor {out} measures {m['state']} through its map: {m['inverse']} "
                 "drives sub-models, initial states and schedules")
    for out, why in maps.get("not_measurements", {}).items():
        say(con, f"warning: output {out} is used as no state's measurement (no sub-model "
                 f"is driven by it, no derived residual built on it): {why}")


def _print_sensitivity(con, info):
    from fdigen.console import say

    if info.get("sensitivity_needs"):
        say(con, "Fault sensitivity at the thresholds: not estimated: the thresholds of "
                 + ", ".join(info["sensitivity_needs"]) + " are not designed yet "
                 "(`fdigen tune --model FILE --write` designs them)")
    if info.get("sensitivity"):
        say(con, "Fault sensitivity at the thresholds (estimate: one run per fault at its "
                 "test size, residual ratio to threshold scaled linearly; isolation needs, "
                 "against every fault of another class, one residual it lacks; nominal "
                 "parameters and no confirmation time, so it can be optimistic: `fdigen "
                 "tune` measures these sizes over the parameter spread):")
        for entry in info["sensitivity"].values():
            say(con, f"  {entry['text']}")


def _readable_A(design, k):
    """The reduced A of filter ``k`` without DiracDelta/Piecewise (see design.readable)."""
    if design is None:
        return k["A_reduced_symbolic"]
    from fdigen.design.readable import readable_matrix

    for filt in design.kalman:
        if filt.residual == k["residual"]:
            return readable_matrix(filt.reduction.A_r)
    return k["A_reduced_symbolic"]


@click.command()
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--backend", "backends", multiple=True,
              type=click.Choice(["casadi_sx", "casadi_compiled", "c"]),
              help="Backends to compare with the reference [default: all].")
@click.option("--points", default=1000, show_default=True, type=COUNT, help="Random points.")
@click.option("--duration", default=None, type=POSITIVE_SECONDS,
              help="Seconds of each closed-loop trajectory [default: as simulate: the "
                   "model's [simulation] duration, else 6 RMS windows or 5 slowest time "
                   "constants, at most 20000 samples].")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
def verify(model, backends, points, duration, as_json):
    """Prove every backend computes what the symbolic reference says."""
    from fdigen.cli.durations import verify_duration
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.verify.equivalence import verify as run_verify

    design = cached_design(load_model(resolve_model_path(model)))
    duration, source = verify_duration(design.model, design.config.sample_time, duration)
    rep = run_verify(design, backends or None, n_points=points, duration=duration)
    rep["duration"] = duration
    rep["ok"] = all(b["summary"]["ok"] for b in rep["backends"].values())
    if as_json:
        echo(json.dumps(rep, indent=1, sort_keys=True))
    else:
        trajs = rep["trajectories"]
        echo(f"{points} random points; {len(trajs)} closed-loop trajectories of "
             f"{duration:g} s ({source}), {sum(t['samples'] for t in trajs)} samples")
        for name, b in rep["backends"].items():
            s = b["summary"]
            echo(f"{name:16s} points max rel {s['points_max_rel']:.3g}  trajectories max "
                 f"rel {s['trajectories_max_rel']:.3g}  discrete mismatches "
                 f"{s['discrete_mismatches']}  {'OK' if s['ok'] else 'FAIL'}")
    if not rep["ok"]:
        sys.exit(1)

"""The commands that run the FDI on logs: ``fdigen detect``, ``fdigen report`` and
``fdigen experiments`` (``fdigen simulate``: :mod:`fdigen.cli.simulate_cmd`).

``detect`` and ``report`` also take ``--platform`` and then hand over to the runners of
:mod:`fdigen.cli.platform_common`.
"""

from __future__ import annotations

import contextlib
import json
import math

import click

from fdigen.cli.errors import _fail, echo
from fdigen.cli.platform_common import (_FORCE_OPTION, _GEOMETRY_OPTION, _PER_LEG_OPTION,
                                        _SAFETY_OPTION, _not_a_folder, _platform_flag,
                                        _platform_only, _run_platform_detect,
                                        _run_platform_report)
from fdigen.files.atomic import write_text


@click.command()
@click.argument("log", type=click.Path())
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--backend", default="auto", show_default=True,
              type=click.Choice(["auto", "c", "casadi", "reference"]))
@_platform_flag("LOG is the folder of a platform run (leg1.csv..leg6.csv, as written by "
                "`fdigen simulate --platform`): every leg's FDI, then the supervisor.")
@_GEOMETRY_OPTION
@_SAFETY_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print the decision as JSON.")
@click.pass_context
def detect(ctx, log, model, backend, platform_run, geometry, safety_duration, as_json):
    """Run the FDI core over LOG (rig CSV format, or .mat, .parquet, .h5 with the same
    columns) and report flags and diagnosis.

    With --platform, LOG is a folder of six leg logs: each leg's decision (class, time,
    action, flags) and the platform's (which leg, which class, safety sequence or not).
    """
    _platform_only(ctx, platform_run, ("geometry", "safety_duration"))
    if platform_run:
        _run_platform_detect(log, model, backend, geometry, safety_duration, as_json)
        return
    _not_a_folder(log)
    from fdigen.errors import LogError
    from fdigen.files.bounded import check_regular_file

    check_regular_file(log, what="log", error=LogError)   # before deriving the design
    from fdigen.design.cache import cached_design
    from fdigen.detect import detect_log
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    design = cached_design(load_model(resolve_model_path(model)))
    with _default_model_hint(model):
        summary, _ = detect_log(design, log, backend)
    summary["design_refused"] = design.config.refused or None
    if as_json:
        echo(json.dumps(summary, indent=1))
        return
    from fdigen.console import NBSP, console, print_table, say

    con = console()
    if design.config.refused:
        from fdigen.design.config import refused_text

        say(console(stderr=True), "warning: " + refused_text(design.config.refused))
    say(con, f"{log}: {summary['samples']} samples at {summary['sample_time']:g}{NBSP}s")
    p = _places(summary.get("sample_time"))
    _say_log_repairs(con, summary, p)
    print_table(con, [("residual", "left"), ("flag raised at [s]", "right")],
                [(f["residual"] + (" (late)" if f.get("late") else ""),
                  f"{f['t_raised']:.{p}f}") for f in summary["flags"]])
    if any(f.get("late") for f in summary["flags"]):
        say(con, "(late): raised after its validity horizon once the first flag froze the "
                 "parallel models ([fdi.frozen_horizon]): no evidence for the class decision "
                 "or the action")
    say(con, _decision_text(summary))
    if summary["diagnosis"]["action"] == "accommodate" and design.config.voter is None:
        from fdigen.design.config import ACCOMMODATE_WITHOUT_VOTER

        say(con, ACCOMMODATE_WITHOUT_VOTER)


@contextlib.contextmanager
def _default_model_hint(model):
    """Without ``--model``, a log that lacks the default model's columns is most likely
    another plant's: say which model was assumed."""
    from fdigen.errors import LogError

    try:
        yield
    except LogError as exc:
        if model is not None or "missing column" not in str(exc):
            raise
        raise LogError(f"{exc}; the default model is pneumatic_cylinder: pass --model "
                       "(a built-in model's name or your model file)") from exc


def _places(sample_time) -> int:
    """Decimals of the times ``detect`` prints: milliseconds, or the sample time's own
    (a user's buck converter at 20 us read every flag and its action "at 0.025 s")."""
    try:
        dt = float(sample_time)
    except (TypeError, ValueError):
        return 3
    if not math.isfinite(dt) or dt <= 0:
        return 3
    return min(max(3, math.ceil(-math.log10(dt) - 1e-9)), 9)


def _action_basis_text(d: dict, lead: str, p: int = 3) -> str:
    """`` from <t> s (<why>: <classes>)``: when and why an action was taken without (or
    before) an isolated class."""
    from fdigen.console import NBSP

    why = ("every consistent class calls for it" if d["action_basis"] == "unanimous"
           else "the most severe of the consistent classes' actions")
    head = f"{lead}, at" if lead else " from"
    return (f"{head} {d['t_action']:.{p}f}{NBSP}s: {why}: "
            f"{', '.join(d['action_classes'])})"
            if lead else f"{head} {d['t_action']:.{p}f}{NBSP}s ({why}: "
            f"{', '.join(d['action_classes'])})")


def _decision_text(summary: dict) -> str:
    """The decision line of ``fdigen detect``: the isolated class, time and action; or
    that flags were raised without a class being isolated (and which); or nothing."""
    from fdigen.console import NBSP

    d = summary["diagnosis"]
    p = _places(summary.get("sample_time"))
    esc = d.get("unexplained")
    if not summary.get("enough_data", True) and not summary["detected"]:
        return f"diagnosis: {summary['verdict']} (no flag raised), action: {d['action']}"
    if esc:
        flags = ", ".join(esc["contradicting_flags"]) or "flags"
        what = (f"{esc['contradicts']} isolated at {esc['t_contradicted']:.{p}f}{NBSP}s"
                if esc["contradicts"] != "none" else "every declared fault")
        text = (f"diagnosis: unexplained at {esc['t']:.{p}f}{NBSP}s ({flags} contradicts "
                f"{what}: several faults, or one the model lacks), action: {d['action']}")
    elif d["t_isolated"] is not None:
        text = (f"diagnosis: {d['fault']} at {d['t_isolated']:.{p}f}{NBSP}s, action: "
                f"{d['action']}"
                + (f" (candidates: {', '.join(d['candidates'])})" if d["candidates"] else ""))
        if d.get("t_action") is not None and d.get("action_basis") not in (None, "isolated"):
            # taken under ambiguity before the isolation, and latched: say so, or the
            # action reads as the isolated class's own
            text += _action_basis_text(d, " (latched: taken before the isolation", p)
    elif summary["detected"]:
        raised = ", ".join(f"{f['residual']} at {f['t_raised']:.{p}f}{NBSP}s"
                           for f in summary["flags"])
        text = (f"diagnosis: detected, not isolated (flags raised: {raised}), action: "
                f"{d['action']}")
        if d.get("t_action") is not None:
            text += _action_basis_text(d, "", p)
        named = d.get("named_class")
        if named:
            text += (f"; the faults named are all of class {named}, separated by residuals "
                     "the class decision does not read (docs/isolation.md, section 4)")
    else:
        return f"diagnosis: none (no flag raised), action: {d['action']}"
    if summary["flags"]:
        text += (f"\nconsistent faults: {d['fault_set']}"
                 + (f" (since {d['t_fault_set']:.{p}f}{NBSP}s)"
                    if d["t_fault_set"] is not None else ""))
    if not summary.get("enough_data", True):
        text += f"\nnote: {summary['verdict']}"
    return text


@click.command()
@click.argument("log", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Report to write: a .png, .pdf or .svg figure or a self-contained .html page (with "
                   "--platform a .png overview; each leg's report goes beside it as "
                   "<name>_leg<i>.png).")
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--backend", default="auto", show_default=True,
              type=click.Choice(["auto", "c", "casadi", "reference"]))
@_platform_flag("LOG is the folder of a platform run: draw the six legs' demands, "
                "positions and decisions, and each leg's residuals.")
@_PER_LEG_OPTION
@_GEOMETRY_OPTION
@_SAFETY_OPTION
@_FORCE_OPTION
@click.pass_context
def report(ctx, log, output, model, backend, platform_run, per_leg, geometry, safety_duration,
           force):
    """Draw the moving RMS of each residual on LOG against its threshold (paper Figs 6-7)."""
    _platform_only(ctx, platform_run, ("per_leg", "geometry", "safety_duration", "force"))
    if platform_run:
        _run_platform_report(log, output, model, backend, per_leg, geometry, safety_duration,
                             force)
        return
    _not_a_folder(log)
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.report import diagnosis_text, output_format, render_report

    output_format(output)  # fail on a bad suffix before deriving anything
    from fdigen.files.outputs import check_output_file

    check_output_file(output, "-o")
    design = cached_design(load_model(resolve_model_path(model)))
    from fdigen.console import console, say

    if design.config.refused:      # said first, as detect, build and inspect do
        from fdigen.design.config import refused_text

        say(console(stderr=True), "warning: " + refused_text(design.config.refused))
    with _default_model_hint(model):
        summary = render_report(design, log, output, backend)

    # what reading the log did to it, as detect says (attack 10: a log whose command was
    # missing on 998 of 1000 rows was drawn as "no flag raised" and nothing else)
    _say_log_repairs(console(), summary, _places(summary.get("sample_time")))
    echo(f"wrote {output}: {diagnosis_text(summary)}")


def _say_log_repairs(con, summary: dict, p: int) -> None:
    """What reading the log did to it (``fdigen detect`` and ``fdigen report``): gaps
    interpolated, dropped rows put back, duplicated rows dropped, logger outages."""
    from fdigen.console import say

    miss = {k: v for k, v in (summary.get("missing") or {}).items() if k != "duplicates"}
    if miss:
        from fdigen.sim.log_gaps import MAX_FILL

        say(con, f"missing samples (gaps of up to {MAX_FILL} samples interpolated, longer "
                 "ones run as a dead sensor: its nf_ flag): "
                 + ", ".join(f"{k} {v}" for k, v in miss.items() if k != "rows")
                 + (f"; {miss['rows']} dropped rows put back" if miss.get("rows") else ""))
    if (summary.get("missing") or {}).get("duplicates"):
        say(con, f"{summary['missing']['duplicates']} duplicated rows (written twice, stamp "
                 "and values) dropped")
    if summary.get("outages"):
        say(con, "logger outage (a command missing), not diagnosed; the core restarts "
                 "after it: " + ", ".join(f"{a:.{p}f}-{b:.{p}f} s"
                                          for a, b in summary["outages"]))


@click.command()
@click.option("-o", "--output", default=None, type=click.Path(dir_okay=False),
              help="Markdown file to write (e.g. EXPERIMENTS.md) [default: print it].")
@click.option("--model", "model", default=None,
              help="The pneumatic cylinder's model file (a variant of it: the paper's "
                   "experiments name its faults; another plant is refused).")
@click.option("--backend", default="auto", show_default=True,
              type=click.Choice(["auto", "c", "casadi", "reference"]))
@click.option("--after", default=15.0, show_default=True,
              help="Seconds simulated after each fault.")
@click.option("--seed", default=0, show_default=True, help="Seed of the sensor noise.")
@click.option("--rig-logs", default=None, type=click.Path(file_okay=False),
              help="Folder of the reference rig's fdi_*.csv logs [default: $FDIGEN_RIG_LOGS "
                   "or the shared rig folder beside the repository; skipped if absent].")
def experiments(output, model, backend, after, seed, rig_logs):
    """Reproduce the paper's Table 2 in simulation and check the rig logs; write markdown."""
    from pathlib import Path

    from fdigen.design.cache import cached_design
    from fdigen.experiments import (check_model, default_rig_logs, experiments_document,
                                    rig_log_outcomes, run_experiments)
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    if output is not None:
        from fdigen.files.outputs import check_output_file

        check_output_file(output, "-o")
    design = cached_design(load_model(resolve_model_path(model)))
    check_model(design)
    folder = Path(rig_logs) if rig_logs else default_rig_logs()
    if folder is not None and not folder.is_dir():
        _fail(f"{folder}: no such folder of rig logs")
    outcomes = run_experiments(design, backend, after=after, seed=seed)
    rig = None if folder is None else rig_log_outcomes(design, folder, backend)
    shown = "/".join(folder.resolve().parts[-3:]) + "/" if folder else ""
    text = experiments_document(design, outcomes, rig, after=after, seed=seed,
                                rig_folder=shown)
    if output is None:
        echo(text, nl=False)
        return
    try:
        write_text(output, text)
    except OSError as exc:
        _fail(f"{output}: cannot write ({exc.strerror or exc})")
    ok = sum(o.correct for o in outcomes + (rig or []))
    echo(f"wrote {output}: {ok} of {len(outcomes) + len(rig or [])} runs diagnosed "
         "correctly")

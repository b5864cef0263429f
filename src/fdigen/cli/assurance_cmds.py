"""The assurance commands: ``fdigen prove`` (Frama-C EVA on the generated C) and
``fdigen pil`` (processor-in-the-loop on the emulated Cortex-M4F).

Logic in :mod:`fdigen.verify.prove` and :mod:`fdigen.verify.pil`; see docs/assurance.md.
"""

from __future__ import annotations

import json
import sys

import click

from fdigen.cli.errors import echo


def _design(model):
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    return cached_design(load_model(resolve_model_path(model)))


@click.command()
@click.option("--model", "model", default=None,
              help="Model file or built-in model name [default: pneumatic_cylinder].")
@click.option("--float-type", "float_types", multiple=True,
              type=click.Choice(["double", "float"]),
              help="Variant(s) of the generated C to analyse [default: both].")
@click.option("--precision", default=None, type=click.IntRange(0, 11),
              help="EVA precision 0..11 [default: 1, 0 alarms on the shipped models].")
@click.option("--platform", "platform", is_flag=True,
              help="Analyse the six-leg bank (<model>_platform_step) with the leg core.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
def prove(model, float_types, precision, platform, as_json):
    """Prove the generated C free of run-time errors (Frama-C EVA); exit 1 on any alarm."""
    from fdigen.verify.prove import DEFAULT_PRECISION
    from fdigen.verify.prove import prove as run_prove

    design = _design(model)
    rep = run_prove(design, float_types or ("double", "float"),
                    precision=DEFAULT_PRECISION if precision is None else precision,
                    platform=platform)
    if as_json:
        echo(json.dumps(rep, indent=1, sort_keys=True))
    else:
        for v in rep["variants"]:
            cov = v["coverage"]
            echo(f"{rep['model']} ({v['float_type']}): {v['alarms']} alarms; "
                 f"functions {cov['functions'][0]}/{cov['functions'][1]}, statements "
                 f"{cov['statements'][0]}/{cov['statements'][1]} reached; "
                 f"{v['seconds']:.1f} s")
            for a in v["alarm_list"]:
                echo(f"  {a['file']}:{a['line']}: {a['message']}")
        echo("assumptions: " + "; ".join(rep["assumptions"]))
    if rep["alarms"]:
        sys.exit(1)


def _platform_run(design, folder):
    """(demand, u, y) of a folder of platform logs (the demands: each leg's reference
    column, else its primary sensor, as ``fdigen platform detect`` takes them)."""
    import numpy as np

    from fdigen.platform.simulate import primary_output_index
    from fdigen.platform.supervisor import read_platform_logs

    logs = read_platform_logs(design, folder)
    ref = dict(design.model.simulation).get("reference_column", "xref")
    primary = primary_output_index(design.model)
    demand = np.stack([lg.extra[ref] if ref in lg.extra else lg.y[:, primary]
                       for lg in logs], axis=1)
    return demand, np.stack([lg.u for lg in logs], axis=1), np.stack([lg.y for lg in logs],
                                                                      axis=1)


@click.command()
@click.argument("logs", nargs=-1, required=True, type=click.Path())
@click.option("--model", "model", default=None,
              help="Model file or built-in model name [default: pneumatic_cylinder].")
@click.option("--platform", "platform", is_flag=True,
              help="Each argument is a folder of platform logs (leg1.csv .. leg6.csv): run "
                   "the six-leg bank's step instead of the single core's.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
def pil(logs, model, platform, as_json):
    """Processor-in-the-loop: replay LOG(s) on the emulated Cortex-M4F (QEMU mps2-an386)
    and on the host; exit 1 unless every output is bit-identical."""
    from pathlib import Path

    from fdigen.sim.log import read_log
    from fdigen.verify.pil import run_pil

    design = _design(model)
    data = []
    for path in logs:
        if platform:
            data.append(_platform_run(design, path))
        else:
            log = read_log(path, design.model, sample_time=design.config.sample_time)
            data.append((log.u, log.y))
    rep = run_pil(design, data, platform=platform)
    rep["logs"] = [Path(p).name for p in logs]
    if as_json:
        echo(json.dumps(rep, indent=1, sort_keys=True))
    else:
        code = rep["code_bytes"]
        echo(f"{rep['step']}: {rep['samples']} samples of {len(logs)} log(s) on the "
             f"emulated Cortex-M4F: {'bit-identical to' if rep['equal'] else 'DIFFERENT from'}"
             f" the host float build (max |difference| {rep['max_abs_difference']:.3g}, "
             f"{rep['mismatched_samples']} samples differ)")
        echo(f"{rep['instructions_per_step']:.0f} instructions per step (QEMU -icount); "
             f"stack {rep['stack_bytes']} B measured ({rep['stack_bytes_static']} B "
             f"-fstack-usage); core .text {code.get('.text', 0)} B, .rodata "
             f"{code.get('.rodata', 0)} B, .data+.bss "
             f"{code.get('.data', 0) + code.get('.bss', 0)} B; state {rep['state_bytes']} B")
    if not rep["equal"]:
        sys.exit(1)


@click.command()
@click.option("--model", "model", default=None,
              help="Model file or built-in model name [default: pneumatic_cylinder].")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
def misra(model, as_json):
    """MISRA C:2012 report of the generated C (cppcheck's addon) against the deviation
    record; exit 1 on a violation of a rule without a deviation."""
    from fdigen.verify.misra import load_deviations, misra_report

    rep = misra_report(_design(model))
    if as_json:
        echo(json.dumps(rep, indent=1, sort_keys=True))
    else:
        record = load_deviations()["rules"]
        echo(f"{rep['model']}: {rep['violations']} violations of "
             f"{len(rep['rules'])} rules in {len(rep['files'])} files")
        for rule, n in rep["rules"].items():
            entry = record.get(rule)
            echo(f"  {rule:>5} {n:5d}  " + (f"deviation ({entry['category']}): "
                                            f"{entry['title']}" if entry
                                            else "NO DEVIATION RECORD"))
    if rep["undeviated"]:
        sys.exit(1)

"""The assurance commands: ``fdigen prove`` (Frama-C EVA on the generated C) and
``fdigen pil`` (processor-in-the-loop on the emulated Cortex-M4F).

Logic in :mod:`fdigen.verify.prove` and :mod:`fdigen.verify.pil`; see docs/assurance.md.
"""

from __future__ import annotations

import json
import sys

import click


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
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
def prove(model, float_types, precision, as_json):
    """Prove the generated C free of run-time errors (Frama-C EVA); exit 1 on any alarm."""
    from fdigen.verify.prove import DEFAULT_PRECISION
    from fdigen.verify.prove import prove as run_prove

    design = _design(model)
    rep = run_prove(design, float_types or ("double", "float"),
                    precision=DEFAULT_PRECISION if precision is None else precision)
    if as_json:
        click.echo(json.dumps(rep, indent=1, sort_keys=True))
    else:
        for v in rep["variants"]:
            cov = v["coverage"]
            click.echo(f"{rep['model']} ({v['float_type']}): {v['alarms']} alarms; "
                       f"functions {cov['functions'][0]}/{cov['functions'][1]}, statements "
                       f"{cov['statements'][0]}/{cov['statements'][1]} reached; "
                       f"{v['seconds']:.1f} s")
            for a in v["alarm_list"]:
                click.echo(f"  {a['file']}:{a['line']}: {a['message']}")
        click.echo("assumptions: " + "; ".join(rep["assumptions"]))
    if rep["alarms"]:
        sys.exit(1)

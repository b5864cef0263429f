"""The code-generation commands: ``fdigen build``, ``fdigen inspect`` and ``fdigen verify``.

``build`` derives the FDI design and regenerates every backend, ``inspect`` prints the
derived artefacts (``_print_inspect`` is its rich table view), ``verify`` compares every
backend with the symbolic reference.
"""

from __future__ import annotations

import json
import sys

import click

from fdigen.cli.types import COUNT, POSITIVE_SECONDS


@click.command()
@click.option("--model", "model", default=None,
              help="Model file (TOML) or built-in model name [default: pneumatic_cylinder].")
@click.option("--out", "out", default=None, type=click.Path(file_okay=False),
              help="Output folder [default: the repository's generated/].")
@click.option("--check", is_flag=True, help="Write nothing; exit 1 if generated code is stale.")
@click.option("--force", is_flag=True, help="Rebuild even if nothing changed.")
def build(model, out, check, force):
    """Derive the FDI design and regenerate all backends' code."""
    from fdigen.pipeline import build as run_build

    result = run_build(model, out, check=check, force=force)
    if check:
        if result.changed:
            click.echo(f"{result.folder} is stale; files that would change:")
            for rel in result.changed:
                click.echo(f"  {rel}")
            sys.exit(1)
        click.echo(f"{result.folder} is up to date ({len(result.files)} files)")
        return
    if result.up_to_date:
        click.echo(f"{result.folder} is up to date (nothing to do)")
    else:
        click.echo(f"wrote {len(result.files)} files to {result.folder}")


@click.command()
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--json", "as_json", is_flag=True, help="Print the derived artefacts as JSON.")
def inspect(model, as_json):
    """Print the derived artefacts: linearisation, reductions, gains, signature table."""
    from fdigen.design.describe import describe_design
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    design = cached_design(load_model(resolve_model_path(model)))
    info = describe_design(design)
    if as_json:
        click.echo(json.dumps(info, indent=1, sort_keys=True))
        return
    _print_inspect(info)


def _print_inspect(info):
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    con = Console()
    con.print(f"[bold]{info['model']}[/] ({info['source']}), states {info['states']}, "
              f"sample time {info['sample_time']} s")
    for k in info["kalman"]:
        con.print(f"Kalman filter {k['residual']}: measurement {k['measurement']}, "
                  f"coordinates {k['coordinates']}, |poles| "
                  + ", ".join(f"{p:.4f}" for p in k["poles_discrete_abs"]))
        con.print(escape(f"  reduced A = {k['A_reduced_symbolic']}"))
        if k.get("scheduled_on"):
            con.print(escape("  prediction scheduled on " + ", ".join(
                f"{s} = {sig}" for s, sig in k["scheduled_on"].items())))
    table = Table(title="Fault signature table (derived): 1 = the residual responds")
    residuals = list(info["signature_table"])
    table.add_column("fault")
    table.add_column("class")
    for r in residuals:
        table.add_column(r, justify="center")
    for f, spec in info["faults"].items():
        table.add_row(f, spec["class"], *[str(info["signature_table"][r][f]) for r in residuals])
    con.print(table)
    for e in info["extra_residuals"]:
        con.print(escape(f"derived residual {e['residual']}: {e['description']}"))
    if info["unresolved_pairs_within_class"]:
        con.print("fault pairs not isolable from each other: "
                  + ", ".join("/".join(p) for p in info["unresolved_pairs_within_class"]))


@click.command()
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--backend", "backends", multiple=True,
              type=click.Choice(["casadi_sx", "casadi_compiled", "c"]),
              help="Backends to compare with the reference [default: all].")
@click.option("--points", default=1000, show_default=True, type=COUNT, help="Random points.")
@click.option("--duration", default=20.0, show_default=True, type=POSITIVE_SECONDS,
              help="Seconds of each closed-loop trajectory.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
def verify(model, backends, points, duration, as_json):
    """Prove every backend computes what the symbolic reference says."""
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.verify.equivalence import verify as run_verify

    design = cached_design(load_model(resolve_model_path(model)))
    rep = run_verify(design, backends or None, n_points=points, duration=duration)
    if as_json:
        click.echo(json.dumps(rep, indent=1, sort_keys=True))
    else:
        for name, b in rep["backends"].items():
            s = b["summary"]
            click.echo(f"{name:16s} points max rel {s['points_max_rel']:.3g}  trajectories max "
                       f"rel {s['trajectories_max_rel']:.3g}  discrete mismatches "
                       f"{s['discrete_mismatches']}  {'OK' if s['ok'] else 'FAIL'}")
    if not all(b["summary"]["ok"] for b in rep["backends"].values()):
        sys.exit(1)

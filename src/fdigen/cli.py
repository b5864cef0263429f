"""The ``fdigen`` command line: a thin layer over the pipeline functions.

Errors fdigen knows about print one line naming the problem and exit with status 2;
nothing prints a traceback unless ``FDIGEN_DEBUG=1``.
"""

from __future__ import annotations

import json
import os
import sys

import click

from fdigen.errors import FdigenError


def _fail(message: str, code: int = 2):
    click.echo(f"fdigen: error: {message}", err=True)
    sys.exit(code)


class _Group(click.Group):
    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except FdigenError as exc:
            _fail(str(exc))
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except Exception as exc:  # an fdigen bug: say so without a traceback
            if os.environ.get("FDIGEN_DEBUG"):
                raise
            _fail(f"internal error ({type(exc).__name__}: {exc}); "
                  "rerun with FDIGEN_DEBUG=1 for details", 3)


@click.group(cls=_Group)
@click.version_option(package_name="fdigen")
def main():
    """fdigen: symbolic model-to-code generator for fault detection and isolation."""


@main.command()
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


@main.command()
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


@main.command()
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--backend", "backends", multiple=True,
              type=click.Choice(["casadi_sx", "casadi_compiled", "c"]),
              help="Backends to compare with the reference [default: all].")
@click.option("--points", default=1000, show_default=True, help="Random points.")
@click.option("--duration", default=20.0, show_default=True,
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


@main.command()
@click.argument("log", type=click.Path(dir_okay=False))
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--backend", default="auto", show_default=True,
              type=click.Choice(["auto", "c", "casadi", "reference"]))
@click.option("--json", "as_json", is_flag=True, help="Print the decision as JSON.")
def detect(log, model, backend, as_json):
    """Run the FDI core over LOG (rig CSV format) and report flags and diagnosis."""
    from fdigen.design.cache import cached_design
    from fdigen.detect import detect_log
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    design = cached_design(load_model(resolve_model_path(model)))
    summary, _ = detect_log(design, log, backend)
    if as_json:
        click.echo(json.dumps(summary, indent=1))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{log}: {summary['samples']} samples at {summary['sample_time']:g} s")
    table.add_column("residual")
    table.add_column("flag raised at [s]", justify="right")
    for f in summary["flags"]:
        table.add_row(f["residual"], f"{f['t_raised']:.3f}")
    con = Console()
    con.print(table)
    d = summary["diagnosis"]
    when = "" if d["t_isolated"] is None else f" at {d['t_isolated']:.3f} s"
    con.print(f"diagnosis: {d['fault']}{when}, action: {d['action']}"
              + (f" (candidates: {', '.join(d['candidates'])})" if d["candidates"] else ""))


def _parse_fault(text: str):
    """``name@t0=size`` or ``name@t0=size/s`` (a ramp: size per second)."""
    from fdigen.sim.plant import FaultEvent

    try:
        name, rest = text.split("@", 1)
        t0, size = rest.split("=", 1)
        ramp = size.endswith("/s")
        return FaultEvent(name.strip(), float(t0), float(size[:-2] if ramp else size), ramp)
    except ValueError:
        raise click.BadParameter(f"expected NAME@T0=SIZE or NAME@T0=RATE/s, got {text!r}")


@main.command()
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--duration", default=20.0, show_default=True, help="Seconds.")
@click.option("--fault", "faults", multiple=True,
              help="Fault to inject: NAME@T0=SIZE, or NAME@T0=RATE/s for a drift.")
@click.option("--seed", default=0, show_default=True)
@click.option("--no-noise", is_flag=True, help="Noise-free sensors.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Log file to write (CSV); the ground truth goes beside it as .json.")
def simulate(model, duration, faults, seed, no_noise, output):
    """Simulate the closed loop and write a log in the rig format, with ground truth."""
    from pathlib import Path

    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.sim.log import write_log
    from fdigen.sim.plant import simulate as run_sim

    m = load_model(resolve_model_path(model))
    events = [_parse_fault(f) for f in faults]
    sim = run_sim(m, duration, faults=events, seed=seed, noise=not no_noise)
    write_log(output, sim.columns())
    truth = {"case": Path(output).stem, "sample_time": float(sim.t[1] - sim.t[0]),
             "model": m.name, "seed": seed, "noise": not no_noise,
             "truth": {"parameters": {q.name: q.value for q in m.parameters},
                       "faults": [{"kind": e.name, "t0": e.t0, "size": e.size, "ramp": e.ramp}
                                  for e in events]}}
    Path(output).with_suffix(".json").write_text(json.dumps(truth, indent=1) + "\n")
    click.echo(f"wrote {len(sim.t)} samples to {output}")


if __name__ == "__main__":  # pragma: no cover
    main()

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


# -- the platform's shared pieces (used by `simulate/detect/report --platform` and by the
# -- `platform` group) -------------------------------------------------------------------------
def _platform_geometry(path):
    from pathlib import Path

    from fdigen.platform.geometry import PlatformGeometry, default_geometry

    if path is None:
        return default_geometry()
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise FdigenError(f"{path}: cannot read the geometry JSON ({exc})") from None
    if not isinstance(data, dict):
        raise FdigenError(f"{path}: the geometry JSON must be an object")
    return PlatformGeometry.from_dict(data.get("geometry", data))


def _parse_pose(text: str, degrees: bool):
    import numpy as np

    from fdigen.platform.geometry import DOF_NAMES

    try:
        q = [float(v) for v in text.replace(";", ",").split(",")]
    except ValueError:
        q = []
    if len(q) != 6 or not all(np.isfinite(q)):
        raise FdigenError(f"--pose: expected 6 numbers '{','.join(DOF_NAMES)}', got {text!r}")
    if degrees:
        q[3:] = [float(np.radians(v)) for v in q[3:]]
    return np.array(q)


_GEOMETRY_OPTION = click.option(
    "--geometry", "geometry", default=None, type=click.Path(dir_okay=False),
    help="Platform geometry JSON (keys of `fdigen platform ik --json`'s geometry) "
         "[default: the built-in 6-6 platform, stroke 0.2 m].")
_SAFETY_OPTION = click.option("--safety-duration", "safety_duration", default=3.0,
                              show_default=True, help="Seconds of the safety sequence.")
_BANK_OPTION = click.option(
    "--bank", default="c", show_default=True, type=click.Choice(["c", "python", "none"]),
    help="Platform: FDI bank and supervisor in the loop: the generated C, the Python "
         "reference, or none (open loop, motion demands throughout).")
_SEGMENT_OPTION = click.option("--segment", default=6.0, show_default=True,
                               help="Platform: seconds per degree of freedom of the motion "
                                    "sequence.")
_PER_LEG_OPTION = click.option("--per-leg/--no-per-leg", default=True, show_default=True,
                               help="Platform: also write each leg's residual report.")


def _platform_flag(what: str):
    return click.option("--platform", "platform_run", is_flag=True, help=what)


def _platform_only(ctx, platform_run: bool, names) -> None:
    """Refuse platform options given without ``--platform`` (a usage error, exit 2)."""
    from click.core import ParameterSource

    if platform_run:
        return
    opts = {p.name: "/".join(p.opts + p.secondary_opts) for p in ctx.command.params}
    given = [opts[n] for n in names if ctx.get_parameter_source(n) is not ParameterSource.DEFAULT]
    if given:
        raise click.UsageError(f"{', '.join(given)}: only with --platform")


def _run_platform_simulate(output, faults, model, duration, segment, seed, no_noise, bank,
                           geometry, safety_duration):
    from pathlib import Path

    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.platform.demands import MotionSequence
    from fdigen.platform.simulate import (parse_leg_fault, simulate_platform,
                                          write_platform_logs)
    from fdigen.platform.supervisor import PlatformFdi, platform_summary

    if Path(output).exists() and not Path(output).is_dir():
        _fail(f"{output}: is a file; a platform run is written to a folder "
              "(leg1.csv..leg6.csv, pose_demand.csv, truth.json)")
    m = load_model(resolve_model_path(model))
    geo = _platform_geometry(geometry)
    events = [parse_leg_fault(f) for f in faults]
    motion = MotionSequence(segment=segment)
    fdi = None
    design = None
    if bank != "none":
        design = cached_design(m)
        if bank == "c":
            from fdigen.platform.codegen import PlatformCFdi
            fdi = PlatformCFdi(design, geo, safety_duration)
        else:
            fdi = PlatformFdi(design, geo, safety_duration)
    run = simulate_platform(m, duration, geometry=geo, motion=motion, faults=events,
                            seed=seed, noise=not no_noise, bank=fdi)
    summary = None
    if run.bank is not None:
        summary = platform_summary(design, run.t, run.bank)["platform"]
        summary["bank"] = bank
    write_platform_logs(run, output, summary)
    click.echo(f"wrote 6 legs x {len(run.t)} samples to {output}"
               + (f"; online decision: {summary['text']}" if summary else ""))


def _run_platform_detect(folder, model, backend, geometry, safety_duration, as_json):
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.platform.supervisor import detect_platform

    design = cached_design(load_model(resolve_model_path(model)))
    summary, _ = detect_platform(design, folder, geometry=_platform_geometry(geometry),
                                 backend=backend, safety_duration=safety_duration)
    if as_json:
        click.echo(json.dumps(summary, indent=1))
        return
    for leg in summary["legs"]:
        fdi = leg["fdi"]
        flags = ", ".join(f"{f['residual']}@{f['t_raised']:.3f}" for f in fdi["flags"]) or "-"
        when = "" if leg["t_isolated"] is None else f" at {leg['t_isolated']:.3f} s"
        click.echo(f"leg {leg['leg']}: {leg['fault_class']}{when}, action {leg['action']}; "
                   f"flags {flags}")
    click.echo(f"platform: {summary['platform']['text']}")


def _run_platform_report(folder, output, model, backend, per_leg, geometry, safety_duration):
    from pathlib import Path

    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.platform.supervisor import detect_platform, platform_figure

    out = Path(output)
    if out.suffix.lower() != ".png":
        _fail(f"{output}: the platform overview is a .png figure")
    if not out.resolve().parent.is_dir():
        _fail(f"{output}: cannot write report (no folder {out.resolve().parent})")
    design = cached_design(load_model(resolve_model_path(model)))
    summary, raw = detect_platform(design, folder, geometry=_platform_geometry(geometry),
                                   backend=backend, safety_duration=safety_duration)
    fig = platform_figure(design, raw, summary)
    try:
        from fdigen.report import png_bytes
        out.write_bytes(png_bytes(fig))
    except ImportError:
        fig.savefig(out, format="png", metadata={"Software": None})
    written = [str(out)]
    if per_leg:
        try:
            from fdigen.report import render_report
        except ImportError:
            render_report = None
        if render_report is not None:
            for i in range(1, 7):
                leg_out = out.with_name(f"{out.stem}_leg{i}.png")
                render_report(design, Path(folder) / f"leg{i}.csv", leg_out, backend)
                written.append(str(leg_out))
    click.echo(f"wrote {', '.join(written)}: {summary['platform']['text']}")


def _not_a_folder(path: str) -> None:
    from pathlib import Path

    if Path(path).is_dir():
        _fail(f"{path}: is a folder; a platform run's folder of leg logs needs --platform")


@main.command()
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
    """Run the FDI core over LOG (rig CSV format) and report flags and diagnosis.

    With --platform, LOG is a folder of six leg logs: each leg's decision (class, time,
    action, flags) and the platform's (which leg, which class, safety sequence or not).
    """
    _platform_only(ctx, platform_run, ("geometry", "safety_duration"))
    if platform_run:
        _run_platform_detect(log, model, backend, geometry, safety_duration, as_json)
        return
    _not_a_folder(log)
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


def _parse_effect(text: str, model):
    """``NAME=VALUE``: a library effect (fdigen.discover.effects) and its parameter value."""
    from fdigen.discover.effects import get_effect

    name, sep, value = text.partition("=")
    try:
        size = float(value)
    except ValueError:
        raise click.BadParameter(f"expected NAME=VALUE, got {text!r}", param_hint="--effect")
    if not sep:
        raise click.BadParameter(f"expected NAME=VALUE, got {text!r}", param_hint="--effect")
    eff = get_effect(name.strip(), model)
    return eff, {eff.parameter_names[0]: size}


def _parse_fault(text: str):
    """``name@t0=size``, ``name@t0=size/s`` (a ramp: size per second) or
    ``name@t0=stuck`` (a sensor holding its last value)."""
    from fdigen.sim.plant import FaultEvent

    try:
        name, rest = text.split("@", 1)
        t0, size = rest.split("=", 1)
        if size.strip() == "stuck":
            return FaultEvent(name.strip(), float(t0), 0.0, stuck=True)
        ramp = size.endswith("/s")
        return FaultEvent(name.strip(), float(t0), float(size[:-2] if ramp else size), ramp)
    except ValueError:
        raise click.BadParameter(f"expected NAME@T0=SIZE or NAME@T0=RATE/s, got {text!r}")


@main.command()
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--duration", default=None, type=float,
              help="Seconds [default: 20; with --platform one pass of the motion sequence].")
@click.option("--fault", "faults", multiple=True,
              help="Fault to inject: NAME@T0=SIZE, or NAME@T0=RATE/s for a drift; with "
                   "--platform LEG:NAME@T0=SIZE (LEG 1..6, also =RATE/s and =stuck).")
@click.option("--effect", "effects", multiple=True,
              help="Library effect the nominal model lacks, switched on in the plant: "
                   "NAME=VALUE (e.g. coulomb_friction=35); repeatable (not with --platform).")
@click.option("--seed", default=0, show_default=True)
@click.option("--no-noise", is_flag=True, help="Noise-free sensors.")
@click.option("-o", "--output", required=True, type=click.Path(),
              help="Log file to write (CSV); the ground truth goes beside it as .json. With "
                   "--platform a folder: leg1.csv..leg6.csv, pose_demand.csv, truth.json.")
@_platform_flag("Simulate the six-leg Stewart-Gough platform through the paper's motion "
                "sequence, with the FDI bank and supervisor in the loop: one log per leg "
                "plus the pose demand.")
@_BANK_OPTION
@_SEGMENT_OPTION
@_GEOMETRY_OPTION
@_SAFETY_OPTION
@click.pass_context
def simulate(ctx, model, duration, faults, effects, seed, no_noise, output, platform_run, bank,
             segment, geometry, safety_duration):
    """Simulate the closed loop and write a log in the rig format, with ground truth."""
    _platform_only(ctx, platform_run, ("bank", "segment", "geometry", "safety_duration"))
    if platform_run:
        if effects:
            raise click.UsageError("--effect: not with --platform (the platform's legs are "
                                   "the model as written)")
        _run_platform_simulate(output, faults, model, duration, segment, seed, no_noise, bank,
                               geometry, safety_duration)
        return
    from pathlib import Path

    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.sim.log import write_log
    from fdigen.sim.plant import simulate as run_sim

    if Path(output).is_dir():
        _fail(f"{output}: is a folder; a single-cylinder log is a CSV file (--platform "
              "writes a folder of leg logs)")
    duration = 20.0 if duration is None else duration
    m = load_model(resolve_model_path(model))
    events = [_parse_fault(f) for f in faults]
    switched = [_parse_effect(e, m) for e in effects]
    plant_effects = tuple(pe for eff, values in switched
                          for pe in eff.plant_effects(m, values))
    sim = run_sim(m, duration, faults=events, effects=plant_effects, seed=seed,
                  noise=not no_noise)
    write_log(output, sim.columns())
    truth = {"case": Path(output).stem, "sample_time": float(sim.t[1] - sim.t[0]),
             "model": m.name, "seed": seed, "noise": not no_noise,
             "truth": {"parameters": {q.name: q.value for q in m.parameters},
                       "faults": [{"kind": e.name, "t0": e.t0, "size": e.size, "ramp": e.ramp,
                                   "stuck": e.stuck}
                                  for e in events],
                       "effects": [{"effect": eff.name, "parameters": values}
                                   for eff, values in switched]}}
    Path(output).with_suffix(".json").write_text(json.dumps(truth, indent=1) + "\n")
    click.echo(f"wrote {len(sim.t)} samples to {output}")


@main.command()
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--runs", default=40, show_default=True, help="Healthy Monte Carlo runs.")
@click.option("--duration", default=10.0, show_default=True,
              help="Seconds per run (the false-alarm rate is per run of this length).")
@click.option("--false-alarm-rate", "false_alarm_rate", default=0.01, show_default=True,
              help="Target probability that a healthy run raises any flag.")
@click.option("--margin", default=1.25, show_default=True,
              help="Safety factor on the fitted quantile.")
@click.option("--tolerance", default=0.10, show_default=True,
              help="Relative spread of the uncertain parameters (uniform, +-).")
@click.option("--validation-runs", "validation_runs", default=10, show_default=True,
              help="Fresh healthy runs checked with the tuned core.")
@click.option("--fault-sizes", "fault_sizes", default="0.25,0.5,1,2", show_default=True,
              help="Fault sizes relative to each fault's test_size (comma separated).")
@click.option("--fault-starts", "fault_starts", default=2, show_default=True,
              help="Onset times per fault and size.")
@click.option("--keep", default="",
              help="Residuals whose thresholds stay as in the model file (comma separated).")
@click.option("--seed", default=0, show_default=True, help="Master seed.")
@click.option("--workers", default=2, show_default=True,
              help="Local Dask worker processes (one thread each).")
@click.option("--scheduler", default=None,
              help="Address of a running Dask scheduler, or 'synchronous' (in-process).")
@click.option("--write", is_flag=True,
              help="Write the tuned thresholds into the model file's [fdi.thresholds].")
@click.option("--report", "report", default=None, type=click.Path(dir_okay=False),
              help="Write the full report (all numbers, per run) as JSON.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
def tune(model, runs, duration, false_alarm_rate, margin, tolerance, validation_runs,
         fault_sizes, fault_starts, keep, seed, workers, scheduler, write, report, as_json):
    """Design the residual thresholds by Monte Carlo for a target false-alarm rate.

    Healthy runs (noise, demand and +-tolerance parameter spread) give each residual's
    per-run maximum RMS; a Gumbel/GEV fit gives the quantile for the false-alarm rate,
    times the margin. The design is then rebuilt with those thresholds and checked on
    fresh healthy runs and on every fault over a range of sizes (detection and isolation
    delays). Without --write the TOML snippet and the diff --write would apply are
    printed. The defaults (1.16e6 simulated samples) took 4.5-9 minutes on a shared,
    loaded 2-core machine (about 2 minutes on 2 idle cores); a full campaign (--runs 500
    --duration 20, 1.15e7 samples) takes 10-15 minutes on 2 idle cores, 45-90 loaded.
    """
    from pathlib import Path

    from fdigen.pipeline import resolve_model_path
    from fdigen.tune import TuneSettings, thresholds_snippet, tune as run_tune, write_thresholds

    try:
        factors = tuple(float(v) for v in fault_sizes.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"expected numbers separated by commas, got {fault_sizes!r}",
                                 param_hint="--fault-sizes")
    settings = TuneSettings(runs=runs, duration=duration, false_alarm_rate=false_alarm_rate,
                            margin=margin, tolerance=tolerance,
                            validation_runs=validation_runs, fault_factors=factors,
                            fault_starts=fault_starts, seed=seed,
                            keep=tuple(k.strip() for k in keep.split(",") if k.strip()))
    log = (lambda msg: None) if as_json else (lambda msg: click.echo(msg, err=True))
    rep = run_tune(model, settings, workers=workers, scheduler=scheduler,
                   progress=not as_json, log=log)
    path = resolve_model_path(model)
    diff = write_thresholds(path, rep["thresholds"], rep["threshold_text"], dry_run=not write)
    rep["written"] = bool(write)
    rep["diff"] = diff
    if report:
        Path(report).write_text(json.dumps(rep, indent=1, default=float) + "\n")
    if as_json:
        click.echo(json.dumps(rep, indent=1, default=float))
        return
    _print_tune(rep)
    if write:
        click.echo(f"wrote the tuned thresholds to {path}; `fdigen build` puts them into "
                   "the generated code")
    else:
        click.echo(thresholds_snippet(rep["thresholds"], rep["current_thresholds"],
                                      rep["threshold_text"]))
        click.echo(f"--write would change {path}:" if diff else "--write would change nothing")
        click.echo(diff, nl=False)
    if report:
        click.echo(f"report written to {report}")


def _print_tune(rep):
    from rich.console import Console
    from rich.table import Table

    def g(v, fmt=".3g"):
        return "-" if v is None else format(v, fmt)

    con = Console()
    st = rep["threshold_statistics"]
    s = rep["settings"]
    table = Table(title=f"{rep['model']}: thresholds from {st['runs']} healthy runs of "
                        f"{s['duration']:g} s (alpha {s['false_alarm_rate']:g}/run, "
                        f"{st['alpha_per_residual']:.2g}/residual, margin {st['margin']:g})")
    for col in ("residual", "current", "healthy max", "empirical q", "Gumbel q", "GEV q (xi)",
                "basis", "tuned", "x current"):
        table.add_column(col, justify="left" if col in ("residual", "basis") else "right")
    for name in rep["residuals"]:
        f = st["residuals"][name]
        gev = f.get("gev")
        table.add_row(name, g(f["current"]), g(f["empirical_max"]), g(f["empirical_quantile"]),
                      g((f.get("gumbel") or {}).get("quantile")),
                      "-" if not gev else f"{gev['quantile']:.3g} ({gev['xi']:+.2f})",
                      f["basis"], rep["threshold_text"][name], g(f["ratio_to_current"], ".2f"))
    con.print(table)
    fa = rep["false_alarm"]
    con.print(f"false alarms per {fa['run_duration']:g} s run: target {fa['target_per_run']:g}; "
              f"fitted {g(fa['fitted'])} ({fa['basis']}); validation "
              f"{fa['validation_false_alarms']}/{fa['validation_runs']} (95 % upper bound "
              f"{fa['validation_upper_95']:.2g}); healthy runs exceeding the current "
              f"thresholds: {fa['healthy_runs_current_thresholds_exceeded']}/{st['runs']}")
    ft = Table(title="Fault campaign with the tuned thresholds (delays in s: median \\[max])")
    for col in ("fault", "sizes", "runs", "detected", "missed", "detection delay",
                "isolated ok", "false iso.", "not iso.", "isolation delay", "FA before",
                "off-signature before isolation"):
        ft.add_column(col, justify="left" if col in ("fault", "off-signature before "
                                                      "isolation") else "right")
    for name, f in rep["faults"].items():
        dd, idl = f["detection_delay"], f["isolation_delay"]
        sizes = ", ".join(f"{b['size']:.3g}" for b in f["by_size"]) + ("/s" if f["ramp"] else "")
        ft.add_row(name, sizes, str(f["runs"]), str(f["detected"]), str(f["missed"]),
                   "-" if not dd["n"] else f"{dd['median']:.3f} [{dd['max']:.3f}]",
                   str(f["isolated_correct"]), str(f["false_isolations"]),
                   str(f["not_isolated"]),
                   "-" if not idl["n"] else f"{idl['median']:.3f} [{idl['max']:.3f}]",
                   str(f["false_alarms_before_onset"]),
                   ", ".join(f"{r} ({n})" for r, n in
                             f["off_signature_before_isolation"].items()) or "-")
    con.print(ft)
    for name in rep["residuals"]:
        f = st["residuals"][name]
        if f.get("warning") or f.get("note"):
            con.print(f"{name}: {f.get('note') or ''} {f.get('warning') or ''}".strip())
    t = rep["timing"]
    con.print(f"{rep['executor']}: {t['samples']} samples in {t['total']:.0f} s "
              f"({g(t['samples_per_second_per_core'], '.3g')} simulated samples/s per core)")


@main.command()
@click.argument("log", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Report to write: a .png figure or a self-contained .html page (with "
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
@click.pass_context
def report(ctx, log, output, model, backend, platform_run, per_leg, geometry, safety_duration):
    """Draw the moving RMS of each residual on LOG against its threshold (paper Figs 6-7)."""
    _platform_only(ctx, platform_run, ("per_leg", "geometry", "safety_duration"))
    if platform_run:
        _run_platform_report(log, output, model, backend, per_leg, geometry, safety_duration)
        return
    _not_a_folder(log)
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.report import diagnosis_text, output_format, render_report

    output_format(output)  # fail on a bad suffix before deriving anything
    design = cached_design(load_model(resolve_model_path(model)))
    summary = render_report(design, log, output, backend)
    click.echo(f"wrote {output}: {diagnosis_text(summary)}")


@main.command()
@click.option("-o", "--output", default=None, type=click.Path(dir_okay=False),
              help="Markdown file to write (e.g. EXPERIMENTS.md) [default: print it].")
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
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
        click.echo(text, nl=False)
        return
    try:
        Path(output).write_text(text)
    except OSError as exc:
        _fail(f"{output}: cannot write ({exc.strerror or exc})")
    ok = sum(o.correct for o in outcomes + (rig or []))
    click.echo(f"wrote {output}: {ok} of {len(outcomes) + len(rig or [])} runs diagnosed "
               "correctly")


# -- the Stewart-Gough platform: six legs, one FDI bank, supervisory safety ------------------
@main.group()
def platform():
    """The Stewart-Gough platform: six legs, one FDI bank, supervisory safety.

    Every leg is the single-cylinder model with its own FDI; a supervisor accommodates a
    sensor fault on its leg and takes the platform to its rest pose on a pneumatic or
    actuator fault, naming the leg.
    """


@platform.command("ik")
@click.option("--pose", required=True,
              help="surge,sway,heave,roll,pitch,yaw relative to home (m, rad).")
@click.option("--degrees", is_flag=True, help="Angles of --pose in degrees.")
@_GEOMETRY_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def platform_ik(pose, degrees, geometry, as_json):
    """Inverse kinematics: leg lengths and piston positions of a pose (exit 2 if out of reach)."""
    from fdigen.platform.geometry import DOF_NAMES, ROTATION_CONVENTION

    geo = _platform_geometry(geometry)
    q = _parse_pose(pose, degrees)
    x = geo.check_reachable(q)
    lengths = geo.leg_lengths(q)
    if as_json:
        click.echo(json.dumps({"pose": dict(zip(DOF_NAMES, q.tolist())),
                               "geometry": geo.to_dict(),
                               "leg_lengths": lengths.tolist(),
                               "piston_positions": x.tolist(),
                               "stroke_use_percent": (x / geo.stroke * 100).tolist()},
                              indent=1))
        return
    click.echo(f"pose relative to home; {ROTATION_CONVENTION}")
    click.echo("leg  base joint a_i [m]           top joint b_i [m]            "
               "length [m]  piston [mm]")
    for i in range(6):
        a, b = geo.base[i], geo.top[i]
        click.echo(f"{i + 1:3d}  ({a[0]:+.4f}, {a[1]:+.4f}, {a[2]:+.4f})  "
                   f"({b[0]:+.4f}, {b[1]:+.4f}, {b[2]:+.4f})  {lengths[i]:10.5f}  "
                   f"{x[i] * 1e3:10.2f}")
    click.echo(f"stroke 0..{geo.stroke * 1e3:.0f} mm, l_min {geo.l_min} m, "
               f"home height {geo.home_height:.5f} m")


@platform.command("simulate")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              help="Folder to write leg1.csv..leg6.csv, pose_demand.csv and truth.json to.")
@click.option("--fault", "faults", multiple=True,
              help="Fault on a leg: LEG:NAME@T0=SIZE, LEG:NAME@T0=RATE/s or "
                   "LEG:NAME@T0=stuck (LEG 1..6).")
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--duration", default=None, type=float,
              help="Seconds [default: one pass of the motion sequence].")
@_SEGMENT_OPTION
@click.option("--seed", default=0, show_default=True)
@click.option("--no-noise", is_flag=True, help="Noise-free sensors.")
@_BANK_OPTION
@_GEOMETRY_OPTION
@_SAFETY_OPTION
def platform_simulate(output, faults, model, duration, segment, seed, no_noise, bank,
                      geometry, safety_duration):
    """Simulate the six legs through the paper's motion sequence, with faults on any leg
    (the same as `fdigen simulate --platform`)."""
    _run_platform_simulate(output, faults, model, duration, segment, seed, no_noise, bank,
                           geometry, safety_duration)


@platform.command("detect")
@click.argument("folder", type=click.Path(file_okay=False))
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--backend", default="auto", show_default=True,
              type=click.Choice(["auto", "c", "casadi", "reference"]))
@_GEOMETRY_OPTION
@_SAFETY_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print the decision as JSON.")
def platform_detect(folder, model, backend, geometry, safety_duration, as_json):
    """Run the FDI of every leg over FOLDER's leg logs and the supervisor over them
    (the same as `fdigen detect --platform`)."""
    _run_platform_detect(folder, model, backend, geometry, safety_duration, as_json)


@platform.command("report")
@click.argument("folder", type=click.Path(file_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Overview figure (.png) of the six legs' decisions; each leg's residual "
                   "report goes beside it as <name>_leg<i>.png.")
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--backend", default="auto", show_default=True,
              type=click.Choice(["auto", "c", "casadi", "reference"]))
@_PER_LEG_OPTION
@_GEOMETRY_OPTION
@_SAFETY_OPTION
def platform_report(folder, output, model, backend, per_leg, geometry, safety_duration):
    """Draw the six legs' demands, positions and decisions, and each leg's residuals
    (the same as `fdigen report --platform`)."""
    _run_platform_report(folder, output, model, backend, per_leg, geometry, safety_duration)


@platform.command("build")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              help="Folder for <model>_fdi.{h,c} and <model>_platform_fdi.{h,c}.")
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--float-type", "float_type", default="double", show_default=True,
              type=click.Choice(["double", "float"]))
@_GEOMETRY_OPTION
@_SAFETY_OPTION
def platform_build(output, model, float_type, geometry, safety_duration):
    """Generate the C99 platform bank: <model>_platform_step() over the six legs."""
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.platform.codegen import write_platform_sources

    design = cached_design(load_model(resolve_model_path(model)))
    files = write_platform_sources(design, output, geometry=_platform_geometry(geometry),
                                   safety_duration=safety_duration, float_type=float_type)
    click.echo(f"wrote {len(files)} files to {output}: " + ", ".join(f.name for f in files))


@main.command()
@click.argument("log", type=click.Path(dir_okay=False))
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--out", "out", default=None, type=click.Path(file_okay=False),
              help="Folder for the augmented model, its generated code, discover.png and "
                   "discover.json [default: ./discovered/<log name>].")
@click.option("--fraction", default=0.6, show_default=True,
              help="Share of the log that calibrates; the rest validates.")
@click.option("--alpha", default=1e-3, show_default=True, help="Significance of the tests.")
@click.option("--max-effects", "max_effects", default=2, show_default=True,
              help="At most this many effects.")
@click.option("--reinit", default=1.0, show_default=True,
              help="Re-initialisation period [s] of the output-error simulation.")
@click.option("--no-build", "no_build", is_flag=True,
              help="Write the augmented model file but do not rebuild its code.")
@click.option("--no-fdi", "no_fdi", is_flag=True,
              help="Do not run the FDI cores (original and augmented) over the log.")
@click.option("--backend", default="auto", show_default=True,
              type=click.Choice(["auto", "c", "casadi", "reference"]))
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def discover(log, model, out, fraction, alpha, max_effects, reinit, no_build, no_fdi,
             backend, as_json):
    """Find the effect LOG shows and the model lacks, add it, report errors before/after.

    Calibrates the uncertain parameters on the first part of LOG (equation error),
    locates the model equation whose error holds structure beyond noise, picks the library
    effect explaining it (BIC, checked on the held-back part), writes the augmented model
    file and rebuilds its code, and reports output error and FDI residuals before and
    after. See docs/discover.md.
    """
    from pathlib import Path

    from fdigen.discover.pipeline import DiscoverSettings, discover as run_discover
    from fdigen.discover.report import text_report

    if out is None:
        out = Path("discovered") / Path(log).stem
    settings = DiscoverSettings(fraction=fraction, alpha=alpha, max_effects=max_effects,
                                reinit=reinit)
    progress = None if as_json else (lambda msg: click.echo(msg, err=True))
    res = run_discover(log, model, out=out, settings=settings, build=not no_build,
                       fdi=not no_fdi, backend=backend, progress=progress)
    if as_json:
        click.echo(json.dumps(res.as_dict(), indent=1))
        return
    click.echo(text_report(res.as_dict()))


if __name__ == "__main__":  # pragma: no cover
    main()

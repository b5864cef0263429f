"""The platform's shared command-line pieces.

Used both by ``fdigen simulate/detect/report --platform`` and by the ``fdigen platform``
group: the reusable click options (``_GEOMETRY_OPTION``, ``_SAFETY_OPTION``,
``_BANK_OPTION``, ``_SEGMENT_OPTION``, ``_PER_LEG_OPTION``, ``_platform_flag``), the checks
``_platform_only`` and ``_not_a_folder``, the geometry loader ``_platform_geometry`` and
the three runners ``_run_platform_simulate``, ``_run_platform_detect`` and
``_run_platform_report``.
"""

from __future__ import annotations

import json

import click

from fdigen.cli.errors import _fail, echo
from fdigen.cli.types import POSITIVE_SECONDS
from fdigen.errors import FdigenError
from fdigen.files.atomic import atomic_path, write_bytes


def _platform_geometry(path):
    from pathlib import Path

    from fdigen.platform.geometry import PlatformGeometry, default_geometry

    if path is None:
        return default_geometry()
    from fdigen.files.bounded import read_bytes

    raw = read_bytes(path, 1 << 20, what="the geometry JSON")   # regular files only
    try:
        data = json.loads(raw.decode("utf-8"))
    except ValueError as exc:
        raise FdigenError(f"{path}: cannot read the geometry JSON ({exc})") from None
    except RecursionError:
        raise FdigenError(f"{path}: cannot read the geometry JSON (nested too deeply)") \
            from None
    if not isinstance(data, dict):
        raise FdigenError(f"{path}: the geometry JSON must be an object")
    return PlatformGeometry.from_dict(data.get("geometry", data))



_GEOMETRY_OPTION = click.option(
    "--geometry", "geometry", default=None, type=click.Path(dir_okay=False),
    help="Platform geometry JSON (keys of `fdigen platform ik --json`'s geometry) "
         "[default: the built-in 6-6 platform, stroke 0.2 m].")
_SAFETY_OPTION = click.option("--safety-duration", "safety_duration", default=3.0,
                              show_default=True, type=POSITIVE_SECONDS,
                              help="Seconds of the safety sequence (at least one sample "
                                   "time).")
_BANK_OPTION = click.option(
    "--bank", default="c", show_default=True, type=click.Choice(["c", "python", "none"]),
    help="Platform: FDI bank and supervisor in the loop: the generated C, the Python "
         "reference, or none (open loop, motion demands throughout).")
_SEGMENT_OPTION = click.option("--segment", default=6.0, show_default=True, type=POSITIVE_SECONDS,
                               help="Platform: seconds per degree of freedom of the motion "
                                    "sequence.")
_FORCE_OPTION = click.option("--force", is_flag=True,
                             help="Overwrite files beside the output (the ground truth, "
                                  "a platform run's logs) that fdigen did not write.")
#: The files of a platform run folder (``fdigen platform simulate``).
PLATFORM_RUN_FILES = tuple(f"leg{i}.csv" for i in range(1, 7)) + ("pose_demand.csv",
                                                                   "truth.json")
_PER_LEG_OPTION = click.option("--per-leg/--no-per-leg", default=True, show_default=True,
                               help="Platform: also write each leg's residual report.")


def _check_safety(model, safety_duration, float_type: str = "double") -> float:
    """``--safety-duration`` checked against the model's sample time and the real type
    (:func:`fdigen.platform.supervisor.check_safety_duration`): a usage error naming the
    option (exit 2), before any long work."""
    from fdigen.platform.simulate import sample_time_of
    from fdigen.platform.supervisor import check_safety_duration

    try:
        return check_safety_duration(safety_duration, sample_time_of(model), float_type)
    except FdigenError as exc:
        raise click.BadParameter(str(exc), param_hint="'--safety-duration'") from None


def _print_json(doc) -> None:
    """Strict JSON on stdout: a NaN or infinite number is ``null``, never ``NaN``."""
    from fdigen.platform.supervisor import finite_json

    echo(json.dumps(finite_json(doc), indent=1, allow_nan=False))


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
                           geometry, safety_duration, force=False):
    from pathlib import Path

    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.platform.demands import MotionSequence
    from fdigen.platform.simulate import (RunLengthError, check_run_folder, parse_leg_fault,
                                          run_samples, simulate_platform,
                                          write_platform_logs)
    from fdigen.platform.supervisor import PlatformFdi, platform_summary

    if Path(output).exists() and not Path(output).is_dir():
        _fail(f"{output}: is a file; a platform run is written to a folder "
              "(leg1.csv..leg6.csv, pose_demand.csv, truth.json)")
    try:
        events = [parse_leg_fault(f) for f in faults]
    except FdigenError as exc:
        raise click.BadParameter(str(exc), param_hint="--fault") from None
    try:
        motion = MotionSequence(segment=segment)
    except FdigenError as exc:
        raise click.BadParameter(str(exc), param_hint="'--segment'") from None
    from fdigen.files.outputs import check_output_folder

    check_output_folder(output, "-o")
    # the run replaces the whole folder: only an earlier run's files may be there
    check_run_folder(output, "-o", force)
    m = load_model(resolve_model_path(model))
    try:    # at most MAX_SAMPLES, before any array is made (a MemoryError, exit 3)
        run_samples(m, duration, motion)
    except RunLengthError as exc:
        raise click.BadParameter(str(exc), param_hint=f"'--{exc.option}'") from None
    if bank != "none":
        _check_safety(m, safety_duration)
    geo = _platform_geometry(geometry)
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
    write_platform_logs(run, output, summary, force=force)
    echo(f"wrote 6 legs x {len(run.t)} samples to {output}"
         + (f"; online decision: {summary['text']}" if summary else ""))


def _run_platform_detect(folder, model, backend, geometry, safety_duration, as_json):
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.platform.supervisor import detect_platform

    m = load_model(resolve_model_path(model))
    _check_safety(m, safety_duration)
    design = cached_design(m)
    summary, _ = detect_platform(design, folder, geometry=_platform_geometry(geometry),
                                 backend=backend, safety_duration=safety_duration)
    if as_json:
        _print_json(summary)
        return
    for leg in summary["legs"]:
        fdi = leg["fdi"]
        flags = ", ".join(f"{f['residual']}@{f['t_raised']:.3f}" for f in fdi["flags"]) or "-"
        when = "" if leg["t_isolated"] is None else f" at {leg['t_isolated']:.3f} s"
        echo(f"leg {leg['leg']}: {leg['fault_class']}{when}, action {leg['action']}; "
             f"flags {flags}")
    echo(f"platform: {summary['platform']['text']}")


def _run_platform_report(folder, output, model, backend, per_leg, geometry, safety_duration,
                         force=False):
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
    from fdigen.files.outputs import check_output_file

    check_output_file(out, "-o")
    if per_leg:   # the legs' figures beside it: never a file fdigen did not write
        from fdigen.files.outputs import check_figure_sidecars

        check_figure_sidecars([out.with_name(f"{out.stem}_leg{i}.png") for i in range(1, 7)],
                              "-o", force)
    m = load_model(resolve_model_path(model))
    _check_safety(m, safety_duration)
    design = cached_design(m)
    summary, raw = detect_platform(design, folder, geometry=_platform_geometry(geometry),
                                   backend=backend, safety_duration=safety_duration)
    fig = platform_figure(design, raw, summary)
    try:
        from fdigen.report import png_bytes
        write_bytes(out, png_bytes(fig))
    except ImportError:
        with atomic_path(out) as tmp:
            fig.savefig(tmp, format="png", metadata={"Software": None})
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
    echo(f"wrote {', '.join(written)}: {summary['platform']['text']}")


def _not_a_folder(path: str) -> None:
    from pathlib import Path

    if Path(path).is_dir():
        _fail(f"{path}: is a folder; a platform run's folder of leg logs needs --platform")

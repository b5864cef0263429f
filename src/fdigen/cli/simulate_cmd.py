"""``fdigen simulate``: the closed loop of the model (or of the six-leg platform), with
faults, effects and plant parameters of its own, written as a log with its ground truth.
"""

from __future__ import annotations

import json

import click

from fdigen.cli.errors import _fail, echo
from fdigen.cli.parsing import _parse_effect, _parse_fault, _parse_parameter
from fdigen.cli.platform_common import (_BANK_OPTION, _FORCE_OPTION, _GEOMETRY_OPTION,
                                        _SAFETY_OPTION, _SEGMENT_OPTION, _platform_flag,
                                        _platform_only, _run_platform_simulate)
from fdigen.cli.types import POSITIVE_SECONDS
from fdigen.files.atomic import write_text


@click.command()
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--duration", default=None, type=POSITIVE_SECONDS,
              help="Seconds [default: the model's [simulation] duration, else 6 RMS "
                   "windows or 5 slowest time constants, at most 20000 samples; with "
                   "--platform one pass of the motion sequence].")
@click.option("--fault", "faults", multiple=True,
              help="Fault to inject: NAME@T0=SIZE, NAME@T0=RATE/s for a drift, or "
                   "NAME@T0=stuck for a sensor that holds its last reading; with "
                   "--platform LEG:NAME@T0=SIZE (LEG 1..6, also =RATE/s and =stuck).")
@click.option("--effect", "effects", multiple=True,
              help="Library effect the nominal model lacks, switched on in the plant: "
                   "NAME=VALUE (e.g. coulomb_friction=35); repeatable (not with --platform).")
@click.option("--parameter", "parameters", multiple=True,
              help="A parameter of the simulated plant other than the model's: NAME=VALUE "
                   "(e.g. Rcoil=10.9, a coil 9 % warm); repeatable (not with --platform).")
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
@_FORCE_OPTION
@click.pass_context
def simulate(ctx, model, duration, faults, effects, parameters, seed, no_noise, output,
             platform_run, bank, segment, geometry, safety_duration, force):
    """Simulate the closed loop and write a log in the rig format, with ground truth."""
    _platform_only(ctx, platform_run, ("bank", "segment", "geometry", "safety_duration"))
    if platform_run:
        if effects or parameters:
            raise click.UsageError(f"{'--effect' if effects else '--parameter'}: not with "
                                   "--platform (the platform's legs are the model as written)")
        _run_platform_simulate(output, faults, model, duration, segment, seed, no_noise, bank,
                               geometry, safety_duration, force)
        return
    from pathlib import Path

    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.sim.log import write_log
    from fdigen.sim.plant import simulate as run_sim

    if Path(output).is_dir():
        _fail(f"{output}: is a folder; a single-cylinder log is a CSV file (--platform "
              "writes a folder of leg logs)")
    from fdigen.sim.log_tables import table_format

    if table_format(output) is not None:     # CSV text under .mat was a log nothing read
        raise click.BadParameter(
            f"{output}: simulate writes its log as CSV text, not {table_format(output)}; "
            "name it .csv (detect, report, discover and commission read MAT, HDF5 and "
            "Parquet logs too)", param_hint="-o")
    from fdigen.cli.durations import simulation_duration
    from fdigen.files.outputs import check_output_file

    log_target = check_output_file(output, "-o")       # before the simulation runs
    truth_path = Path(output).with_suffix(".json")
    if check_output_file(truth_path, "-o") == log_target:
        _fail(f"-o {output}: the ground truth is written beside the log as "
              f"{truth_path.name}, which is the log itself; name the log .csv")
    from fdigen.files.outputs import check_sidecars

    check_sidecars([truth_path], truth_path, f"-o {output} (ground truth beside the log)",
                   force)
    m = load_model(resolve_model_path(model))
    duration, source = simulation_duration(m, duration)
    events = [_parse_fault(f) for f in faults]
    for text, e in zip(faults, events):
        if e.t0 >= duration:
            raise click.BadParameter(
                f"{text!r} starts at T0 = {e.t0:g} s, not before the end of the log at "
                f"{duration:g} s ({source}); the fault would never happen", param_hint="--fault")
    switched = [_parse_effect(e, m) for e in effects]
    plant_effects = tuple(pe for eff, values in switched
                          for pe in eff.plant_effects(m, values))
    pairs = [_parse_parameter(p, m) for p in parameters]
    twice = sorted({n for n, _ in pairs if [k for k, _ in pairs].count(n) > 1})
    if twice:
        raise click.BadParameter(f"{', '.join(twice)} given more than once: one value per "
                                 "parameter", param_hint="--parameter")
    plant_values = dict(pairs)
    from fdigen.sim.substep_accuracy import converged_simulation
    from fdigen.sim.substeps import simulation_substeps

    accuracy = converged_simulation(
        m, lambda n: run_sim(m, duration, faults=events, effects=plant_effects, seed=seed,
                             noise=not no_noise, parameters=plant_values or None,
                             substeps=n),
        simulation_substeps(m, float(m.fdi.get("sample_time", 1e-3))), noise=not no_noise)
    sim = accuracy.result
    import numpy as np

    columns = sim.columns()
    for name, values in columns.items():      # a demand of exp(1000 t): inf in its column
        if name not in {s.column for s in (*m.inputs, *m.outputs)} and \
                not np.all(np.isfinite(values)):
            k = int(np.argmax(~np.isfinite(values)))
            _fail(f"the simulation's column {name!r} is not finite from t = {sim.t[k]:g} s "
                  "(a demand of [simulation] that overflows or is undefined there); "
                  "nothing was written")
    bad = ~np.all(np.isfinite(np.hstack([sim.u, sim.y])), axis=1)
    if bad.any():      # a log of NaN is no log: every command that reads it refuses it
        from fdigen.errors import FdigenError

        raise FdigenError(
            f"the simulated plant left the finite numbers at t = {sim.t[np.argmax(bad)]:g} s "
            f"({int(bad.sum())} of {len(sim.t)} samples not finite): "
            + ("the faults or effects asked for (" + ", ".join(faults + effects)
               + ") drive it out of its equations' domain; try smaller sizes"
               if faults or effects else "the model diverges from its initial state")
            + "; nothing was written")
    where = sim.first_not_real()
    if where is not None:    # clamped to a limit, the log would look plausible: it is not
        from fdigen.errors import FdigenError

        raise FdigenError(
            f"the simulated plant left its equations' domain at t = {where[0]:g} s: the "
            f"derivative of dynamics.{where[1]} is not a number there (a sqrt or log of a "
            "negative number, or 0/0), and the states would be clamped to their limits "
            "from then on; "
            + ("the faults or effects asked for (" + ", ".join(faults + effects)
               + ") drive it there: try smaller sizes, or guard the argument as the physics "
               "says (sqrt(max(Ps - pA, 0)))" if faults or effects else
               "guard the argument as the physics says (sqrt(max(Ps - pA, 0))) or start "
               "the plant inside its domain") + "; nothing was written")
    write_log(output, columns)
    truth = {"case": Path(output).stem, "sample_time": float(sim.t[1] - sim.t[0]),
             "model": m.name, "seed": seed, "noise": not no_noise,
             "truth": {"parameters": {q.name: plant_values.get(q.name, q.value)
                                      for q in m.parameters},
                       "initial": {s.name: float(sim.x[0, i]) for i, s in enumerate(m.states)},
                       "faults": [{"kind": e.name, "t0": e.t0, "size": e.size, "ramp": e.ramp,
                                   "stuck": e.stuck}
                                  for e in events],
                       "effects": [{"effect": eff.name, "parameters": values,
                                    "units": {q.name: q.unit for q in eff.parameters}}
                                   for eff, values in switched]}}
    # the pair is written one file after the other: the truth names the log it belongs to
    # (a simulate killed between the two left a new log beside the old truth)
    import hashlib

    truth["substeps"] = {"used": accuracy.used, "stable": accuracy.start,
                         "converged": accuracy.converged}
    truth["log_sha256"] = hashlib.sha256(Path(output).read_bytes()).hexdigest()
    write_text(truth_path, json.dumps(truth, indent=1) + "\n")
    for eff, values in switched:      # the number means what the model's units say
        echo("effect " + ", ".join(f"{q.name} = {values.get(q.name, q.nominal):g} "
                                   f"{q.unit}" for q in eff.parameters)
             + f" ({eff.name}, in the model's own units)")
    echo(f"wrote {len(sim.t)} samples ({duration:g} s, {source}) to {output}")
    if accuracy.text():
        echo(("" if accuracy.converged else "warning: ") + accuracy.text(),
             err=not accuracy.converged)
    outside = sim.outside_ranges()
    if outside:
        echo("warning: the run leaves the declared ranges the design was derived over: "
             + "; ".join(outside) + " (a fault may do that; a healthy run doing it points "
             "at a reference, controller or range in other units than the plant's)",
             err=True)

"""``fdigen commission``: from one healthy log to a commissioned, built FDI design."""

from __future__ import annotations

import json

import click

from fdigen.cli.errors import echo, progress_printer
from fdigen.cli.types import RUNS, SCHEDULER, WORKERS


@click.command()
@click.argument("log", type=click.Path(dir_okay=False, exists=True))
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--out", "out", default=None, type=click.Path(file_okay=False),
              help="Output folder [default: ./commissioned/<log name>].")
@click.option("--runs", default=40, show_default=True, type=RUNS,
              help="Healthy runs of the threshold campaign.")
@click.option("--duration", default=None, type=float,
              help="Seconds per run [default: 10 s, or the model's run length (its "
                   "[simulation] duration) when 10 s holds fewer than 6 RMS windows].")
@click.option("--validation-runs", "validation_runs", default=10, show_default=True,
              help="Fresh healthy runs checked with the final thresholds.")
@click.option("--fault-sizes", "fault_sizes", default="0.5,1,2", show_default=True,
              help="Fault sizes relative to each fault's test_size (comma separated).")
@click.option("--fault-starts", "fault_starts", default=1, show_default=True,
              help="Onset times per fault and size.")
@click.option("--false-alarm-rate", "false_alarm_rate", default=0.01, show_default=True,
              help="Target probability that a simulated healthy run raises any flag.")
@click.option("--data-margin", "data_margin", default=1.5, show_default=True,
              help="Each threshold at least this times the healthy log's max RMS.")
@click.option("--min-tolerance", "min_tolerance", default=0.05, show_default=True,
              type=click.FloatRange(0.0, 0.9),
              help="Smallest relative spread of a calibrated parameter in the campaigns "
                   "(the rig drifts between runs; a calibration on one log is tight). A "
                   "parameter whose model file declares a smaller tolerance keeps its own "
                   "(at most 0.9, the widest spread a campaign takes).")
@click.option("--seed", default=0, show_default=True, help="Master seed of the campaigns.")
@click.option("--workers", default=2, show_default=True, type=WORKERS,
              help="Local Dask worker processes.")
@click.option("--scheduler", default=None, type=SCHEDULER,
              help="Address of a running Dask scheduler (tcp://HOST:PORT), or "
                   "'synchronous' (in-process).")
@click.option("--no-build", "no_build", is_flag=True, help="Do not build the code.")
@click.option("--force", is_flag=True,
              help="Overwrite files in --out under the names commission writes "
                   "(commission.json, <model>_commissioned.toml, discover/...) that fdigen "
                   "did not write.")
@click.option("--method", default="auto", show_default=True,
              type=click.Choice(["auto", "output-error"]),
              help="Calibration (as `fdigen discover --method`): auto, the equation test "
                   "where every state is measured or the derivative of one; output-error "
                   "always (slower; uses every sensor, static ones too).")
@click.option("--validate", "validate", multiple=True, type=click.Path(),
              help="Another healthy log of the rig (repeatable): the first confirms the "
                   "effects discover finds, and the final design must raise no flag on "
                   "any (they set no threshold).")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def commission(log, model, out, runs, duration, validation_runs, fault_sizes, fault_starts,
               false_alarm_rate, data_margin, min_tolerance, seed, workers, scheduler,
               no_build, force, method, validate, as_json):
    """Commission FDI on a rig from one healthy LOG.

    Calibrates the model and finds the effects it lacks (discover), writes the
    commissioned model file, designs the thresholds for that plant by a Monte Carlo
    campaign, checks them against LOG itself (each at least --data-margin times LOG's max
    RMS, raised if needed; no flag on LOG), runs the fault campaign (detection and
    isolation delays) and builds the code. `fdigen detect --model <model_file>` then uses
    it. The defaults take about a minute on 2 idle cores on the built-in cylinder's rig
    logs; a model with a state no sensor measures is calibrated by output error, which
    takes minutes on a long log (a 10,000-sample drive log: about 6 min in discover
    alone). See docs/commission.md.
    """
    from pathlib import Path

    from fdigen.commission.pipeline import CommissionSettings, commission as run
    from fdigen.commission.report import text_report

    try:
        factors = tuple(float(v) for v in fault_sizes.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"expected numbers separated by commas, got {fault_sizes!r}",
                                 param_hint="--fault-sizes")
    if out is None:
        out = Path("commissioned") / Path(log).stem
    settings = CommissionSettings(runs=runs, duration=duration,
                                  validation_runs=validation_runs, fault_factors=factors,
                                  fault_starts=fault_starts,
                                  false_alarm_rate=false_alarm_rate,
                                  data_margin=data_margin, min_tolerance=min_tolerance,
                                  seed=seed, method=method)
    progress = progress_printer(as_json)
    res = run(log, model, out=out, settings=settings, workers=workers, scheduler=scheduler,
              build=not no_build, progress=progress, force=force, validate=validate)
    if as_json:
        echo(json.dumps(res, indent=1, default=float))
    else:
        echo(text_report(res))
    if not res.get("verdict", {}).get("usable", True):
        raise SystemExit(1)   # a useless design is refused (the verdict says why)

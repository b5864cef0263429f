"""``fdigen discover``: find the effect a log shows and the model lacks, and add it."""

from __future__ import annotations

import json

import click

from fdigen.cli.errors import echo, progress_printer


@click.command()
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
@click.option("--reinit", default=None, type=float,
              help="Re-initialisation period [s] of the output-error simulation "
                   "[default: the longer of 1 s and 50 samples].")
@click.option("--window", default=None, type=float,
              help="Modulating window of the equation test [s] [default: from the log's "
                   "sample time and the plant's slowest time constant].")
@click.option("--method", default="auto", show_default=True,
              type=click.Choice(["auto", "output-error"]),
              help="auto: the equation test where every state is measured (through any "
                   "invertible sensor map) or is the derivative of one, the output-error "
                   "loop otherwise; output-error: the output-error loop always (slower, "
                   "more sensitive to small effects a calibration nearly absorbs).")
@click.option("--validate", "validate", default=None, type=click.Path(dir_okay=False),
              help="A second log: report the free-run error before and after on it.")
@click.option("--no-build", "no_build", is_flag=True,
              help="Write the augmented model file but do not rebuild its code.")
@click.option("--no-fdi", "no_fdi", is_flag=True,
              help="Do not run the FDI cores (original and augmented) over the log.")
@click.option("--backend", default="auto", show_default=True,
              type=click.Choice(["auto", "c", "casadi", "reference"]))
@click.option("--force", is_flag=True,
              help="Overwrite files in --out under the names discover writes "
                   "(discover.json, discover.png, <model>_discovered.toml...) that fdigen "
                   "did not write.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def discover(log, model, out, fraction, alpha, max_effects, reinit, window, method,
             validate, no_build, no_fdi, backend, force, as_json):
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
    from fdigen.files.outputs import check_output_folder

    check_output_folder(out, "--out")                 # before the calibration runs
    if window is not None and not window > 0:
        raise click.BadParameter(f"must be a positive number of seconds, got {window:g}",
                                 param_hint="--window")
    settings = DiscoverSettings(fraction=fraction, alpha=alpha, max_effects=max_effects,
                                reinit=reinit, window=window, method=method)
    progress = progress_printer(as_json)
    res = run_discover(log, model, out=out, settings=settings, build=not no_build,
                       fdi=not no_fdi, backend=backend, progress=progress,
                       validate=validate, force=force)
    if as_json:
        echo(json.dumps(res.as_dict(), indent=1))
        return
    if res.as_dict().get("method") == "output_error":
        from fdigen.discover.output_loop_view import text_report as oe_report

        echo(oe_report(res.as_dict()))
        return
    echo(text_report(res.as_dict()))

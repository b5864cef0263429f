"""The commissioned design on healthy logs of the rig it never saw (``commission --validate``).

The campaign's validation runs are simulations of the commissioned model: they cannot
show what the rig does that the model lacks. A user's drive train had backlash and dry
friction on its load; commissioned on a 10 s log that never reversed, its design passed
0 of 4 simulated validation runs and raised a flag on every other healthy log of the
same rig, at the first speed reversal (``safety_stop`` at 8.0 s, 4.9 s). The measured
healthy logs an engineer records beside the commissioning one are the test that can:

* the final design (flags on) runs over each log, as ``fdigen detect`` runs it; any flag
  is a false alarm on the real plant, and refuses the design
  (:func:`fdigen.commission.verdict.design_verdict`);
* per residual, the log's largest RMS over its threshold, :math:`\\max_k
  \\mathrm{RMS}_i[k] / J_i` (the RMS of the design with every flag off, as the
  commissioning log's check reads it), says how close the log came where it raised
  none.

The logs are read as the commissioning log is (short gaps filled, a long one refused) and
never change the thresholds: they are the unseen data.
"""

from __future__ import annotations

import numpy as np


def refuse_unusable_logs(model, logs, main_log=None) -> None:
    """Refuse, before any work, a ``--validate`` log the design cannot judge: one at
    another sample time than the model's ``[fdi] sample_time`` (read as ``detect`` reads
    it; a log whose stamps ran 9 % slow was taken and reported "quiet"), shorter than the
    RMS window (a 2-row log was reported "quiet"), or the same data as the commissioning
    log ``main_log`` or as another ``--validate`` log (by path, link or content: the
    thresholds clear the commissioning log by construction, so it cannot fail). Raises
    :class:`~fdigen.errors.LogError` naming the log."""
    import hashlib
    from pathlib import Path

    from fdigen.errors import LogError
    from fdigen.files.bounded import read_bytes
    from fdigen.sim.log import MAX_LOG_BYTES, read_log

    if not logs:
        return
    # the two numbers of [fdi] a log is judged by (the whole configuration needs every
    # threshold, which a model not tuned yet lacks: a user's axis was refused for it)
    try:
        sample_time = float(model.fdi["sample_time"])
        window = int(model.fdi.get("window", 100))
    except (KeyError, TypeError, ValueError):
        sample_time, window = None, 1   # the design says what is wrong with them
    seen = {}
    for path in ([main_log] if main_log is not None else []) + list(logs):
        try:
            digest = hashlib.sha256(read_bytes(Path(path), MAX_LOG_BYTES, what="log",
                                               error=LogError)).hexdigest()
        except LogError:
            continue                    # read_log below says what is wrong with it
        if digest in seen:
            raise LogError(f"{path}: the same data as {seen[digest]}: a validation log must "
                           "be another healthy log of the rig")
        seen[digest] = ("the commissioning log" if path is main_log and main_log is not None
                        else f"--validate {path}")
    for path in logs:
        lg = read_log(path, model, sample_time=sample_time, missing="fill")
        if len(lg.t) < window:
            raise LogError(f"{path}: {len(lg.t)} samples, fewer than the RMS window of "
                           f"{window}: a validation log this short cannot show a flag")


def check_validation_logs(model, logs, say=None) -> list[dict]:
    """Run the design of ``model`` (its final thresholds) over each healthy log of ``logs``
    (``say`` receives a line per log).

    Returns
    -------
    list of dict
        Per log: ``log`` (path), ``samples``, ``flags`` (residual -> first time raised),
        ``quiet`` (no flag), ``peak_over_threshold`` (residual -> the log's largest RMS
        over its threshold).
    """
    from fdigen.commission.healthy_check import first_flag_times
    from fdigen.design.cache import cached_design
    from fdigen.discover.design_check import log_rms
    from fdigen.sim.log import read_log

    if not logs:
        return []
    say = say or (lambda msg: None)
    say(f"  the final design on {len(logs)} healthy validation log"
        f"{'s' if len(logs) > 1 else ''} of the rig")
    design = cached_design(model)
    names = list(design.residual_names)
    thresholds = {n: float(v) for n, v in design.config.thresholds.items()}
    s0, startup = int(design.evaluation.startup), float(design.config.startup or 0.0)
    out = []
    for path in logs:
        lg = read_log(path, model, sample_time=design.config.sample_time, missing="fill")
        rms = log_rms(design, lg.u, lg.y)[s0:]   # no flag can rise in the start-up
        first = first_flag_times(design, lg.t, lg.u, lg.y)
        peak = {n: float(np.nanmax(rms[:, i]) / thresholds[n])
                for i, n in enumerate(names) if len(rms)
                and thresholds.get(n, 0.0) > 0 and np.isfinite(thresholds[n])}
        out.append({"log": str(path), "samples": int(len(lg.t)), "flags": first,
                    "quiet": not first, "peak_over_threshold": peak,
                    # validated by one RMS window after the start-up at least (a log
                    # one sample past it had "validated" the design on 5 s)
                    "startup": startup,
                    "validates": len(rms) >= int(design.config.window)})
        say(f"  {path}: " + validation_text(out[-1], float(lg.t[-1] - lg.t[0])))
    return out


def validation_text(checked: dict, seconds: float | None = None) -> str:
    """What one validation log showed, in words: a log that lies within the design's
    start-up validates nothing (a user's 6-minute log against a start-up of 400 s was
    reported "no flag")."""
    if not checked.get("validates", True):
        span = f"its {seconds:.6g} s lie" if seconds is not None else "it lies"
        return (f"VALIDATES NOTHING: {span} within the design's start-up of "
                f"{checked['startup']:g} s ([fdi] startup), or less than one RMS window "
                "past it, and shows nothing of the flags; a longer healthy log of the rig "
                "validates the design")
    if checked["flags"]:
        return "flags " + ", ".join(f"{n} at {t:.6g} s" for n, t in checked["flags"].items())
    return "no flag" + (f" (after the start-up of {checked['startup']:g} s)"
                        if checked.get("startup") else "")


def validation_log_failures(checked: list[dict]) -> tuple[list[str], list[str]]:
    """The verdict's failures and fixes of :func:`check_validation_logs`' flagged logs."""
    failures = [f"the design raised "
                + ", ".join(f"{n} at {t:.6g} s" for n, t in c["flags"].items())
                + f" on the healthy validation log {c['log']}: a false alarm on the real rig, "
                "which the simulated validation runs (the model's own plant) cannot show"
                for c in checked if not c["quiet"]]
    fixes = (["false alarms on a healthy log of the rig: commission on a log that covers "
              "what the rig does (every direction and range of the set-points), or write "
              "the effect the model lacks into it (`fdigen discover` names what it can "
              "explain; look at where the flag rose: a reversal points at backlash or dry "
              "friction)"] if failures else [])
    return failures, fixes

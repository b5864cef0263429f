"""The default durations of the command line's closed-loop runs, taken from the model.

``simulate``, ``verify`` (each trajectory) and ``tune`` (each run) last ``--duration``,
else the model file's ``[simulation] duration``, else a length from the plant: one rule,
:func:`fdigen.sim.run_length.default_duration` (6 RMS windows or 5 slowest time
constants, at most 20000 samples). Each function returns the duration and a few words
saying where it came from, for the command's output.
"""

from __future__ import annotations

from fdigen.sim.run_length import default_duration

#: The fewest samples a ``simulate`` or ``verify`` run may have.
MIN_SAMPLES = 10


def simulation_duration(model, duration: float | None) -> tuple[float, str]:
    """``(seconds, source)`` of a ``simulate`` run: ``--duration``, else the model's
    default (:func:`fdigen.sim.run_length.default_duration`)."""
    if duration is not None:
        dt = float((model.fdi or {}).get("sample_time") or 0.0)
        if dt > 0 and float(duration) < MIN_SAMPLES * dt:
            # 0.1 s at 0.1 s: an internal error, after a one-sample log was written
            import click

            raise click.BadParameter(
                f"{float(duration):g} s is shorter than {MIN_SAMPLES} samples of the model's "
                f"sample time {dt:g} s: a run needs at least {MIN_SAMPLES * dt:g} s",
                param_hint="--duration")
        return float(duration), "--duration"
    return default_duration(model)


#: The most samples of one ``verify`` trajectory when ``--duration`` does not ask for
#: more: every backend keeps every sample of it (a model's [simulation] duration of
#: 10000 s at 1 ms, 1e7 samples, took 6.8 GB and ran past 10 minutes in silence: attack
#: round 13).
VERIFY_SAMPLES = 200_000


def verify_duration(model, sample_time: float, duration: float | None) -> tuple[float, str]:
    """``(seconds, source)`` of each ``verify`` trajectory: the same rule as
    :func:`simulation_duration`, but a length taken from the model file is cut to
    :data:`VERIFY_SAMPLES` samples of the design's ``sample_time`` (and says so)."""
    seconds, source = simulation_duration(model, duration)
    if duration is None and sample_time > 0 and seconds / sample_time > VERIFY_SAMPLES:
        return VERIFY_SAMPLES * sample_time, (
            f"{source} cut to {VERIFY_SAMPLES} samples for the comparison; --duration asks "
            "for more")
    return seconds, source

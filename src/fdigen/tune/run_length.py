"""Whether the runs of a tuning campaign can give a verdict, and their default length.

The false-alarm rate a campaign designs for is per run of its duration, and a residual's
per-run maximum RMS (the statistic the thresholds are fitted to) is taken after the
design's settling time (one RMS window): a run no longer than the settling time plus one
RMS window of ``N`` samples never holds a filled window, and gives no verdict. Without
``--duration`` a run lasts as long as ``simulate``'s and ``verify``'s
(:func:`fdigen.sim.run_length.default_duration`).
"""

from __future__ import annotations

from fdigen.errors import FdigenError


def check_run_duration(model, duration: float, sample_time: float, window: int) -> list[str]:
    """Refuse runs that cannot give a verdict; warnings for runs shorter than the logs.

    Raises
    ------
    FdigenError
        When a run of ``duration`` does not outlast the settling time (one RMS window)
        plus one full RMS window of ``window`` samples.
    """
    samples = int(round(duration / sample_time))
    if samples < 2 * window:
        raise FdigenError(
            f"--duration {duration:g} s is {samples} samples: a run must outlast the settling "
            f"time and one RMS window ({window} samples of {sample_time:g} s each, so at "
            f"least {2 * window * sample_time:g} s) or no residual ever reaches its RMS and "
            "no verdict is possible")
    notes = []
    logs = model.simulation.get("duration")
    if logs and duration < float(logs):
        notes.append(
            f"warning: runs of {duration:g} s are shorter than the model's [simulation] "
            f"duration {float(logs):g} s: the false-alarm rate is per {duration:g} s run, "
            f"and slow drifts that take longer to build up are not seen; a "
            f"{float(logs):g} s log will raise false alarms more often")
    return notes

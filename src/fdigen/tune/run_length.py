"""How long each run of a tuning campaign lasts, and whether a run can give a verdict.

The false-alarm rate a campaign designs for is per run of its duration, and a residual's
per-run maximum RMS (the statistic the thresholds are fitted to) is taken after the
design's settling time (one RMS window): a run no longer than the settling time plus one
RMS window of ``N`` samples never holds a filled window, and gives no verdict.

Without ``--duration`` a run lasts the model's ``[simulation] duration`` (the length of
the logs the core will watch); a model without one gets a length from the plant:

.. math::

    D = \\max\\bigl(6\\,N T_s,\\; \\min(5\\,\\tau_{slow},\\; 20000\\,T_s)\\bigr)

with :math:`T_s` the sample time and :math:`\\tau_{slow}` the slowest stable time constant
at the operating point (:func:`fdigen.discover.windows.slowest_time_constant`).
"""

from __future__ import annotations

from fdigen.errors import FdigenError

#: RMS windows in a run of a model without ``[simulation] duration`` (at least)
MIN_RUN_WINDOWS = 6
#: slowest time constants in such a run (up to :data:`MAX_DEFAULT_SAMPLES`)
RUN_TIME_CONSTANTS = 5
#: the longest default run, in samples (simulate's and verify's default length)
MAX_DEFAULT_SAMPLES = 20000


def default_run_duration(model, sample_time: float, window: int) -> tuple[float, str]:
    """Seconds per run without ``--duration``, and where the number comes from."""
    given = model.simulation.get("duration")
    if given:
        return float(given), "the model's [simulation] duration"
    from fdigen.discover.windows import slowest_time_constant

    tau = slowest_time_constant(model)
    windows = MIN_RUN_WINDOWS * window * sample_time
    plant = min(RUN_TIME_CONSTANTS * tau, MAX_DEFAULT_SAMPLES * sample_time)
    seconds = max(windows, plant)
    seconds = float(f"{round(seconds / sample_time) * sample_time:.12g}")
    why = (f"{MIN_RUN_WINDOWS} RMS windows" if seconds == windows else
           f"{RUN_TIME_CONSTANTS} x the slowest time constant {tau:.3g} s"
           if plant < MAX_DEFAULT_SAMPLES * sample_time else
           f"{MAX_DEFAULT_SAMPLES} samples")
    return seconds, f"no [simulation] duration: {why}"


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

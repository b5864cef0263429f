"""The options of ``fdigen commission`` (:class:`CommissionSettings`) and the length of its
campaign runs (:func:`campaign_duration`)."""

from __future__ import annotations

import dataclasses

from fdigen.errors import FdigenError


@dataclasses.dataclass(frozen=True)
class CommissionSettings:
    """Options of :func:`commission` (defaults in brackets).

    Attributes
    ----------
    runs : int
        Healthy runs of the threshold campaign [40].
    duration : float
        Seconds per simulated run [None: :func:`campaign_duration`]; the false-alarm rate
        is per run of this length.
    validation_runs : int
        Fresh healthy runs checked with the final thresholds [10].
    fault_factors : tuple of float
        Fault sizes relative to each fault's ``test_size`` [0.5, 1, 2].
    fault_starts : int
        Onset times per fault and size [1].
    false_alarm_rate : float
        Target probability that a simulated healthy run raises any flag [0.01].
    margin : float
        Safety factor on the campaign's quantile [1.25].
    data_margin : float
        Each threshold is at least this many times the measured healthy log's maximum
        RMS [1.5].
    sigmas : float
        Parameter spread of the campaign in standard deviations of the calibration [3].
    min_tolerance : float
        Smallest relative spread of the uncertain parameters [0.05]: a calibration on one
        log is tight, the rig drifts (temperature, wear) between runs.
    seed : int
    fraction : float
        Share of the healthy log that calibrates [0.6]; the rest is held back.
    method : {"auto", "output-error"}
        Calibration of discover ["auto": the equation test where every state is measured
        or the derivative of a measured one, the output-error loop otherwise];
        "output-error" always (a water heater's heater power, read by a power meter that
        the equation test does not use, was calibrated only by output error).
    horizon_runs : int
        Healthy runs of the threshold campaign on which the validity horizons of frozen
        residuals are measured and written to ``[fdi.frozen_horizon]`` [10] (as
        ``fdigen tune --write`` does): without them a flag of a parallel model drifting
        after the first flag contradicted an isolated sensor fault, and a user's
        commissioned tanks escalated a transmitter offset to ``unexplained``.
    """

    runs: int = 40
    duration: float | None = None
    validation_runs: int = 10
    fault_factors: tuple = (0.5, 1.0, 2.0)
    fault_starts: int = 1
    false_alarm_rate: float = 0.01
    margin: float = 1.25
    data_margin: float = 1.5
    sigmas: float = 3.0
    min_tolerance: float = 0.05
    seed: int = 0
    method: str = "auto"
    fraction: float = 0.6
    horizon_runs: int = 10

    def __post_init__(self):
        if self.data_margin < 1:
            raise FdigenError("the data margin must be >= 1")
        if not 0 <= self.min_tolerance < 1:
            raise FdigenError("the minimum tolerance must be in [0, 1)")


#: Seconds per campaign run when none is given, if the model's sampling allows it.
DEFAULT_RUN = 10.0


def campaign_duration(model) -> float:
    """Seconds per campaign run without ``--duration``: 10 s where that holds the
    :data:`~fdigen.sim.run_length.MIN_RUN_WINDOWS` RMS windows a run needs, else the
    model's run length (:func:`fdigen.sim.run_length.default_duration`: its
    ``[simulation] duration``, else windows and time constants): a model sampled at 1 s
    got 10-sample runs and was refused after its calibration. A model whose own
    ``[simulation] duration`` is shorter (and holds the windows) keeps it: a user's boost
    converter at 50 us ran 10 s campaigns (200,000 samples a run, 100 times its 0.1 s)
    and was quoted false alarms per 10 s where tune quotes them per 0.1 s."""
    from fdigen.sim.run_length import MIN_RUN_WINDOWS, default_duration

    dt = float(model.fdi.get("sample_time", 1e-3))
    need = MIN_RUN_WINDOWS * int(model.fdi.get("window", 100)) * dt
    declared = model.simulation.get("duration")
    if declared is not None and need <= float(declared) < DEFAULT_RUN:
        return float(declared)
    return DEFAULT_RUN if DEFAULT_RUN >= need else default_duration(model)[0]

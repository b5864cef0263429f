"""Settings of a tuning campaign and the description of one run.

Holds :class:`TuneSettings` (the campaign's knobs, validated on construction),
:class:`Case` (one task: a closed-loop run and its FDI evaluation, small and picklable so
Dask can ship it) and :data:`NO_FLAG` (the threshold that switches flags off in the
healthy campaign).
"""

from __future__ import annotations

import dataclasses

from fdigen.design.evaluation import NEVER_FLAGS
from fdigen.errors import FdigenError

#: Threshold used to switch flags off in the healthy campaign (finite: the config needs it).
NO_FLAG = NEVER_FLAGS


@dataclasses.dataclass(frozen=True)
class TuneSettings:
    """Campaign settings.

    Attributes
    ----------
    runs : int
        Healthy runs used to tune the thresholds.
    duration : float or None
        Seconds per run (the false-alarm rate is per run of this length); None: the
        model's ``[simulation] duration``, else a length from the plant
        (:func:`fdigen.tune.run_length.default_run_duration`).
    false_alarm_rate : float
        Target probability :math:`\\alpha` that a healthy run raises any flag.
    margin : float
        Safety factor :math:`m \\ge 1` on the quantile.
    tolerance : float
        Relative spread of the ``uncertain`` parameters (uniform, +-).
    tolerances : tuple of (str, float)
        Per-parameter spreads overriding ``tolerance`` (``fdigen commission``: each
        calibrated parameter by its own uncertainty).
    settle : float or None
        Seconds excluded from the maxima (default: one RMS window).
    ref_scale : tuple of float
        Range of the demand amplitude scale :math:`a`.
    ref_shift : float
        Upper end of the demand time shift :math:`\\tau` [s].
    validation_runs : int
        Fresh healthy runs checked with the tuned core.
    fault_factors : tuple of float
        Fault sizes relative to each fault's ``test_size``.
    fault_starts : int
        Onset times per fault and size, evenly spaced in [0.35, 0.65] of the duration.
    faults : tuple of str or None
        Faults of the campaign (default: all the model's faults).
    min_fit_runs : int
        Below this many runs, thresholds are empirical (no extreme-value fit).
    seed : int
        Master seed: every run's noise seed, parameters and demand derive from it.
    keep : tuple of str
        Residuals whose thresholds stay as in the model file (a design decision rather
        than a noise statistic, e.g. the voter's); still fitted and reported.
    vertex_runs : bool
        Also run the healthy plant at the vertices of the tolerance box
        (:func:`fdigen.tune.cases.tolerance_vertices`); no threshold is set below their
        RMS.
    horizon_runs : int
        Healthy runs (the first of ``runs``) on which the validity horizons of frozen
        residuals are measured (:mod:`fdigen.tune.frozen_horizon`); 0: not measured.
    horizon_fault_runs : int
        With ``horizon_runs``: runs per fault case (each fault at its test size, sensor
        offsets also as drifts) whose flags outside the fault's signature after the first
        flag bound the horizons too (:func:`fdigen.tune.frozen_horizon.fault_run_horizons`).
    """

    runs: int = 40
    duration: float | None = None
    false_alarm_rate: float = 0.01
    margin: float = 1.25
    tolerance: float = 0.10
    tolerances: tuple = ()
    settle: float | None = None
    ref_scale: tuple = (0.8, 1.1)
    ref_shift: float = 100.0
    validation_runs: int = 10
    fault_factors: tuple = (0.25, 0.5, 1.0, 2.0)
    fault_starts: int = 2
    faults: tuple | None = None
    min_fit_runs: int = 20
    seed: int = 0
    keep: tuple = ()
    vertex_runs: bool = True
    horizon_runs: int = 0
    horizon_fault_runs: int = 0

    def __post_init__(self):
        if self.runs < 2:
            raise FdigenError("tune needs at least 2 healthy runs")
        if not 0 < self.false_alarm_rate < 1:
            raise FdigenError("the false-alarm rate must be in (0, 1)")
        if self.margin < 1:
            raise FdigenError("the safety margin must be >= 1")
        if self.duration is not None and self.duration <= 0:
            raise FdigenError("the duration must be positive")


@dataclasses.dataclass(frozen=True)
class Case:
    """One task: a closed-loop run and its FDI evaluation (small, picklable)."""

    kind: str                      # "healthy", "validation" or "fault"
    index: int
    seed: int
    duration: float
    parameters: dict
    ref_scale: float
    ref_shift: float
    fault: tuple | None = None     # (name, t0, size, ramp)
    factor: float | None = None
    plant: object = None           # Model simulated (None: the design's own model)
    effects: tuple = ()            # fdigen.sim.plant.Effect switched on in the plant
    substeps: int | None = None    # RK4 sub-steps of the plant (None: the model's own)

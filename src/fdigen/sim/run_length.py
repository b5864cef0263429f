"""The default length of a closed-loop run: one rule for ``simulate``, ``verify`` and ``tune``.

A run lasts the model file's ``[simulation] duration`` (the length of the logs the core
will watch); a model without one gets a length from the plant:

.. math::

    D = \\max\\bigl(6\\,N T_s,\\; \\min(5\\,\\tau_{slow},\\; 20000\\,T_s)\\bigr)

with :math:`T_s` the sample time (``fdi.sample_time``), :math:`N` the RMS window
(``fdi.window``, samples) and :math:`\\tau_{slow} = 1/\\min|\\mathrm{Re}\\,\\lambda|` over
the stable linearised modes at the operating point: long enough for the RMS windows to
fill several times and the slowest mode to settle, at most 20000 samples.
"""

from __future__ import annotations

#: RMS windows in a run of a model without ``[simulation] duration`` (at least)
MIN_RUN_WINDOWS = 6
#: slowest time constants in such a run (up to :data:`MAX_DEFAULT_SAMPLES`)
RUN_TIME_CONSTANTS = 5
#: the longest default run, in samples
MAX_DEFAULT_SAMPLES = 20000


def slowest_stable_time_constant(model) -> float:
    """:math:`1/\\min|\\mathrm{Re}\\,\\lambda|` over the stable linearised modes at the
    operating point (``inf`` when there is none)."""
    from fdigen.sim.substeps import model_modes

    modes = model_modes(model)
    at_op = modes.modes[0] if modes.points and not modes.points[0] else ()
    stable = [-lam.real for lam in at_op if lam.real < -1e-12]
    return 1.0 / min(stable) if stable else float("inf")


def default_duration(model) -> tuple[float, str]:
    """``(seconds, source)`` of a run without ``--duration`` (module docstring)."""
    given = dict(model.simulation or {}).get("duration")
    if given is not None:
        return float(given), "the model's [simulation] duration"
    dt = float(model.fdi.get("sample_time", 1e-3))
    window = int(model.fdi.get("window", 100))
    tau = slowest_stable_time_constant(model)
    windows = MIN_RUN_WINDOWS * window * dt
    plant = min(RUN_TIME_CONSTANTS * tau, MAX_DEFAULT_SAMPLES * dt)
    seconds = float(f"{max(1, round(max(windows, plant) / dt)) * dt:.12g}")
    why = (f"{MIN_RUN_WINDOWS} RMS windows of {window} samples" if windows >= plant else
           f"{RUN_TIME_CONSTANTS} x the slowest time constant {tau:.3g} s"
           if plant < MAX_DEFAULT_SAMPLES * dt else f"{MAX_DEFAULT_SAMPLES} samples")
    return seconds, f"no [simulation] duration: {why}"

"""The default durations of the command line's closed-loop runs, taken from the model.

``simulate`` runs for the model file's ``[simulation] duration`` (else
:data:`SIMULATION_DEFAULT` seconds, as :func:`fdigen.sim.plant.simulate` does);
``verify`` runs its trajectories for the same ``[simulation] duration`` when the model
gives one, else for :data:`VERIFY_SAMPLES` sample times. Each function returns the
duration and a few words saying where it came from, for the command's output.
"""

from __future__ import annotations

#: Seconds simulated when neither ``--duration`` nor ``[simulation] duration`` is given.
SIMULATION_DEFAULT = 20.0

#: Samples per ``verify`` trajectory when the model gives no ``[simulation] duration``:
#: 20 s at the cylinder's 1 ms, 2 s at 0.1 ms, 2000 s at 0.1 s.
VERIFY_SAMPLES = 20_000


def _model_duration(model) -> float | None:
    value = dict(model.simulation or {}).get("duration")
    return None if value is None else float(value)


def simulation_duration(model, duration: float | None) -> tuple[float, str]:
    """``(seconds, source)`` of a ``simulate`` run: ``--duration``, else the model's
    ``[simulation] duration``, else :data:`SIMULATION_DEFAULT`."""
    if duration is not None:
        return float(duration), "--duration"
    given = _model_duration(model)
    if given is not None:
        return given, "the model's [simulation] duration"
    return SIMULATION_DEFAULT, f"the default {SIMULATION_DEFAULT:g} s"


def verify_duration(model, sample_time: float, duration: float | None) -> tuple[float, str]:
    """``(seconds, source)`` of each ``verify`` trajectory: ``--duration``, else the model's
    ``[simulation] duration``, else ``VERIFY_SAMPLES * sample_time``."""
    if duration is not None:
        return float(duration), "--duration"
    given = _model_duration(model)
    if given is not None:
        return given, "the model's [simulation] duration"
    return (float(f"{VERIFY_SAMPLES * sample_time:.12g}"),
            f"{VERIFY_SAMPLES} samples of {sample_time:g} s")

"""Numerical stability of a classical Runge-Kutta (RK4) integration of the model.

Shared by the FDI design's parallel model (``fdi.substeps``,
:func:`fdigen.design.parallel_model.check_parallel_model_step`) and the plant simulator
(``[simulation] substeps``, :func:`fdigen.sim.plant.simulate`): both integrate
``dx/dt = f(x, u)`` over a sample time by ``substeps`` RK4 steps of ``h = T / substeps``.
The linearisation's eigenvalues ``lambda`` are evaluated at the operating point and at
each end of every state's declared ``range`` (one state at a time); a step is stable when
every mode satisfies ``|R(lambda h)| <= max(1, |e^{lambda h}|)``: RK4 may not amplify a
mode the plant damps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fdigen.derive.linearisation import numeric, operating_point_substitution, symbolic_jacobians
from fdigen.model.model import Model

#: the largest sub-step count searched for a stable one
MAX_STABLE_SUBSTEPS = 100000


def rk4_amplification(z):
    """Amplification of one classical Runge-Kutta step on ``dx/dt = lambda x``, ``z = lambda h``.

    .. math:: R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24
    """
    return 1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24


def _amplifies(lam: complex, sample_time: float, substeps: int) -> bool:
    """``|R(lambda h)| > max(1, |e^{lambda h}|)`` with ``h = sample_time / substeps``."""
    z = lam * sample_time / substeps
    return abs(rk4_amplification(z)) - max(1.0, abs(np.exp(z))) > 1e-9


@dataclass(frozen=True)
class LinearisedModes:
    """Eigenvalues of ``A = df/dx`` at the operating point and at the state range ends.

    ``points[k]`` is the departure from the operating point (``{}`` for the point itself,
    else ``{state: range end}``) and ``modes[k]`` its eigenvalues; points where the
    Jacobian is complex or not finite (a range end on a singularity) are left out.
    """

    points: tuple
    modes: tuple


def linearised_modes(model: Model, parameters: dict | None = None) -> LinearisedModes:
    """The model's linearised modes at the operating point and each state range end
    (with ``parameters``: at those parameter values instead of the model's)."""
    points = [{}]
    for s in model.states:
        if s.range:
            points += [{s.name: float(s.range[0])}, {s.name: float(s.range[1])}]
    jac_A = symbolic_jacobians(model).A          # derived once, evaluated at every point
    kept, modes = [], []
    for point in points:
        try:
            A = numeric(jac_A, operating_point_substitution(model, point, parameters))
        except (TypeError, ValueError):   # complex or infinite (zoo) there
            continue
        if not np.all(np.isfinite(A)):
            continue
        kept.append(point)
        modes.append(tuple(complex(v) for v in np.linalg.eigvals(A)) if A.size else ())
    return LinearisedModes(tuple(kept), tuple(modes))


@dataclass(frozen=True)
class UnstableMode:
    """The fastest mode an RK4 integration amplifies, and the sub-steps it needs."""

    lam: complex
    point: dict
    step: float
    amplification: float
    need: int

    def where(self) -> str:
        """Where the mode was found, in words."""
        if not self.point:
            return "the operating point"
        return "the operating point with " + ", ".join(f"{k} = {v:g}"
                                                        for k, v in self.point.items())


def unstable_mode(modes: LinearisedModes, sample_time: float,
                  substeps: int) -> UnstableMode | None:
    """The fastest linearised mode that ``substeps`` RK4 steps per sample amplify, or None.

    ``need`` is the least sub-step count (above ``substeps``) for which that mode satisfies
    ``|R(lambda T / need)| <= max(1, |e^{lambda T / need}|)``.
    """
    worst = None
    for point, lams in zip(modes.points, modes.modes):
        for lam in lams:
            if _amplifies(lam, sample_time, substeps) and (worst is None
                                                          or abs(lam) > abs(worst[0])):
                worst = (lam, point)
    if worst is None:
        return None
    lam, point = worst
    need = substeps
    while need < MAX_STABLE_SUBSTEPS:
        need += 1
        if not _amplifies(lam, sample_time, need):
            break
    h = sample_time / substeps
    return UnstableMode(lam, dict(point), h, float(abs(rk4_amplification(lam * h))), need)


def least_stable_substeps(modes: LinearisedModes, sample_time: float, start: int = 1) -> int:
    """The least sub-step count ``>= start`` for which no linearised mode is amplified."""
    substeps = int(start)
    while True:
        mode = unstable_mode(modes, sample_time, substeps)
        if mode is None:
            return substeps
        substeps = mode.need
        if substeps >= MAX_STABLE_SUBSTEPS:
            return substeps

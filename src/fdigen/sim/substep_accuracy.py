"""The RK4 sub-steps of the plant simulator, checked for *accuracy* on the run itself.

:mod:`fdigen.sim.substeps` chooses a count that integrates every linearised mode stably
at the operating point and the range ends. Stable is not accurate, and a fault can take
the plant where the linearisation said nothing: a clean room's door opened to 1.8 m^2
drives two pressures together through ``sqrt(|p1 - p2|) sign(p1 - p2)``, whose slope is
infinite where they meet. At the 10 sub-steps chosen at the operating point the simulated
room stayed 19 Pa above the anteroom with the door wide open (29.2 against 10.4 Pa), the
true plant (200 sub-steps) at 14.3 against 14.1 Pa; nothing said so.

The check is step doubling on the run asked for: the same run (same noise, faults and
demand) at ``N`` and ``2N`` sub-steps. ``N`` is accurate when the outputs of the two
differ by at most each sensor's noise (:data:`ACCURATE_FRACTION`) at
:data:`ACCURATE_QUANTILE` of the samples (a closed loop that switches, a load/unload
compressor, may switch one sample apart at any count); else ``N`` is doubled, at most
:data:`MAX_DOUBLINGS` times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the largest integration difference accepted, as a fraction of each output's noise
ACCURATE_FRACTION = 1.0
#: the quantile of the per-sample differences compared (the rest may switch apart)
ACCURATE_QUANTILE = 0.95
#: the most times the sub-steps are doubled (16 x the stable count)
MAX_DOUBLINGS = 4
#: the difference scale of a noise-free output, relative to its span over the run
NOISE_FREE_RELATIVE = 1e-4


@dataclass(frozen=True)
class SubstepAccuracy:
    """The outcome of :func:`converged_simulation`.

    ``start`` is the stable count the check began at, ``used`` the count of ``result``;
    ``ratio`` is the last comparison's difference over its tolerance (at most 1 when
    ``converged``), at ``output`` and time ``t`` (its largest difference).
    """

    start: int
    used: int
    ratio: float
    converged: bool
    output: str
    t: float
    result: object

    @property
    def raised(self) -> bool:
        """Whether the count used is above the stable one."""
        return self.used > self.start

    def text(self, run: str = "this run") -> str | None:
        """What the check did, in words (``None`` when the stable count was accurate);
        ``run`` names the run checked."""
        if self.converged and not self.raised:
            return None
        if self.converged:
            return (f"the simulated plant's RK4 sub-steps raised from {self.start} to "
                    f"{self.used} per sample: at fewer, the {self.output} of {run} differed "
                    f"from its run at twice as many by more than its noise (the integration, "
                    "not the plant)")
        return (f"the simulated plant does not converge in its RK4 sub-steps: at "
                f"{self.used // 2} and {self.used} per sample the {self.output} of {run} "
                f"differs by {self.ratio * ACCURATE_FRACTION:.3g} times its noise (largest "
                f"at t = {self.t:g} s); the log is the run at {self.used}, and may not be "
                "the plant's: a slope without bound (sqrt or abs at zero), or a switch, "
                "there; [simulation] substeps decides it")


def first_limit_contact(result) -> int:
    """The first sample at which a state of ``result`` (a simulation) sits on one of its
    ``limits`` (the simulator clamps there), or the run's length.

    A clamp is a modelled discontinuity (a piston on its end stop), which RK4 integrates
    to first order at any count: the cylinder's dead position sensor drove the piston
    into its stop, and 10 against 20 sub-steps differed there by 1.2 noise std for the
    rest of the run, which doubling would halve only. The runs are compared up to it.
    """
    import sympy as sp

    x = np.asarray(result.x, dtype=float)
    K = len(x)
    first = K
    values = dict(result.model.parameter_values)
    for i, s in enumerate(result.model.states):
        if s.limits is None:
            continue
        for bound in s.limits:
            try:
                b = float(sp.sympify(bound).xreplace(values))
            except (TypeError, ValueError):
                continue
            on = np.abs(x[:, i] - b) <= 1e-12 * max(abs(b), 1.0)
            # arrivals on the limit (a state that starts on it has not hit it)
            hit = np.flatnonzero(on[1:] & ~on[:-1]) + 1
            if hit.size:
                first = min(first, int(hit[0]))
    return first


def output_disagreement(a, b, noise_std) -> tuple[float, int, float]:
    """How far two runs of one plant disagree, over their tolerance.

    .. math:: r = \\max_k \\frac{Q_{0.95}(|y^a_k - y^b_k|)}{\\epsilon_k},\\qquad
              \\epsilon_k = \\sigma_k

    (``sigma_k`` the output's noise; a noise-free output: :data:`NOISE_FREE_RELATIVE` of
    its span over the run), up to the first sample at which either run sits on a state's
    limit (:func:`first_limit_contact`). A sample finite in one run and not in the other
    is an infinite difference.

    Returns
    -------
    (float, int, float)
        ``r``, the output it is largest at, and the time of that output's largest
        difference.
    """
    end = min(first_limit_contact(a), first_limit_contact(b)) if hasattr(a, "model") else None
    ya, yb = np.asarray(a.y, float)[:end], np.asarray(b.y, float)[:end]
    t = np.asarray(a.t, float)[:end]
    finite_a, finite_b = np.isfinite(ya), np.isfinite(yb)
    worst = (0.0, 0, float(t[0]) if len(t) else 0.0)
    for k in range(ya.shape[1]):
        both = finite_a[:, k] & finite_b[:, k]
        if np.any(finite_a[:, k] != finite_b[:, k]):
            j = int(np.argmax(finite_a[:, k] != finite_b[:, k]))
            return float("inf"), k, float(t[j])
        if not both.any():
            continue
        diff = np.abs(ya[both, k] - yb[both, k])
        span = float(np.ptp(yb[both, k]))
        tol = (ACCURATE_FRACTION * float(noise_std[k]) if noise_std[k] > 0
               else NOISE_FREE_RELATIVE * max(span, float(np.max(np.abs(yb[both, k]))), 1e-300))
        ratio = float(np.quantile(diff, ACCURATE_QUANTILE)) / tol
        if ratio > worst[0]:
            worst = (ratio, k, float(t[both][int(np.argmax(diff))]))
    return worst


def converged_simulation(model, run, start: int, noise: bool = True) -> SubstepAccuracy:
    """The run at the least doubling of ``start`` sub-steps that the next doubling agrees
    with (:func:`output_disagreement` at most 1).

    Parameters
    ----------
    model : Model
        The simulated plant (its outputs' noise sets the tolerance).
    run : callable
        ``run(substeps) -> SimulationResult``: the same run at another count.
    start : int
        The stable count (:func:`fdigen.sim.substeps.simulation_substeps`).
    noise : bool
        Whether the runs add sensor noise (without: the noise-free tolerance).
    """
    sig = np.array([o.noise_std if noise else 0.0 for o in model.outputs], float)
    n = int(start)
    coarse = run(n)
    ratio, k, t = 0.0, 0, 0.0
    for _ in range(MAX_DOUBLINGS):
        fine = run(2 * n)
        ratio, k, t = output_disagreement(coarse, fine, sig)
        if ratio <= 1.0:
            return SubstepAccuracy(int(start), n, ratio, True,
                                   model.outputs[k].name, t, coarse)
        n, coarse = 2 * n, fine
    return SubstepAccuracy(int(start), n, ratio, False, model.outputs[k].name, t, coarse)

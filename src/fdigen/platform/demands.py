"""The paper's sequence of motions as smooth pose trajectories, and the leg demands.

Section 5 of the paper drives the platform with "a series of motions that represent the
6-degrees of movement": surge, sway, heave, then roll, pitch, yaw. :class:`MotionSequence`
moves each degree of freedom in turn, the others held at home, with one excursion per
segment:

    dwell at home | 0 -> +A | +A -> -A | -A -> 0 | dwell at home

each move a quintic time-scaling (zero velocity and acceleration at both ends, so the
pose demand is C2 and every leg demand too). With ``T`` the move time and ``sigma = (t -
t_0)/T``:

.. math::

    q(t) = q_0 + (q_1 - q_0)\\, s(\\sigma),\\qquad s(\\sigma) = 10\\sigma^3 - 15\\sigma^4
    + 6\\sigma^5,\\qquad \\max |\\dot q| = \\tfrac{15}{8} \\frac{|q_1 - q_0|}{T}

The leg demands are the inverse kinematics of the pose demand,
``xref_i(t) = || p(q(t)) + R(q(t)) b_i - a_i || - l_min``
(:meth:`fdigen.platform.geometry.PlatformGeometry.piston_positions`), checked against
every leg's stroke.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fdigen.errors import FdigenError
from fdigen.platform.geometry import DOF_NAMES, PlatformGeometry

#: Default excursion per degree of freedom (m, m, m, rad, rad, rad): each uses about
#: +-57 mm of the 200 mm stroke on the most loaded leg of the default geometry, the
#: single-leg demand's +-70 mm less a margin for the platform's nonlinearity.
DEFAULT_AMPLITUDES = (0.10, 0.09, 0.07, float(np.radians(14.0)), float(np.radians(14.0)),
                      float(np.radians(18.0)))


def quintic(sigma) -> np.ndarray:
    """The quintic time-scaling ``s = 10 sigma^3 - 15 sigma^4 + 6 sigma^5`` on [0, 1]
    (clipped outside), written ``sigma^3 (10 + sigma (-15 + 6 sigma))`` as in the C."""
    s = np.clip(np.asarray(sigma, dtype=float), 0.0, 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


@dataclass(frozen=True)
class MotionSequence:
    """Each degree of freedom in turn, one smooth excursion each (the paper's demand).

    Parameters
    ----------
    amplitudes : sequence of 6 float
        Excursion ``A`` per degree of freedom, in :data:`DOF_NAMES` order
        (m, m, m, rad, rad, rad).
    segment : float
        Seconds per degree of freedom (dwell + move up + move across + move back + dwell).
    dwell : float
        Seconds held at home at each end of a segment.
    order : sequence of str
        Degrees of freedom to move, in turn (default: all six, in the paper's order).
    repeat : bool
        Repeat the sequence after its end (else hold the home pose).
    """

    amplitudes: tuple = DEFAULT_AMPLITUDES
    segment: float = 6.0
    dwell: float = 0.5
    order: tuple = DOF_NAMES
    repeat: bool = True

    def __post_init__(self):
        amps = tuple(float(a) for a in self.amplitudes)
        if len(amps) != 6 or not all(np.isfinite(amps)):
            raise FdigenError("motion sequence: 6 finite amplitudes expected")
        object.__setattr__(self, "amplitudes", amps)
        order = tuple(self.order)
        unknown = [d for d in order if d not in DOF_NAMES]
        if unknown or not order:
            raise FdigenError(f"motion sequence: unknown degree(s) of freedom {unknown} "
                              f"(known: {', '.join(DOF_NAMES)})")
        object.__setattr__(self, "order", order)
        if not (self.segment > 0 and 0 <= self.dwell and 2 * self.dwell < self.segment):
            raise FdigenError(f"motion sequence: a segment of {self.segment:g} s with a "
                              f"dwell of {self.dwell:g} s at each end; need segment > "
                              "2 dwell >= 0")

    @property
    def duration(self) -> float:
        """Seconds of one pass through the sequence."""
        return self.segment * len(self.order)

    def segments(self) -> list[dict]:
        """``[{"dof", "t_start", "t_end", "amplitude"}]`` of one pass."""
        return [{"dof": d, "t_start": k * self.segment, "t_end": (k + 1) * self.segment,
                 "amplitude": self.amplitudes[DOF_NAMES.index(d)]}
                for k, d in enumerate(self.order)]

    def profile(self, tau) -> np.ndarray:
        """The unit excursion ``e(tau)`` in [-1, 1] of one segment, ``tau`` in seconds
        from the segment start: 0 -> 1 in ``T``, 1 -> -1 in ``2T``, -1 -> 0 in ``T``
        with ``T = (segment - 2 dwell) / 4``."""
        tau = np.asarray(tau, dtype=float)
        T = (self.segment - 2 * self.dwell) / 4.0
        s = tau - self.dwell
        up = quintic(s / T)
        across = quintic((s - T) / (2 * T))
        back = quintic((s - 3 * T) / T)
        return up - 2.0 * across + back

    def pose(self, t) -> np.ndarray:
        """The pose demand at times ``t`` (relative to home), shape ``t.shape + (6,)``."""
        t = np.asarray(t, dtype=float)
        tt = np.mod(t, self.duration) if self.repeat else t
        q = np.zeros(t.shape + (6,))
        for seg in self.segments():
            j = DOF_NAMES.index(seg["dof"])
            on = (tt >= seg["t_start"]) & (tt < seg["t_end"])
            q[..., j] += np.where(on, seg["amplitude"] * self.profile(tt - seg["t_start"]), 0.0)
        return q

    def to_dict(self) -> dict:
        """JSON description."""
        return {"amplitudes": dict(zip(DOF_NAMES, self.amplitudes)), "segment": self.segment,
                "dwell": self.dwell, "order": list(self.order), "repeat": self.repeat,
                "duration": self.duration, "time_scaling": "quintic 10s^3-15s^4+6s^5"}


def leg_demands(geometry: PlatformGeometry, motion: MotionSequence, t, *,
                margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Pose demand and leg (piston position) demands ``xref_i(t)``, checked.

    Parameters
    ----------
    geometry : PlatformGeometry
    motion : MotionSequence
    t : array_like, shape (K,)
        Sample times [s].
    margin : float
        Distance every demand must keep from both end stops [m].

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Pose demand ``(K, 6)`` and piston position demands ``(K, 6)`` [m].

    Raises
    ------
    ReachabilityError
        If a demand leaves a leg's stroke (names the leg, by how much, and when).
    """
    t = np.asarray(t, dtype=float)
    q = motion.pose(t)
    x = geometry.check_reachable(q, margin=margin, t=t, what="motion demand")
    return q, x


def stroke_use(geometry: PlatformGeometry, motion: MotionSequence, dt: float = 1e-3) -> dict:
    """Piston range each degree of freedom's segment uses on every leg.

    Returns
    -------
    dict
        ``{dof: {"min_mm": [6], "max_mm": [6], "use_percent": float}}`` plus ``"all"``:
        the whole pass; ``use_percent`` is the largest excursion from mid-stroke as a
        percentage of the half stroke.
    """
    t = np.arange(0.0, motion.duration, dt)
    _, x = leg_demands(geometry, motion, t)
    out = {}
    half = geometry.stroke / 2.0
    for seg in motion.segments() + [{"dof": "all", "t_start": 0.0, "t_end": motion.duration}]:
        on = (t >= seg["t_start"]) & (t < seg["t_end"])
        lo, hi = x[on].min(axis=0), x[on].max(axis=0)
        out[seg["dof"]] = {"min_mm": (lo * 1e3).round(2).tolist(),
                           "max_mm": (hi * 1e3).round(2).tolist(),
                           "use_percent": float(np.max(np.abs(np.r_[lo, hi] - half)) / half
                                                * 100.0)}
    return out

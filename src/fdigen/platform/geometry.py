"""Geometry and kinematics of the 6-6 Stewart-Gough platform.

Frames and conventions
----------------------
* Base frame ``{B}``: origin at the centre of the base joint circle, ``z`` up.
* Top frame ``{P}``: attached to the moving plate, origin at the centre of the top joint
  circle, axes parallel to ``{B}``'s at the home pose.
* A *pose* is ``q = (surge, sway, heave, roll, pitch, yaw)`` in metres and radians,
  **relative to the home pose**: the origin of ``{P}`` is at

  .. math:: p(q) = (\\mathrm{surge},\\ \\mathrm{sway},\\ z_{home} + \\mathrm{heave})

  and its orientation is ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (intrinsic z-y'-x'' Euler
  angles: roll about ``x``, pitch about ``y``, yaw about ``z``, as in the paper; equal to
  scipy's ``Rotation.from_euler("ZYX", [yaw, pitch, roll])``).
* Leg ``i`` (1..6 in messages, 0..5 in arrays) joins base joint ``a_i`` (in ``{B}``) to
  top joint ``b_i`` (in ``{P}``). Its length and piston position are

  .. math::

      l_i(q) = \\lVert p(q) + R(q)\\, b_i - a_i \\rVert, \\qquad x_i = l_i - l_{min},
      \\qquad 0 \\le x_i \\le L

  with ``l_min`` the joint-to-joint length of a fully retracted leg and ``L`` the
  cylinder stroke (``x`` is measured from the retracted end stop, as in the cylinder
  model).

The default geometry (:func:`default_geometry`) uses the rig cylinder's stroke
``L = 0.2 m``, ``l_min = 0.45 m`` and a semi-regular hexagon layout; ``z_home`` puts every
leg at mid-stroke (``x = L/2``, the cylinder model's operating point) at the home pose,
and the rest pose (where the safety sequence takes the platform) is the home pose lowered
until every piston is at ``x = 0.1 L`` (20 mm), the bottom of the cylinder model's
normal operating range.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fdigen.errors import FdigenError

#: The six degrees of freedom of a pose, in order.
DOF_NAMES = ("surge", "sway", "heave", "roll", "pitch", "yaw")
#: Units of the pose components.
DOF_UNITS = ("m", "m", "m", "rad", "rad", "rad")
#: Number of legs.
NLEGS = 6
#: The rotation convention, stated once for messages and JSON.
ROTATION_CONVENTION = ("R = Rz(yaw) Ry(pitch) Rx(roll): intrinsic z-y'-x'' Euler angles, "
                       "roll about x, pitch about y, yaw about z")


class ReachabilityError(FdigenError):
    """A pose (or a trajectory) needs a leg outside its stroke.

    Attributes
    ----------
    leg : int
        The offending leg, 1..6 (the worst one).
    excess : float
        How far outside the stroke, metres (> 0).
    side : str
        ``"extension"`` (too long) or ``"retraction"`` (too short).
    """

    def __init__(self, message, leg, excess, side):
        super().__init__(message)
        self.leg, self.excess, self.side = leg, excess, side


def rotation_matrix(roll, pitch, yaw) -> np.ndarray:
    """``R = Rz(yaw) Ry(pitch) Rx(roll)``, vectorised.

    Parameters
    ----------
    roll, pitch, yaw : float or array_like
        Angles [rad], broadcast together to shape ``S``.

    Returns
    -------
    numpy.ndarray
        Shape ``S + (3, 3)``.

    Notes
    -----
    .. math::

        R = \\begin{pmatrix}
        c_\\psi c_\\theta & c_\\psi s_\\theta s_\\phi - s_\\psi c_\\phi &
            c_\\psi s_\\theta c_\\phi + s_\\psi s_\\phi \\\\
        s_\\psi c_\\theta & s_\\psi s_\\theta s_\\phi + c_\\psi c_\\phi &
            s_\\psi s_\\theta c_\\phi - c_\\psi s_\\phi \\\\
        -s_\\theta & c_\\theta s_\\phi & c_\\theta c_\\phi
        \\end{pmatrix}

    with ``phi = roll``, ``theta = pitch``, ``psi = yaw``.
    """
    r, p, y = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (roll, pitch, yaw)))
    cr, sr, cp, sp_, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    R = np.empty(r.shape + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp_ * sr - sy * cr
    R[..., 0, 2] = cy * sp_ * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp_ * sr + cy * cr
    R[..., 1, 2] = sy * sp_ * cr - cy * sr
    R[..., 2, 0] = -sp_
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def _pose_array(pose) -> np.ndarray:
    q = np.asarray(pose, dtype=float)
    if q.shape[-1:] != (6,):
        raise FdigenError(f"a pose has 6 components ({', '.join(DOF_NAMES)}), "
                          f"got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise FdigenError("a pose must be finite")
    return q


def format_pose(pose) -> str:
    """``surge=0.010 m, ..., yaw=2.00 deg`` for messages."""
    q = np.asarray(pose, dtype=float)
    parts = [f"{n}={v:.4g} m" for n, v in zip(DOF_NAMES[:3], q[:3])]
    parts += [f"{n}={np.degrees(v):.4g} deg" for n, v in zip(DOF_NAMES[3:], q[3:])]
    return ", ".join(parts)


@dataclass(frozen=True)
class PlatformGeometry:
    """A 6-6 Stewart-Gough platform.

    Parameters
    ----------
    base : array_like, shape (6, 3)
        Base joint positions ``a_i`` in ``{B}`` [m].
    top : array_like, shape (6, 3)
        Top joint positions ``b_i`` in ``{P}`` [m].
    l_min : float
        Joint-to-joint length of a fully retracted leg [m] (``x = 0``).
    stroke : float
        Cylinder stroke ``L`` [m]; leg length ``l_min + x`` with ``x`` in ``[0, L]``.
    home_height : float
        ``z_home``: height of ``{P}``'s origin above ``{B}``'s at the home pose [m].
    rest : array_like, shape (6,)
        Rest pose (relative to home), the end of the safety sequence.

    Raises
    ------
    FdigenError
        On wrong shapes, non-finite or non-positive sizes, coincident joints, or a home
        or rest pose outside the stroke.
    """

    base: np.ndarray
    top: np.ndarray
    l_min: float
    stroke: float
    home_height: float
    rest: np.ndarray = field(default_factory=lambda: np.zeros(6))

    def __post_init__(self):
        base = np.array(self.base, dtype=float)
        top = np.array(self.top, dtype=float)
        for name, arr in (("base", base), ("top", top)):
            if arr.shape != (NLEGS, 3) or not np.all(np.isfinite(arr)):
                raise FdigenError(f"platform geometry: {name} joints must be 6 finite "
                                  f"(x, y, z) points, got shape {arr.shape}")
            d = np.linalg.norm(arr[:, None, :] - arr[None, :, :], axis=-1)
            if np.any(d[np.triu_indices(NLEGS, 1)] < 1e-6):
                raise FdigenError(f"platform geometry: two {name} joints coincide")
        for name in ("l_min", "stroke", "home_height"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0:
                raise FdigenError(f"platform geometry: {name} must be finite and > 0, got {v}")
            object.__setattr__(self, name, v)
        base.setflags(write=False)
        top.setflags(write=False)
        rest = _pose_array(self.rest).copy()
        rest.setflags(write=False)
        object.__setattr__(self, "base", base)
        object.__setattr__(self, "top", top)
        object.__setattr__(self, "rest", rest)
        self.check_reachable(np.zeros(6), what="home pose")
        self.check_reachable(rest, what="rest pose")

    # -- kinematics -------------------------------------------------------------------------
    def leg_vectors(self, pose) -> np.ndarray:
        """Leg vectors ``p + R b_i - a_i`` in ``{B}``: shape ``S + (6, 3)`` for poses of
        shape ``S + (6,)``."""
        q = _pose_array(pose)
        R = rotation_matrix(q[..., 3], q[..., 4], q[..., 5])
        p = np.stack([q[..., 0], q[..., 1], self.home_height + q[..., 2]], axis=-1)
        return p[..., None, :] + np.einsum("...jk,ik->...ij", R, self.top) - self.base

    def leg_lengths(self, pose) -> np.ndarray:
        """Inverse kinematics: ``l_i = || p + R b_i - a_i ||``.

        Parameters
        ----------
        pose : array_like, shape ``S + (6,)``
            Pose(s) relative to home: surge, sway, heave [m], roll, pitch, yaw [rad].

        Returns
        -------
        numpy.ndarray, shape ``S + (6,)``
            Leg lengths [m] (joint to joint).
        """
        return np.linalg.norm(self.leg_vectors(pose), axis=-1)

    def piston_positions(self, pose) -> np.ndarray:
        """Piston positions ``x_i = l_i - l_min`` [m], shape ``S + (6,)`` (not checked)."""
        return self.leg_lengths(pose) - self.l_min

    def positions_to_lengths(self, x) -> np.ndarray:
        """``l_i = l_min + x_i``."""
        return np.asarray(x, dtype=float) + self.l_min

    @property
    def home_lengths(self) -> np.ndarray:
        """Leg lengths at the home pose."""
        return self.leg_lengths(np.zeros(6))

    @property
    def rest_lengths(self) -> np.ndarray:
        """Leg lengths at the rest pose (the safety sequence's target)."""
        return self.leg_lengths(self.rest)

    @property
    def rest_positions(self) -> np.ndarray:
        """Piston positions at the rest pose."""
        return self.rest_lengths - self.l_min

    def check_positions(self, x, *, margin: float = 0.0, t=None, what: str = "demand"):
        """Raise :class:`ReachabilityError` if any piston position leaves ``[m, L - m]``.

        Parameters
        ----------
        x : array_like, shape ``(6,)`` or ``(K, 6)``
            Piston positions [m].
        margin : float
            Required distance from both end stops [m].
        t : array_like, optional
            Time of each row, named in the message.
        what : str
            What is checked, for the message.

        Raises
        ------
        ReachabilityError
            Naming the worst leg (1..6), by how much it is out of stroke and on which
            side, and the time or row where it is worst.
        """
        x = np.atleast_2d(np.asarray(x, dtype=float))
        lo, hi = margin, self.stroke - margin
        over = np.maximum(x - hi, lo - x)           # > 0 where out of stroke
        if not np.all(np.isfinite(x)):
            raise FdigenError(f"{what}: non-finite piston position")
        if np.all(over <= 1e-12):
            return
        k, i = np.unravel_index(int(np.argmax(np.round(over, 12))), over.shape)
        side = "extension" if x[k, i] > hi else "retraction"
        limit = "full extension" if side == "extension" else "full retraction"
        if margin:
            limit += f" less a {margin * 1e3:.3g} mm margin"
        when = "" if x.shape[0] == 1 else (f" at t = {float(np.asarray(t)[k]):.3f} s"
                                           if t is not None else f" at row {k}")
        raise ReachabilityError(
            f"{what} out of reach{when}: leg {i + 1} needs piston position "
            f"{x[k, i] * 1e3:.2f} mm (length {x[k, i] + self.l_min:.4f} m), "
            f"{over[k, i] * 1e3:.2f} mm beyond {limit} (stroke 0..{self.stroke * 1e3:.0f} mm, "
            f"length {self.l_min:.4f}..{self.l_min + self.stroke:.4f} m)",
            leg=int(i) + 1, excess=float(over[k, i]), side=side)

    def check_reachable(self, pose, *, margin: float = 0.0, t=None, what: str = "pose"):
        """Raise :class:`ReachabilityError` if a pose (or any of ``(K, 6)`` poses) needs a
        leg outside its stroke; returns the piston positions otherwise."""
        q = _pose_array(pose)
        x = self.piston_positions(q)
        label = what if q.ndim > 1 else f"{what} ({format_pose(q)})"
        self.check_positions(x, margin=margin, t=t, what=label)
        return x

    def forward_kinematics(self, lengths, guess=None, *, tol: float = 1e-12,
                           max_iter: int = 50) -> np.ndarray:
        """The pose whose leg lengths are ``lengths``, by Newton's method.

        Solves ``l(q) = lengths`` from ``guess`` (default: home) with the Jacobian
        ``dl_i/dq = n_i^T [I, d(R b_i)/d(angles)]`` (``n_i`` the unit leg vector),
        evaluated by central differences.

        Returns
        -------
        numpy.ndarray, shape (6,)

        Raises
        ------
        FdigenError
            If Newton does not converge (no assembly near ``guess``).
        """
        target = np.asarray(lengths, dtype=float)
        q = np.zeros(6) if guess is None else np.array(guess, dtype=float)
        h = 1e-7
        for _ in range(max_iter):
            err = self.leg_lengths(q) - target
            if np.max(np.abs(err)) < tol:
                return q
            J = np.empty((6, 6))
            for j in range(6):
                dq = np.zeros(6)
                dq[j] = h
                J[:, j] = (self.leg_lengths(q + dq) - self.leg_lengths(q - dq)) / (2 * h)
            q = q - np.linalg.solve(J, err)
        err = np.max(np.abs(self.leg_lengths(q) - target))
        if err < 1e-9:
            return q
        raise FdigenError(f"forward kinematics did not converge (leg length error {err:.3g} m)")

    # -- description ------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Everything that defines the geometry, JSON-ready (also read by :meth:`from_dict`)."""
        return {"base_joints": self.base.tolist(), "top_joints": self.top.tolist(),
                "l_min": self.l_min, "stroke": self.stroke, "home_height": self.home_height,
                "rest_pose": dict(zip(DOF_NAMES, self.rest.tolist())),
                "pose_convention": "pose relative to home: p = (surge, sway, home_height + "
                                   "heave); " + ROTATION_CONVENTION,
                "leg_length": "l_i = |p + R b_i - a_i|, piston x_i = l_i - l_min in [0, stroke]"}

    @classmethod
    def from_dict(cls, data: dict) -> "PlatformGeometry":
        """A geometry from :meth:`to_dict`'s keys (``rest_pose`` optional: home)."""
        try:
            rest = data.get("rest_pose", {})
            if isinstance(rest, dict):
                rest = [float(rest.get(n, 0.0)) for n in DOF_NAMES]
            return cls(base=data["base_joints"], top=data["top_joints"],
                       l_min=data["l_min"], stroke=data["stroke"],
                       home_height=data["home_height"], rest=rest)
        except KeyError as exc:
            raise FdigenError(f"platform geometry: missing key {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            if isinstance(exc, FdigenError):
                raise
            raise FdigenError(f"platform geometry: {exc}") from None


def hexagon_joints(radius: float, centres_deg, half_angle_deg: float, z: float = 0.0,
                   order=(0, 1, 2, 3, 4, 5)) -> np.ndarray:
    """Six joints in three pairs on a circle: pair ``k`` at ``centres_deg[k] -/+ half_angle``."""
    ang = []
    for c in centres_deg:
        ang += [c - half_angle_deg, c + half_angle_deg]
    ang = np.radians(np.asarray(ang)[list(order)])
    return np.stack([radius * np.cos(ang), radius * np.sin(ang), np.full(6, z)], axis=1)


def symmetric_geometry(*, base_radius: float = 0.5, top_radius: float = 0.3,
                       base_half_angle_deg: float = 10.0, top_half_angle_deg: float = 10.0,
                       l_min: float = 0.45, stroke: float = 0.2, home_fraction: float = 0.5,
                       rest_fraction: float = 0.1) -> PlatformGeometry:
    """A semi-regular 6-6 platform with every leg at ``home_fraction`` of its stroke at home.

    Base joint pairs are centred at 0, 120, 240 degrees, top joint pairs at 60, 180, 300
    degrees (each pair ``+-half_angle``); leg ``i`` joins a base joint to the nearer joint
    of the neighbouring top pair, giving the usual zig-zag. All legs have the same
    horizontal reach ``d``, so with ``l_home = l_min + home_fraction L``

    .. math:: z_{home} = \\sqrt{l_{home}^2 - d^2}

    and the rest pose is the home pose lowered to ``heave = sqrt(l_rest^2 - d^2) - z_home``
    with ``l_rest = l_min + rest_fraction L``.
    """
    base = hexagon_joints(base_radius, (0.0, 120.0, 240.0), base_half_angle_deg)
    # top pairs at 300 (= -60), 60, 180: base joint 0 (at -ha) goes to the top joint of
    # the -60 pair nearer to 0 deg, base joint 1 (at +ha) to the 60 pair's nearer one...
    top = hexagon_joints(top_radius, (-60.0, 60.0, 180.0), top_half_angle_deg,
                         order=(1, 2, 3, 4, 5, 0))
    d = float(np.linalg.norm(top[0, :2] - base[0, :2]))
    l_home = l_min + home_fraction * stroke
    l_rest = l_min + rest_fraction * stroke
    if not d < l_rest:
        raise FdigenError("platform geometry: legs too short for the joint circles")
    z_home = float(np.sqrt(l_home ** 2 - d ** 2))
    z_rest = float(np.sqrt(l_rest ** 2 - d ** 2))
    return PlatformGeometry(base=base, top=top, l_min=l_min, stroke=stroke,
                            home_height=z_home, rest=np.array([0, 0, z_rest - z_home, 0, 0, 0]))


def default_geometry() -> PlatformGeometry:
    """The documented default platform: the rig cylinder (stroke 0.2 m) on every leg.

    Base joints on a 0.5 m circle, top joints on a 0.3 m circle, pairs +-10 degrees about
    their centres; ``l_min = 0.45 m`` (retracted, joint to joint), so a leg is 0.45..0.65 m
    long; home pose: every leg 0.55 m (mid-stroke); rest pose: every piston at 20 mm.
    """
    return symmetric_geometry()

"""Numeric equivalence of every backend with the symbolic reference.

Two checks, both against :class:`fdigen.backends.reference.ReferenceFdi`:

* **points**: the pure step ``(z, u, y, p, mode) -> (z_next, r, aux)`` on many seeded
  random points over the physical range (states and inputs drawn from their ranges,
  outputs from the output equations plus sensor noise, both modes);
* **trajectories**: whole closed-loop runs (the simulator, sensor noise, faults injected),
  through the complete step with evaluation: residuals and RMS values compared with a
  relative tolerance, flags, fault class, action and consistent faults compared exactly,
  sample for sample.

The relative difference of an output is ``|a - b| / max(|b|, s)`` with ``s`` the largest
magnitude of that output over all points (so a residual that crosses zero is compared on
its own scale, not divided by a tiny number).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fdigen.backends.reference import ReferenceFdi
from fdigen.design.fdi_design import FdiDesign
from fdigen.safe_lambdify import safe_lambdify

#: Tolerances the equivalence tests assert (relative, see module docstring).
POINT_RTOL = 1e-12
TRAJECTORY_RTOL = 1e-9


@dataclass(frozen=True)
class Difference:
    """Largest absolute and relative difference of one output of one backend."""

    backend: str
    check: str
    output: str
    max_abs: float
    max_rel: float
    compared: int
    mismatches: int = 0  # for discrete outputs (flags, class, action)


def backend_factories(design: FdiDesign, which=None) -> dict:
    """Constructors of the backends to compare, by name (imported lazily)."""

    def casadi_sx():
        from fdigen.backends.casadi_backend.runner import CasadiFdi
        return CasadiFdi(design, compiled=False)

    def casadi_compiled():
        from fdigen.backends.casadi_backend.runner import CasadiFdi
        return CasadiFdi(design, compiled=True)

    def c_double():
        from fdigen.backends.c.loader import CFdi
        return CFdi(design)

    all_ = {"casadi_sx": casadi_sx, "casadi_compiled": casadi_compiled, "c": c_double}
    return {k: v for k, v in all_.items() if which is None or k in which}


def random_points(design: FdiDesign, n: int, seed: int = 0) -> dict:
    """Seeded random inputs of the step over the physical range.

    Returns a dict with ``z`` (n, nz), ``u`` (n, m), ``y`` (n, p), ``mode`` (n, 2).
    The FDI state is the initial state of a random sample (``init`` program) plus a
    perturbation of a few percent of each state's range, so every part of the state is
    exercised away from consistency.
    """
    model = design.model
    rng = np.random.default_rng(seed)

    def draw(items):
        cols = []
        for s in items:
            lo, hi = s.range if s.range else (-1.0, 1.0)
            cols.append(rng.uniform(lo, hi, n))
        return np.stack(cols, axis=1)

    import sympy as sp

    x = draw(model.states)
    u = draw(model.inputs)
    h = safe_lambdify([list(model.x), list(model.u), list(model.p)], list(model.h()), "numpy")
    p = np.array([q.value for q in model.parameters])
    y = np.stack([np.broadcast_to(np.asarray(v, dtype=float), (n,))
                  for v in h(list(x.T), list(u.T), list(p))], axis=1)
    y = y + rng.standard_normal(y.shape) * np.array([o.noise_std for o in model.outputs])
    ref = ReferenceFdi(design)
    (z0,) = ref.init_fn(list(u.T), list(y.T), list(p))
    z = np.stack([np.broadcast_to(np.asarray(v, dtype=float), (n,)) for v in z0], axis=1)
    # a second random state, so that z is not consistent with y
    x2 = draw(model.states)
    y2 = np.stack([np.broadcast_to(np.asarray(v, dtype=float), (n,))
                   for v in h(list(x2.T), list(u.T), list(p))], axis=1)
    (z2,) = ref.init_fn(list(u.T), list(y2.T), list(p))
    z2 = np.stack([np.broadcast_to(np.asarray(v, dtype=float), (n,)) for v in z2], axis=1)
    w = rng.uniform(0, 0.2, (n, 1))
    z = (1 - w) * z + w * z2
    mode = np.stack([rng.integers(0, 2, n), rng.integers(0, 2, n)], axis=1).astype(float)
    return {"z": z, "u": u, "y": y, "mode": mode}


def reference_points(design: FdiDesign, pts: dict) -> tuple:
    """The reference step on every point at once (vectorised lambdify)."""
    ref = ReferenceFdi(design)
    zn, r, aux = ref.step_fn(list(pts["z"].T), list(pts["u"].T), list(pts["y"].T),
                             list(ref.p), list(pts["mode"].T))
    n = pts["z"].shape[0]

    def stack(vals):
        if not vals:
            return np.zeros((n, 0))
        return np.stack([np.broadcast_to(np.asarray(v, dtype=float), (n,)) for v in vals], 1)

    return stack(zn), stack(r), stack(aux)


def _compare(backend, check, names, got, want):
    out = []
    for j, name in enumerate(names):
        a, b = got[:, j], want[:, j]
        # equal values are equal, infinities and NaN included (a diverging open-loop
        # parallel model is inf in every backend: inf - inf read as a difference of inf)
        same = (a == b) | (np.isnan(a) & np.isnan(b))
        with np.errstate(invalid="ignore"):
            diff = np.where(same, 0.0, np.nan_to_num(np.abs(a - b), nan=np.inf,
                                                     posinf=np.inf))
        finite = np.where(np.isfinite(b), np.abs(b), 0.0)   # the scale of the finite values
        scale = np.maximum(finite, np.max(finite) if b.size else 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            rel = np.where(diff == 0, 0.0, np.where(
                np.isinf(diff), np.inf, diff / np.where(scale > 0, scale, np.inf)))
        out.append(Difference(backend, check, name, float(diff.max(initial=0.0)),
                              float(np.nan_to_num(rel, nan=np.inf, posinf=np.inf)
                                    .max(initial=0.0)),
                              int(a.size)))
    return out


def compare_points(design: FdiDesign, backend, name: str, pts: dict, want=None) -> list:
    """Differences of a backend's ``core`` from the reference on random points."""
    want = want or reference_points(design, pts)
    n = pts["z"].shape[0]
    got = [np.empty_like(w) for w in want]
    for k in range(n):
        zn, r, aux = backend.core(pts["z"][k], pts["u"][k], pts["y"][k], pts["mode"][k])
        got[0][k], got[1][k], got[2][k] = zn, r, aux
    res = []
    res += _compare(name, "points", [f"z_next.{s}" for s in design.state_names], got[0], want[0])
    res += _compare(name, "points", [f"r.{s}" for s in design.residual_names], got[1], want[1])
    res += _compare(name, "points", [f"aux.{s}" for s in design.aux_names], got[2], want[2])
    return res


def compare_runs(design: FdiDesign, name: str, got: dict, want: dict, label: str) -> list:
    """Differences of two whole-log runs: continuous outputs and exact discrete ones."""
    res = []
    res += _compare(name, label, [f"r.{s}" for s in design.residual_names], got["r"], want["r"])
    res += _compare(name, label, [f"rms.{s}" for s in design.residual_names], got["rms"],
                    want["rms"])
    if want["aux"].size:
        res += _compare(name, label, [f"aux.{s}" for s in design.aux_names], got["aux"],
                        want["aux"])
    for key in ("flags", "fault_class", "action", "faults"):
        mism = int(np.sum(np.asarray(got[key]) != np.asarray(want[key])))
        res.append(Difference(name, label, key, float(mism > 0), float(mism > 0),
                              int(len(want[key])), mism))
    return res


def verification_trajectories(design: FdiDesign, duration: float = 20.0, seed: int = 1):
    """Closed-loop runs with faults injected: one healthy, one per fault of the model.

    Each fault starts at 40 % of the run with the size the model file gives it
    (``test_size``); pressure-sensor-like additive faults are ramps (drifts).
    """
    from fdigen.sim.plant import FaultEvent, simulate

    model = design.model
    runs = [("healthy", ())]
    for f in model.faults:
        if f.test_size:
            runs.append((f.name, (FaultEvent(f.name, 0.4 * duration, f.test_size),)))
    out = []
    for k, (label, faults) in enumerate(runs):
        sim = simulate(model, duration, faults=faults, seed=seed + k)
        out.append((label, sim.u, sim.y))
    return out


def verify(design: FdiDesign, backends=None, n_points: int = 1000, duration: float = 20.0,
           seed: int = 0, trajectories=None) -> dict:
    """Compare backends with the reference; returns a JSON-able report.

    Parameters
    ----------
    backends : iterable of str, optional
        Subset of ``casadi_sx``, ``casadi_compiled``, ``c``; default all.
    trajectories : list of (label, u, y), optional
        Default: :func:`verification_trajectories`.
    """
    factories = backend_factories(design, backends)
    pts = random_points(design, n_points, seed)
    want_pts = reference_points(design, pts)
    trajs = trajectories if trajectories is not None else verification_trajectories(
        design, duration)
    ref = ReferenceFdi(design)
    want_runs = [(label, ref.run(u, y)) for label, u, y in trajs]
    diffs = []
    for name, make in factories.items():
        backend = make()
        diffs += compare_points(design, backend, name, pts, want_pts)
        for (label, u, y), (_, want) in zip(trajs, want_runs):
            diffs += compare_runs(design, name, backend.run(u, y), want, f"trajectory:{label}")
    return report(diffs, n_points, trajs)


def report(diffs, n_points, trajs) -> dict:
    """Summarise differences per backend and output (largest over all checks)."""
    out = {"tolerances": {"points_rel": POINT_RTOL, "trajectories_rel": TRAJECTORY_RTOL},
           "points": n_points,
           "trajectories": [{"label": label, "samples": int(u.shape[0])}
                            for label, u, _ in trajs],
           "backends": {}}
    for d in diffs:
        b = out["backends"].setdefault(d.backend, {})
        key = f"{d.check.split(':')[0]}:{d.output}"
        e = b.setdefault(key, {"max_abs": 0.0, "max_rel": 0.0, "compared": 0, "mismatches": 0})
        e["max_abs"] = max(e["max_abs"], d.max_abs)
        e["max_rel"] = max(e["max_rel"], d.max_rel)
        e["compared"] += d.compared
        e["mismatches"] += d.mismatches
    for name, b in out["backends"].items():
        pts_rel = max([v["max_rel"] for k, v in b.items() if k.startswith("points:")], default=0)
        traj_rel = max([v["max_rel"] for k, v in b.items() if k.startswith("trajectory:")
                        and v["mismatches"] == 0 and not k.endswith(
                            ("flags", "fault_class", "action", "faults"))], default=0)
        mism = sum(v["mismatches"] for v in b.values())
        b["summary"] = {"points_max_rel": pts_rel, "trajectories_max_rel": traj_rel,
                        "discrete_mismatches": mism,
                        "ok": pts_rel <= POINT_RTOL and traj_rel <= TRAJECTORY_RTOL
                        and mism == 0}
    return out

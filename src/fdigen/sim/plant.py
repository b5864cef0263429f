"""Closed-loop simulation of a plant built from the same model, with faults and effects.

The plant integrates the nonlinear model (with fault terms and any extra effects the
nominal model lacks) by fixed-step RK4 with sub-steps, clamps states to their physical
limits, measures through the output equations with white Gaussian sensor noise, and is
driven by the controller of the model file's ``[simulation]`` table. The whole run is one
CasADi ``mapaccum`` over fixed-length chunks of samples, built once per plant (model,
effects, sub-steps, sample time) and cached for the process, so repeated runs (Monte Carlo,
tuning) pay only the evaluation: Python never loops per sample.

Timing follows the rig's logs: at sample ``k`` the sensors are read, the controller
computes ``u[k]`` from them, and ``u[k]`` is held over ``[t_k, t_{k+1})``.
"""

from __future__ import annotations

import dataclasses
import math
from collections import OrderedDict
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import sympy as sp

from fdigen.errors import FdigenError
from fdigen.model.expression import parse_expression
from fdigen.model.model import Model
from fdigen.model.simulation_spec import initial_value, simulation_spec
from fdigen.safe_lambdify import safe_lambdify
from fdigen.sim.compiled_plant import PlantChunks
from fdigen.sim.controllers import control_step, integrator_count
from fdigen.sim.run_length import default_duration
from fdigen.sim.substeps import simulation_substeps

#: samples one simulation holds at most (its arrays are some hundred bytes a sample; a
#: duration of 1e12 s asked for 745 GiB and ended in a MemoryError: attack round 3)
MAX_SAMPLES = 10_000_000
#: samples per ``mapaccum`` chunk of a simulation (the last chunk is padded and cut)
CHUNK_SAMPLES = 1000
#: plants kept by :func:`_plant_runner` (each holds a CasADi chunk function)
_PLANT_CACHE_SIZE = 16
_PLANT_CACHE: OrderedDict = OrderedDict()


@dataclass(frozen=True)
class FaultEvent:
    """A fault of the model switched on at ``t0``.

    ``size`` is the fault magnitude (its symbol's value); with ``ramp`` the magnitude grows
    at ``size`` per second from ``t0`` (a drift). With ``stuck`` (sensor faults only) the
    faulty sensor holds the value it read just before ``t0`` (``size`` is ignored).
    """

    name: str
    t0: float
    size: float
    ramp: bool = False
    stuck: bool = False


@dataclass(frozen=True)
class Effect:
    """An effect the nominal model lacks: a term added to one state equation or output.

    ``term`` is a sympy expression over the model's symbols and this effect's own
    ``parameters`` (name -> value).
    """

    name: str
    target: str
    term: sp.Expr
    parameters: dict = field(default_factory=dict)


@dataclass(frozen=True)
class SimulationResult:
    """A simulated log: time, command, measured outputs, true states, reference."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    x: np.ndarray
    ref: np.ndarray
    faults: np.ndarray
    model: Model
    #: (K, n): in how many RK4 stages of sample k a state's derivative was not a number
    #: (a sqrt or log of a negative number, 0/0); a state with limits is then clamped to
    #: one of them and the log still looks finite (:meth:`first_not_real` says where)
    not_real: np.ndarray | None = None

    def first_not_real(self) -> tuple[float, str] | None:
        """``(t, state)`` of the first sample whose derivative was not real, or ``None``;
        the state is the one that went first (a NaN spreads to every state it feeds at
        the next stage, so the first has the most stages)."""
        if self.not_real is None or not self.not_real.any():
            return None
        k = int(np.argmax(self.not_real.any(axis=1)))
        return float(self.t[k]), self.model.states[int(np.argmax(self.not_real[k]))].name

    def outside_ranges(self) -> list[str]:
        """The states that leave their declared ``range`` by more than 5 % of it during
        the run, each as ``"T 324.5 to 450 K against [312, 336]"``: the design was derived
        over those ranges (signatures, scheduling, validity bounds), so a run outside them
        is a run it was not designed for (a user's reference in K for a sensor in degC
        ran the reactor to its limit, and simulate said only "wrote 1800 samples").
        Inputs are left out: a controller's command beyond its nominal range is common,
        and so is the first RMS window, the start-up transient (the cylinder's speed
        overshoots its range for 43 ms from rest)."""
        out = []
        skip = int(self.model.fdi.get("window", 100)) if self.model.fdi else 0
        for values, variables in ((self.x[skip:], self.model.states),):
            for j, v in enumerate(variables):
                if not v.range:
                    continue
                lo, hi = (float(r) for r in v.range)
                col = values[:, j][np.isfinite(values[:, j])]
                if not col.size:
                    continue
                vmin, vmax = float(col.min()), float(col.max())
                slack = 0.05 * (hi - lo)
                if vmin < lo - slack or vmax > hi + slack:
                    out.append(f"{v.name} {vmin:.4g} to {vmax:.4g}"
                               + (f" {v.unit}" if v.unit else "")
                               + f" against [{lo:g}, {hi:g}]")
        return out

    def columns(self) -> dict:
        """Log columns (rig format) -> values."""
        cols = {"t": self.t}
        for j, s in enumerate(self.model.inputs):
            cols[s.column] = self.u[:, j]
        for j, o in enumerate(self.model.outputs):
            cols[o.column] = self.y[:, j]
        spec = simulation_spec(self.model)
        if spec.legacy:
            cols[self.model.simulation.get("reference_column", "xref")] = self.ref
        else:
            for j, c in enumerate(spec.controllers):
                if c.reference is not None:
                    cols[c.reference_column] = self.ref[:, j]
        return cols


def _settings(model: Model):
    simulation_spec(model)
    return dict(model.simulation)


def _plant_functions(model: Model, effects, substeps: int, dt: float):
    from fdigen.backends.casadi_backend.convert import sympy_to_casadi

    sim = _settings(model)
    n, m, p = len(model.states), len(model.inputs), len(model.outputs)
    nf = len(model.faults)
    eff_params = [sp.Symbol(k, real=True) for e in effects for k in e.parameters]
    x = ca.SX.sym("x", n)
    u = ca.SX.sym("u", m)
    f = ca.SX.sym("f", nf)
    par = ca.SX.sym("p", len(model.parameters))
    ep = ca.SX.sym("ep", len(eff_params))
    noise = ca.SX.sym("noise", p)
    ref = ca.SX.sym("ref")
    base = {}
    base.update({s.symbol: x[i] for i, s in enumerate(model.states)})
    base.update({s.symbol: u[i] for i, s in enumerate(model.inputs)})
    base.update({s: f[i] for i, s in enumerate(model.f_sym)})
    base.update({s: par[i] for i, s in enumerate(model.p)})
    base.update({s: ep[i] for i, s in enumerate(eff_params)})
    rhs = model.f(with_faults=True)
    out = model.h(with_faults=True)
    for e in effects:
        term = model.expand(e.term)
        if e.target in {s.name for s in model.states}:
            k = model.state_index(e.target)
            rhs[k] = rhs[k] + term
        else:
            k = model.output_index(e.target)
            out[k] = out[k] + term
    memo = {}
    f_sx = ca.vertcat(*[sympy_to_casadi(rhs[i], base, memo=memo) for i in range(n)])
    h_sx = ca.vertcat(*[sympy_to_casadi(out[i], base, memo=memo) for i in range(p)])
    fun = ca.Function("f", [x, u, f, par, ep], [f_sx])
    meas = ca.Function("h", [x, u, f, par, ep], [h_sx])

    # controllers: one command per input, PI integrators carried in the state
    spec = simulation_spec(model)
    n_int = integrator_count(spec)
    nc = len(spec.controllers)
    ref = ca.SX.sym("ref", nc)
    integ = ca.SX.sym("integ", n_int)

    # one sample: measure, control, integrate. An output with a direct feedthrough
    # (a battery's terminal voltage: OCV - R0*I) reads the input in effect: the
    # controller sees the sample taken under the input held from the previous sample
    # (no algebraic loop), the log the output under the command it records beside it,
    # y_k = h(x_k, u_k) as the FDI core and discover read a log's rows
    held = ca.SX.sym("held", p)
    stuck = ca.SX.sym("stuck", p)
    u_prev = ca.SX.sym("u_prev", m)

    def measured(u_in):
        y = meas(x, u_in, f, par, ep) + noise
        return ca.vertcat(*[ca.if_else(stuck[i] > 0.5, held[i], y[i]) for i in range(p)])

    u_cmd, integ_next = control_step(model, spec, measured(u_prev), ref, integ, dt)
    y_k = measured(u_cmd)
    h = dt / substeps
    lo = [None if s.limits is None else s.limits for s in model.states]
    lim = []
    for i, s in enumerate(model.states):
        if s.limits is None:
            lim.append(None)
        else:
            lim.append(tuple(sympy_to_casadi(b, base, memo={}) for b in s.limits))
    del lo
    xs = x
    nan = ca.SX.zeros(n)
    for _ in range(substeps):
        k1 = fun(xs, u_cmd, f, par, ep)
        k2 = fun(xs + h / 2 * k1, u_cmd, f, par, ep)
        k3 = fun(xs + h / 2 * k2, u_cmd, f, par, ep)
        k4 = fun(xs + h * k3, u_cmd, f, par, ep)
        for k in (k1, k2, k3, k4):     # NaN <= inf is false (CasADi folds k != k to 0)
            nan = nan + ca.logic_not(k <= ca.inf)
        xs = xs + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xs = ca.vertcat(*[xs[i] if lim[i] is None else ca.fmin(ca.fmax(xs[i], lim[i][0]),
                                                                   lim[i][1]) for i in range(n)])
    step = ca.Function("plant_step", [ca.vertcat(x, held, integ, u_prev),
                                      ca.vertcat(noise, f, ref, stuck), par, ep],
                       [ca.vertcat(xs, y_k, integ_next, u_cmd), ca.vertcat(u_cmd, y_k, nan)])
    return step, eff_params


def _operating_inputs(model: Model) -> np.ndarray:
    """The inputs at the operating point (the input held before the first sample)."""
    return np.array([float(model.operating_point.get(v.name, 0.0)) for v in model.inputs])


def _plant_key(model: Model, effects, substeps: int, dt: float) -> tuple:
    """Identity of a simulated plant: everything :func:`_plant_functions` reads.

    That is the model without its ``[simulation]`` table, and of the table only its
    controllers' laws: the demand enters the step as an input, so the runs of a campaign
    (each with its own varied demand, start and duration) share one compiled step where
    each built its own (0.15 s per cylinder run, a third of its simulation).
    """
    from fdigen.model.model_file import model_hash

    laws = tuple(dataclasses.replace(c, reference=None, reference_column="")
                 for c in simulation_spec(model).controllers)
    return (model_hash(dataclasses.replace(model, simulation={})), repr(laws),
            tuple(sp.srepr(s.limits) for s in model.states),
            tuple((e.name, e.target, sp.srepr(e.term), tuple(e.parameters)) for e in effects),
            int(substeps), float(dt))


def _plant_runner(model: Model, effects, substeps: int, dt: float):
    """The chunk function ``mapaccum(plant_step, CHUNK_SAMPLES)`` (a
    :class:`~fdigen.sim.compiled_plant.PlantChunks`: compiled once the process simulates
    the plant often) and the effect symbols.

    Built once per plant identity (:func:`_plant_key`) and kept in a small LRU cache: the
    construction of the CasADi graph costs several times its evaluation.
    """
    key = _plant_key(model, effects, substeps, dt)
    hit = _PLANT_CACHE.get(key)
    if hit is not None:
        _PLANT_CACHE.move_to_end(key)
        return hit
    step, eff_params = _plant_functions(model, tuple(effects), substeps, dt)
    runner = (PlantChunks(step.mapaccum("plant_run", CHUNK_SAMPLES)), eff_params)
    _PLANT_CACHE[key] = runner
    while len(_PLANT_CACHE) > _PLANT_CACHE_SIZE:
        _PLANT_CACHE.popitem(last=False)
    return runner


def reference_signal(model: Model, t: np.ndarray) -> np.ndarray:
    """The demand of the ``[simulation]`` table, an expression of ``t``.

    One column per controller, shape ``(K, controllers)``, in the several-loops form (a
    controller without a reference gets zeros); shape ``(K,)`` in the single-loop form.
    """
    spec = simulation_spec(model)
    if spec.legacy:
        return _signal(model, spec.controllers[0].reference, t, "simulation.reference")
    return np.stack([np.zeros(t.shape) if c.reference is None else
                     _signal(model, c.reference, t,
                             f"simulation.controllers.{c.name}.reference")
                     for c in spec.controllers], axis=1)


def _signal(model: Model, text: str, t: np.ndarray, fld: str) -> np.ndarray:
    tt = sp.Symbol("t", real=True)
    expr = parse_expression(text, {"t": tt, "pi": sp.pi}, source=model.source, field=fld)
    fn = safe_lambdify([tt], expr, modules="numpy")
    return np.broadcast_to(np.asarray(fn(t), dtype=float), t.shape).copy()


def fault_profile(model: Model, t: np.ndarray, faults) -> np.ndarray:
    """Fault magnitudes per sample, shape (K, number of model faults)."""
    names = [f.name for f in model.faults]
    out = np.zeros((len(t), len(names)))
    for ev in faults:
        if ev.name not in names:
            raise FdigenError(f"unknown fault '{ev.name}' (model faults: {', '.join(names)})")
        if ev.stuck:
            continue
        j = names.index(ev.name)
        on = t >= ev.t0
        out[on, j] += ev.size * ((t[on] - ev.t0) if ev.ramp else 1.0)
    return out


def simulate(model: Model, duration: float | None = None, *, faults=(), effects=(),
             parameters: dict | None = None, noise: bool = True, seed: int = 0,
             substeps: int | None = None, dt: float | None = None,
             initial: dict | None = None) -> SimulationResult:
    """Simulate the closed loop of ``model``.

    Parameters
    ----------
    model : Model
    duration : float, optional
        Seconds; default ``simulation.duration``, else a length from the plant
        (:func:`fdigen.sim.run_length.default_duration`).
    faults : sequence of FaultEvent
    effects : sequence of Effect
        Terms the nominal model lacks, switched on in the simulated plant.
    parameters : dict, optional
        Plant parameter values that differ from the model's defaults.
    noise : bool
        Add white Gaussian sensor noise (each output's ``noise_std``).
    seed : int
    substeps : int, optional
        RK4 sub-steps per sample (default ``simulation.substeps``, else the least stable
        count and at least 10: :func:`fdigen.sim.substeps.simulation_substeps`); an
        unstable count is refused.
    dt : float, optional
        Sample time (default ``fdi.sample_time``).
    initial : dict, optional
        Initial state values (default: the operating point).
    """
    sim = _settings(model)
    dt = float(dt or model.fdi.get("sample_time", 1e-3))
    if duration is None:
        duration = default_duration(model)[0]
    duration = float(duration)
    if not math.isfinite(duration) or duration / dt > MAX_SAMPLES:
        raise FdigenError(f"a simulation of {duration:g} s at {dt:g} s is "
                          f"{duration / dt:.3g} samples: at most {MAX_SAMPLES:.0e}; a "
                          "shorter --duration (or [simulation] duration)")
    substeps = simulation_substeps(model, dt, substeps)
    K = int(round(duration / dt))
    t = np.arange(K) * dt
    run, eff_params = _plant_runner(model, tuple(effects), substeps, dt)
    run.start_run()
    values = {q.name: q.value for q in model.parameters}
    values.update(parameters or {})
    par = np.array([values[q.name] for q in model.parameters])
    ep_values = {k: v for e in effects for k, v in e.parameters.items()}
    ep = np.array([ep_values[s.name] for s in eff_params])
    rng = np.random.default_rng(seed)
    sig = np.array([o.noise_std for o in model.outputs])
    nz = rng.standard_normal((K, len(sig))) * sig if noise else np.zeros((K, len(sig)))
    prof = fault_profile(model, t, faults)
    ref = reference_signal(model, t)
    x0 = dict(model.operating_point)
    # an interval of [simulation.initial]: drawn per run, from a stream of the seed's own
    # (the noise's draws unchanged)
    starts = np.random.default_rng([int(seed), 1])
    x0.update({k: initial_value(v, starts) for k, v in sim.get("initial", {}).items()})
    x0.update(initial or {})
    xs0 = []
    for s in model.states:
        v = x0[s.name]
        if isinstance(v, str):
            v = float(parse_expression(v, {q.name: q.symbol for q in model.parameters},
                                       source=model.source, field="simulation.initial")
                      .xreplace(model.parameter_values))
        xs0.append(float(v))
    stuck = np.zeros((K, len(model.outputs)))
    for ev in faults:
        if ev.stuck:
            fault = model.fault(ev.name)
            if fault.location != "sensor":
                raise FdigenError(f"fault '{ev.name}' is not a sensor fault: it cannot stick")
            for out in model.outputs_reached(fault):
                stuck[t >= ev.t0, model.output_index(out)] = 1.0
    refs = ref[:, None] if ref.ndim == 1 else ref
    drive = np.hstack([nz, prof, refs, stuck])
    chunks = -(-K // CHUNK_SAMPLES)
    padded = np.zeros((chunks * CHUNK_SAMPLES, drive.shape[1]))
    padded[:K] = drive
    n_int = integrator_count(simulation_spec(model))
    carry = np.concatenate([xs0, np.zeros(len(model.outputs) + n_int),
                            _operating_inputs(model)])
    x_parts, uy_parts = [], []
    for c in range(chunks):
        x_c, uy_c = run(carry, padded[c * CHUNK_SAMPLES:(c + 1) * CHUNK_SAMPLES].T, par, ep)
        x_c = np.array(x_c)
        carry = x_c[:, -1]
        x_parts.append(x_c.T)
        uy_parts.append(np.array(uy_c).T)
    x_traj = np.vstack(x_parts)[:K, :len(model.states)]
    uy = np.vstack(uy_parts)[:K]
    m, p = len(model.inputs), len(model.outputs)
    x_before = np.vstack([np.array(xs0)[None, :], x_traj[:-1]])
    return SimulationResult(t, uy[:, :m], uy[:, m:m + p], x_before, ref, prof, model,
                            uy[:, m + p:])

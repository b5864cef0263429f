"""Six closed-loop legs of the platform, with the FDI bank and the supervisor in the loop.

Every leg is the single-cylinder plant of :mod:`fdigen.sim.plant` (the model file's
nonlinear equations with fault terms, RK4 with sub-steps, states clamped to their
limits, white Gaussian sensor noise) under its own copy of the model file's controller
(``[simulation].controller``), with its own demand ``xref_i(t)`` (the inverse kinematics
of the pose demand, :mod:`fdigen.platform.demands`), its own noise sequence, its own
parameters and its own faults. One CasADi ``Function`` does one sample of one leg
(measure, control, integrate); it is mapped over the six legs, so a sample of the whole
platform is one call.

With a bank (:class:`fdigen.platform.supervisor.PlatformFdi`, or the generated C bank
:class:`fdigen.platform.codegen.PlatformCFdi`), the loop is closed through the FDI, as on
the real platform: at sample ``k`` each leg measures ``y[k]`` and its controller computes
``u[k]`` from ``xref[k]``; the bank runs on ``(u[k], y[k])``; an accommodated leg's
controller uses, from the next sample on, the FDI's ``position_for_control`` (the
voter's output) instead of its primary sensor, one sample late; once the supervisor
starts the safety sequence, its demands replace the motion demands. Without a bank the
whole run is one CasADi ``mapaccum`` call (the motion demands throughout).

Kinematics are not simulated: the platform's legs are position-controlled independently
(as the paper's rig: one position loop per cylinder, the pose achieved by a supervisory
controller), and the leg loads of the moving plate are in the cylinder model's moving
mass.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from fdigen.errors import FdigenError
from fdigen.model.expression import parse_expression
from fdigen.model.model import Model
from fdigen.model.simulation_spec import initial_value
from fdigen.platform.demands import MotionSequence, leg_demands
from fdigen.platform.geometry import NLEGS, PlatformGeometry, default_geometry
from fdigen.platform.supervisor import ACCOMMODATE
from fdigen.sim.plant import FaultEvent, fault_profile


#: Samples a platform run holds at most. A sample of the six legs takes about 2.7 kB of
#: arrays (drive, noise, fault profile, states, inputs and outputs of six legs, their
#: logs' text): 1e6 samples are some 3 GB and 1000 s at 1 ms. ``--duration 20000`` asked
#: for 2e7 samples and was killed for memory (attack round 13); the single-leg
#: simulator's cap (:data:`fdigen.sim.plant.MAX_SAMPLES`, 1e7) is for one leg.
MAX_SAMPLES = 1_000_000


def sample_time_of(model: Model) -> float:
    """The sample time of a platform run: the model's ``[fdi] sample_time`` (1 ms)."""
    return float(dict(model.fdi).get("sample_time", 1e-3))


class RunLengthError(FdigenError):
    """A platform run too long to hold (or shorter than two samples); ``option`` names
    what sets its length: ``"duration"``, or ``"segment"`` when the duration is one pass
    of the motion sequence."""

    def __init__(self, message: str, option: str):
        super().__init__(message)
        self.option = option


def run_samples(model: Model, duration: float | None, motion: MotionSequence) -> int:
    """Samples of a run of ``duration`` seconds (default one pass of ``motion``), checked
    against :data:`MAX_SAMPLES` before any array is made.

    Raises
    ------
    RunLengthError
        Naming the duration (or, for one pass of the motion, the segment) and the limit.
    """
    dt = sample_time_of(model)
    if duration is None:
        T, option = float(motion.duration), "segment"
        what = (f"one pass of the motion sequence ({len(motion.order)} x "
                f"{motion.segment:g} s segments = {T:g} s)")
        advice = "a shorter segment, or a duration"
    else:
        T, option = float(duration), "duration"
        what = f"a run of {T:g} s"
        advice = "a shorter duration"
    n = T / dt if np.isfinite(T) else np.inf
    if not n <= MAX_SAMPLES:
        raise RunLengthError(f"{what} at {dt:g} s is {n:.3g} samples: a platform run holds "
                             f"at most {MAX_SAMPLES:.0e} ({MAX_SAMPLES * dt:g} s); "
                             f"{advice}", option)
    K = int(round(T / dt))
    if K < 2:
        raise RunLengthError(f"duration {T} s is shorter than two samples", option)
    return K


@dataclass(frozen=True)
class LegFault:
    """A fault of the cylinder model on one leg (``leg`` 1..6)."""

    leg: int
    event: FaultEvent

    def __post_init__(self):
        if not 1 <= int(self.leg) <= NLEGS:
            raise FdigenError(f"leg must be 1..{NLEGS}, got {self.leg}")

    def to_dict(self) -> dict:
        e = self.event
        return {"leg": int(self.leg), "kind": e.name, "t0": e.t0, "size": e.size,
                "ramp": e.ramp, "stuck": bool(getattr(e, "stuck", False))}


def parse_leg_fault(text: str) -> LegFault:
    """``LEG:NAME@T0=SIZE``, ``LEG:NAME@T0=RATE/s`` (a drift) or ``LEG:NAME@T0=stuck``
    (a sensor holding its last reading), legs 1..6.

    Raises
    ------
    FdigenError
        On any other form, naming the text.
    """
    try:
        leg, rest = text.split(":", 1)
        name, rest = rest.split("@", 1)
        t0, size = rest.split("=", 1)
        start = float(t0)
        if not (np.isfinite(start) and start >= 0):
            raise ValueError(t0)
        if size.strip() == "stuck":
            return LegFault(int(leg), FaultEvent(name.strip(), start, 0.0, stuck=True))
        ramp = size.strip().endswith("/s")
        size = float(size.strip()[:-2] if ramp else size)
        if not np.isfinite(size):
            raise ValueError(size)
        return LegFault(int(leg), FaultEvent(name.strip(), start, size, ramp))
    except ValueError:
        raise FdigenError(f"expected LEG:NAME@T0=SIZE, LEG:NAME@T0=RATE/s or "
                          f"LEG:NAME@T0=stuck with LEG in "
                          f"1..{NLEGS}, got {text!r}") from None


def primary_output_index(model: Model) -> int:
    """The output the controller uses and accommodation replaces: the voter's third
    channel (the primary sensor), else the first output."""
    voter = dict(model.fdi).get("voter")
    names = [o.name for o in model.outputs]
    if voter and len(voter.get("channels", [])) == 3 and voter["channels"][2] in names:
        return names.index(voter["channels"][2])
    return 0


def leg_step_function(model: Model, substeps: int, dt: float) -> ca.Function:
    """One sample of one leg: ``([x; held], drive, p) -> ([x_next; y], [u; y])``.

    ``drive = [noise (ny); faults (nf); xref; pos; acc; stuck (ny)]``: sensor noise,
    fault magnitudes, the demand, the accommodated position with its switch (``acc = 1``:
    the controller reads ``pos`` in place of the primary sensor), and which sensors are
    stuck. The measurement is ``y = h(x, f) + noise``, or the reading ``held`` of the
    sample before for a stuck sensor (as :mod:`fdigen.sim.plant`); the command is
    ``u = law(y, xref)`` (the model file's controller), and ``x_next`` is ``substeps``
    RK4 steps of ``f(x, u, f)`` with the states clamped to their limits after each. The
    readings are carried in the state so that a sensor can stick.
    """
    from fdigen.backends.casadi_backend.convert import sympy_to_casadi

    sim = dict(model.simulation)
    for key in ("controller", "input"):
        if key not in sim:
            raise FdigenError(f"{model.source}: [simulation] needs '{key}' for closed-loop runs")
    n, m, p = len(model.states), len(model.inputs), len(model.outputs)
    nf, npar = len(model.faults), len(model.parameters)
    x = ca.SX.sym("x", n)
    u = ca.SX.sym("u", m)
    f = ca.SX.sym("f", nf)
    par = ca.SX.sym("p", npar)
    noise = ca.SX.sym("noise", p)
    ref, pos, acc = ca.SX.sym("xref"), ca.SX.sym("pos"), ca.SX.sym("acc")
    base = {s.symbol: x[i] for i, s in enumerate(model.states)}
    base.update({s.symbol: u[i] for i, s in enumerate(model.inputs)})
    base.update({s: f[i] for i, s in enumerate(model.f_sym)})
    base.update({s: par[i] for i, s in enumerate(model.p)})
    rhs, out = model.f(with_faults=True), model.h(with_faults=True)
    memo = {}
    fun = ca.Function("f", [x, u, f, par],
                      [ca.vertcat(*[sympy_to_casadi(rhs[i], base, memo=memo) for i in range(n)])])
    meas = ca.Function("h", [x, u, f, par],
                       [ca.vertcat(*[sympy_to_casadi(out[i], base, memo=memo)
                                     for i in range(p)])])
    syms = {o.name: o.symbol for o in model.outputs}
    ref_name = sim.get("reference_symbol", "xref")
    import sympy as sp
    syms[ref_name] = sp.Symbol(ref_name, real=True)
    law = parse_expression(sim["controller"], syms, source=model.source,
                           field="simulation.controller")
    held = ca.SX.sym("held", p)
    stuck = ca.SX.sym("stuck", p)
    y = meas(x, ca.DM.zeros(m), f, par) + noise
    y = ca.vertcat(*[ca.if_else(stuck[i] > 0.5, held[i], y[i]) for i in range(p)])
    primary = primary_output_index(model)
    ym = [y[i] for i in range(p)]
    ym[primary] = ca.if_else(acc > 0.5, pos, y[primary])
    cmap = {o.symbol: ym[i] for i, o in enumerate(model.outputs)}
    cmap[syms[ref_name]] = ref
    u_cmd = ca.SX.zeros(m)
    u_cmd[[s.name for s in model.inputs].index(sim["input"])] = sympy_to_casadi(law, cmap)
    lim = [None if s.limits is None else
           tuple(sympy_to_casadi(b, base, memo={}) for b in s.limits) for s in model.states]
    h = dt / substeps
    xs = x
    for _ in range(substeps):
        k1 = fun(xs, u_cmd, f, par)
        k2 = fun(xs + h / 2 * k1, u_cmd, f, par)
        k3 = fun(xs + h / 2 * k2, u_cmd, f, par)
        k4 = fun(xs + h * k3, u_cmd, f, par)
        xs = xs + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xs = ca.vertcat(*[xs[i] if lim[i] is None else
                          ca.fmin(ca.fmax(xs[i], lim[i][0]), lim[i][1]) for i in range(n)])
    return ca.Function("leg_step", [ca.vertcat(x, held),
                                     ca.vertcat(noise, f, ref, pos, acc, stuck), par],
                       [ca.vertcat(xs, y), ca.vertcat(u_cmd, y)])


#: Samples per call of the compiled whole-run function (the last chunk is padded).
CHUNK = 500

_SIX_LEG_CACHE: dict = {}


class SixLegs:
    """One sample of the six legs, ``(x (6, nx), drive (6, nd), p (6, np)) -> (x_next,
    [u; y])``, and whole runs, compiled to C when a compiler works.

    The single-leg :func:`leg_step_function` is mapped over the six legs (``map``), and
    for open-loop runs accumulated over :data:`CHUNK` samples (``mapaccum``); CasADi's
    code generator writes both as C, which :func:`fdigen.backends.c.loader.
    build_shared_library` compiles into a cached shared library, called through ctypes
    (a sample costs a few microseconds instead of CasADi's interpreter's hundreds).
    Without a compiler the CasADi interpreter runs the same functions.
    """

    def __init__(self, model: Model, substeps: int, dt: float, compiled: bool = True):
        leg = leg_step_function(model, substeps, dt)
        self.nx = leg.size1_in(0)
        self.nd = leg.size1_in(1)
        self.np = leg.size1_in(2)
        self.ny_out = leg.size1_out(1)
        six = leg.map(NLEGS)
        X = ca.MX.sym("x", self.nx, NLEGS)
        D = ca.MX.sym("d", self.nd, NLEGS)
        P = ca.MX.sym("p", self.np, NLEGS)
        DC = ca.MX.sym("d", self.nd, NLEGS * CHUNK)
        self.step_fn = ca.Function("platform_legs_step", [X, D, P], six(X, D, P))
        self.chunk_fn = ca.Function("platform_legs_chunk", [X, DC, P],
                                    six.mapaccum(CHUNK)(X, DC, P))
        self.lib = None
        if compiled:
            try:
                self._compile()
            except Exception:  # no compiler: the interpreter runs the same functions
                self.lib = None

    def _compile(self):
        import ctypes
        import os
        import tempfile

        from fdigen.backends.c.loader import build_shared_library

        cg = ca.CodeGenerator("platform_legs", {"with_header": False})
        cg.add(self.step_fn)
        cg.add(self.chunk_fn)
        with tempfile.TemporaryDirectory(prefix="fdigen-legs-") as tmp:
            cg.generate(tmp + os.sep)
            src = Path(tmp, "platform_legs.c").read_text()
        path = build_shared_library({"platform_legs.c": src}, "platform_legs")
        lib = ctypes.CDLL(str(path))
        ci = ctypes.c_longlong
        if lib.platform_legs_casadi_int_size() != ctypes.sizeof(ci):
            raise RuntimeError("unexpected casadi_int size")
        self._calls = {}
        for name, fn in (("step", self.step_fn), ("chunk", self.chunk_fn)):
            sz = [ci() for _ in range(4)]
            getattr(lib, f"platform_legs_{name}_work")(*(ctypes.byref(v) for v in sz))
            n_arg, n_res, n_iw, n_w = (max(int(v.value), 1) for v in sz)
            ins = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
            outs = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
            dp = ctypes.POINTER(ctypes.c_double)
            arg = (dp * n_arg)(*[a.ctypes.data_as(dp) for a in ins])
            res = (dp * n_res)(*[o.ctypes.data_as(dp) for o in outs])
            iw = (ci * n_iw)()
            w = (ctypes.c_double * n_w)()
            f = getattr(lib, f"platform_legs_{name}")
            f.restype = ctypes.c_int
            self._calls[name] = (f, ins, outs, arg, res, iw, w)
        self.lib = lib

    def _call(self, name, *inputs):
        f, ins, outs, arg, res, iw, w = self._calls[name]
        for buf, value in zip(ins, inputs):
            buf[:] = value.ravel()
        if f(arg, res, iw, w, 0) != 0:
            raise RuntimeError(f"platform_legs_{name} failed")
        return outs

    def step(self, x, drive, par):
        """One sample: ``x`` (6, nx), ``drive`` (6, nd), ``par`` (6, np) ->
        ``x_next`` (6, nx), ``[u; y]`` (6, nu + ny)."""
        if self.lib is None:
            xn, uy = self.step_fn(x.T, drive.T, par.T)
            return np.array(xn).T, np.array(uy).T
        xn, uy = self._call("step", x, drive, par)
        return xn.reshape(NLEGS, self.nx).copy(), uy.reshape(NLEGS, self.ny_out).copy()

    def run(self, x0, drive, par):
        """``K`` samples: ``x0`` (6, nx), ``drive`` (K, 6, nd) -> states after each sample
        (K, 6, nx) and ``[u; y]`` (K, 6, nu + ny)."""
        K = drive.shape[0]
        xs = np.zeros((K, NLEGS, self.nx))
        uy = np.zeros((K, NLEGS, self.ny_out))
        x = np.asarray(x0, dtype=float)
        for k0 in range(0, K, CHUNK):
            n = min(CHUNK, K - k0)
            d = np.zeros((CHUNK, NLEGS, self.nd))
            d[:n] = drive[k0:k0 + n]
            d[n:] = drive[k0 + n - 1]  # padding, discarded
            if self.lib is None:
                a, b = self.chunk_fn(x.T, d.reshape(CHUNK * NLEGS, self.nd).T, par.T)
                a = np.array(a).T.reshape(CHUNK, NLEGS, self.nx)
                b = np.array(b).T.reshape(CHUNK, NLEGS, self.ny_out)
            else:
                a, b = self._call("chunk", x, d, par)
                a = a.reshape(CHUNK, NLEGS, self.nx)
                b = b.reshape(CHUNK, NLEGS, self.ny_out)
            xs[k0:k0 + n], uy[k0:k0 + n] = a[:n], b[:n]
            x = a[n - 1].copy()
        return xs, uy


def six_legs(model: Model, substeps: int, dt: float) -> SixLegs:
    """:class:`SixLegs` of a model, built once per process (per model hash and settings)."""
    from fdigen.model.model_file import model_hash

    key = (model_hash(model), substeps, dt)
    if key not in _SIX_LEG_CACHE:
        _SIX_LEG_CACHE[key] = SixLegs(model, substeps, dt)
    return _SIX_LEG_CACHE[key]


@dataclass(frozen=True)
class PlatformRun:
    """A simulated run of the six legs.

    Attributes
    ----------
    t : numpy.ndarray, (K,)
    pose : numpy.ndarray, (K, 6)
        The motion's pose demand (relative to home).
    motion_demand : numpy.ndarray, (K, 6)
        Its inverse kinematics: the legs' piston demands [m].
    xref : numpy.ndarray, (K, 6)
        The demands the legs' controllers used (the safety sequence's after a stop).
    u : numpy.ndarray, (K, 6, nu)
    y : numpy.ndarray, (K, 6, ny)
    x : numpy.ndarray, (K, 6, nx)
        True states at each sample.
    fault_profile : numpy.ndarray, (K, 6, nf)
    faults : tuple of LegFault
    bank : dict or None
        The online bank's record (``fault_class``, ``decision`` (K, 6), ``action``,
        ``faulty_leg``, ``safety`` (K,), ``demand_next`` (K, 6), ``trigger_sample``),
        or None for an open-loop run.
    """

    t: np.ndarray
    pose: np.ndarray
    motion_demand: np.ndarray
    xref: np.ndarray
    u: np.ndarray
    y: np.ndarray
    x: np.ndarray
    fault_profile: np.ndarray
    faults: tuple
    bank: dict | None
    model: Model
    geometry: PlatformGeometry
    motion: MotionSequence
    seed: int
    noise: bool
    parameters: tuple

    def leg_columns(self, leg: int) -> dict:
        """Log columns of leg ``leg`` (1..6) in the rig format: t, u, x, x2, pp, pn, xref."""
        i = leg - 1
        cols = {"t": self.t}
        for j, s in enumerate(self.model.inputs):
            cols[s.column] = self.u[:, i, j]
        for j, o in enumerate(self.model.outputs):
            cols[o.column] = self.y[:, i, j]
        cols[self.model.simulation.get("reference_column", "xref")] = self.xref[:, i]
        return cols


def _leg_parameters(model: Model, parameters) -> tuple:
    values = {q.name: float(q.value) for q in model.parameters}
    if parameters is None or isinstance(parameters, dict):
        per_leg = [dict(parameters or {})] * NLEGS
    else:
        per_leg = list(parameters)
        if len(per_leg) != NLEGS:
            raise FdigenError(f"parameters: one dict per leg ({NLEGS}) expected")
    out = []
    for i, d in enumerate(per_leg):
        unknown = set(d) - set(values)
        if unknown:
            raise FdigenError(f"leg {i + 1}: unknown parameter(s) {sorted(unknown)}")
        v = dict(values)
        v.update({k: float(x) for k, x in d.items()})
        out.append(v)
    return tuple(out)


def _initial_state(model: Model, values: dict, x_demand: float) -> list:
    sim = dict(model.simulation)
    x0 = dict(model.operating_point)
    # an interval of [simulation.initial]: its midpoint (the legs start alike)
    x0.update({k: initial_value(v) for k, v in sim.get("initial", {}).items()})
    pos_state = model.outputs[primary_output_index(model)].expr
    out = []
    psyms = {q.name: q.symbol for q in model.parameters}
    subs = {q.symbol: values[q.name] for q in model.parameters}
    for s in model.states:
        if s.symbol == pos_state:
            out.append(float(x_demand))
            continue
        v = x0[s.name]
        if isinstance(v, str):
            v = float(parse_expression(v, psyms, source=model.source,
                                       field="simulation.initial").xreplace(subs))
        out.append(float(v))
    return out


def simulate_platform(model: Model, duration: float | None = None, *,
                      geometry: PlatformGeometry | None = None,
                      motion: MotionSequence | None = None, faults=(), seed: int = 0,
                      noise: bool = True, parameters=None, substeps: int | None = None,
                      bank=None) -> PlatformRun:
    """Simulate the six legs of the platform in closed loop.

    Parameters
    ----------
    model : Model
        The single-cylinder model (plant, controller, sample time).
    duration : float, optional
        Seconds; default one pass of the motion sequence.
    geometry : PlatformGeometry, optional
        Default :func:`~fdigen.platform.geometry.default_geometry`.
    motion : MotionSequence, optional
        Default: the paper's sequence (:class:`~fdigen.platform.demands.MotionSequence`).
    faults : sequence of LegFault
        Any fault of the model, on any leg, any number.
    seed : int
        Seed of the sensor noise (independent sequences per leg).
    noise : bool
    parameters : dict or sequence of 6 dict, optional
        Plant parameter values differing from the model's (all legs, or per leg).
    substeps : int, optional
        RK4 sub-steps per sample (default ``simulation.substeps`` or 10).
    bank : object, optional
        The FDI bank in the loop: ``reset()`` and ``step(u, y, demand) -> dict`` as
        :class:`~fdigen.platform.supervisor.PlatformFdi`. None: open loop (no FDI, no
        supervisor; the motion demands throughout).

    Returns
    -------
    PlatformRun

    Raises
    ------
    ReachabilityError
        If the motion demand leaves a leg's stroke.
    RunLengthError
        If the run would hold more than :data:`MAX_SAMPLES` samples, or fewer than two.
    """
    geometry = geometry or default_geometry()
    motion = motion or MotionSequence()
    sim = dict(model.simulation)
    dt = sample_time_of(model)
    K = run_samples(model, duration, motion)        # at most MAX_SAMPLES, before any array
    substeps = int(substeps or sim.get("substeps", 10))
    t = np.arange(K) * dt
    pose, xm = leg_demands(geometry, motion, t)
    n, m, p = len(model.states), len(model.inputs), len(model.outputs)
    nf = len(model.faults)
    values = _leg_parameters(model, parameters)
    par = np.array([[v[q.name] for q in model.parameters] for v in values]).T  # (np, 6)
    faults = tuple(faults)
    known = [f.name for f in model.faults]
    for lf in faults:
        if lf.event.name not in known:
            raise FdigenError(f"leg {lf.leg}: the model {model.name} has no fault "
                              f"'{lf.event.name}' (its faults: {', '.join(known)})")
    prof = np.zeros((K, NLEGS, nf))
    for i in range(NLEGS):
        prof[:, i, :] = fault_profile(model, t, [lf.event for lf in faults if lf.leg == i + 1])
    rng = np.random.default_rng(seed)
    sig = np.array([o.noise_std for o in model.outputs])
    nz = (rng.standard_normal((K, NLEGS, p)) * sig) if noise else np.zeros((K, NLEGS, p))
    x0 = np.array([_initial_state(model, values[i], xm[0, i]) + [0.0] * p
                   for i in range(NLEGS)])
    legs = six_legs(model, substeps, dt)
    par6 = par.T.copy()                                        # (6, np)
    nd = p + nf + 3 + p
    drive = np.zeros((K, NLEGS, nd))
    drive[:, :, :p] = nz
    drive[:, :, p:p + nf] = prof
    for lf in faults:
        if getattr(lf.event, "stuck", False):
            fault = model.fault(lf.event.name)
            if fault.location != "sensor":
                raise FdigenError(f"fault '{fault.name}' is not a sensor fault: it cannot stick")
            for out in model.outputs_reached(fault):
                drive[t >= lf.event.t0, lf.leg - 1, p + nf + 3 + model.output_index(out)] = 1
    if bank is None:
        drive[:, :, p + nf] = xm
        xs, uy = legs.run(x0, drive, par6)
        x_before = np.concatenate([x0[None], xs[:-1]], axis=0)[..., :n]
        return PlatformRun(t, pose, xm, xm.copy(), uy[..., :m], uy[..., m:], x_before, prof,
                           faults, None, model, geometry, motion, seed, noise, values)

    bank.reset()
    U = np.zeros((K, NLEGS, m))
    Y = np.zeros((K, NLEGS, p))
    X = np.zeros((K, NLEGS, n))
    xref = np.zeros((K, NLEGS))
    rec = {"fault_class": np.zeros((K, NLEGS), dtype=np.int64),
           "decision": np.zeros((K, NLEGS), dtype=np.int64),
           "action": np.zeros(K, dtype=np.int64), "faulty_leg": np.full(K, -1, dtype=np.int64),
           "safety": np.zeros(K, dtype=bool), "demand_next": np.zeros((K, NLEGS))}
    state = x0
    pos = np.zeros(NLEGS)
    acc = np.zeros(NLEGS)
    demand = xm[0].copy()
    trigger = None
    for k in range(K):
        X[k] = state[:, :n]
        xref[k] = demand
        dk = drive[k]
        dk[:, p + nf] = demand
        dk[:, p + nf + 1] = pos
        dk[:, p + nf + 2] = acc
        state, uy = legs.step(state, dk, par6)
        U[k], Y[k] = uy[:, :m], uy[:, m:]
        out = bank.step(U[k], Y[k], demand)
        rec["fault_class"][k] = out["fault_class"]
        rec["decision"][k] = out["decision"]
        rec["action"][k] = out["action"]
        rec["faulty_leg"][k] = out["faulty_leg"]
        rec["safety"][k] = out["safety"]
        rec["demand_next"][k] = out["demand"]
        if out["safety"] and trigger is None:
            trigger = k
        acc = (np.asarray(out["leg_action"]) == ACCOMMODATE).astype(float)
        if acc.any():
            pos = np.nan_to_num(np.asarray(out["position_for_control"], dtype=float))
        if k + 1 < K:
            demand = np.array(out["demand"]) if out["safety"] else xm[k + 1].copy()
    rec["trigger_sample"] = trigger
    return PlatformRun(t, pose, xm, xref, U, Y, X, prof, faults, rec, model, geometry, motion,
                       seed, noise, values)


# the run's folder, written whole (kept importable from here)
from fdigen.platform.run_folder import (RUN_FILES, check_run_folder,  # noqa: E402,F401
                                        is_run_folder, write_platform_logs)

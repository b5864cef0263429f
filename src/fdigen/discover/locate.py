"""Locate: which model equation carries structure the model does not explain.

The model is tested equation by equation on the measured data (an *equation error*): the
states are reconstructed from the measurements, each equation ``dx_i/dt = f_i(x, u, p)``
is evaluated on them, and its error is tested against the noise level.

Reconstruction
--------------
* A state measured by one or more outputs (``y = x_i``) is the mean of those outputs,
  lightly smoothed (Savitzky-Golay, cubic, ``smooth`` seconds) where it enters ``f``.
* A state that is not measured but is the derivative of a measured one (the kinematic
  chain ``dx/dt = xdot``) is the Savitzky-Golay derivative of that measurement. Its own
  equation is then tested through the second derivative of the measurement, and the
  kinematic equation is an identity (not tested).

Modulating-function windows (sample-and-hold aware)
---------------------------------------------------
The log is cut into disjoint windows of ``window`` seconds (``L`` samples). Window ``w``
starting at sample ``a`` weighs the equation error with the bump
``phi(s) = sin(pi*s)^2`` (zero with its slope at both ends). For a measured state ``z``
(first-order equation), with the command ``u[k]`` held over ``[t_k, t_k+1)`` and
therefore every quantity taken at the half sample ``t_k+1/2``:

.. math::

    E_i[w] = \\frac{\\sum_{l=0}^{L-1} \\phi_l\\,\\big(z_{a+l+1} - z_{a+l}
             - \\Delta t\\, f_i(\\hat x_{a+l+1/2}, u_{a+l}, p)\\big)}
             {\\Delta t \\sum_l \\phi_l},
    \\qquad \\phi_l = \\sin^2\\big(\\pi (l + 1/2)/L\\big),

where ``z_{k+1} - z_k`` is the exact integral of ``dz/dt`` over the sample interval
(so the error is that of the midpoint rule only, O(dt^3)). For a state known through the
second derivative of a measurement ``z`` (second-order equation, e.g. the force balance):

.. math::

    E_i[w] = \\frac{\\sum_{l=0}^{L} \\psi_l\\,\\big((z_{a+l+1} - 2 z_{a+l} + z_{a+l-1})
             /\\Delta t - \\Delta t\\, f_i(\\hat x_{a+l}, \\bar u_{a+l}, p)\\big)}
             {\\Delta t \\sum_l \\psi_l},
    \\qquad \\psi_l = \\sin^2(\\pi l / L),

with ``bar u_k = (u[k-1] + u[k])/2``. By summation by parts the measurement enters only
through the smooth weights' differences (a modulating-function / prefilter method: no
noisy derivative is formed), ``E_i`` is in the state's unit per second (a weighted mean
of ``dx_i/dt - f_i``), and since the windows are disjoint the sensor noise of
neighbouring windows is independent: under a correct model ``E_i[w]`` is white noise.

Test
----
Per equation, on the residual ``e = E_i`` of the calibrated model (validation windows
excluded): a portmanteau statistic of the mean and the first ``lags`` autocorrelations,

.. math::

    Q = N \\frac{\\bar e^2}{s^2} + N (N+2) \\sum_{h=1}^{H} \\frac{r_h^2}{N-h}
    \\sim \\chi^2_{H+1} \\text{ under a white residual}

(Ljung-Box plus a t-test of the mean), and the share of the residual's mean square that
is low-frequency structure (von Neumann: one minus half the ratio of the mean square of
successive differences to the mean square)

.. math::

    \\rho = 1 - \\frac{\\sum_w (e_{w+1} - e_w)^2}{2 \\sum_w e_w^2},

which is near 0 for white noise and near 1 for a slowly varying error. An equation is
*located* when ``p(Q) < alpha`` and ``rho > min_structure``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import sympy as sp
from scipy import signal, stats

from fdigen.discover.interval_means import interval_means
from fdigen.discover.noise import noise_level
from fdigen.errors import FdigenError
from fdigen.model.model import Model
from fdigen.safe_lambdify import safe_lambdify


# -- reconstruction and windows ------------------------------------------------------------

@dataclass
class EquationData:
    """The measured log prepared for equation errors.

    Attributes
    ----------
    model : Model
    t, u, y : numpy.ndarray
        Time (K,), inputs (K, m), outputs (K, p).
    dt : float
    equations : list of str
        Names (state names) of the testable equations, in model order.
    kind : dict of str to str
        ``"first"`` (measured state) or ``"second"`` (derivative of a measured state).
    source : dict of str to str
        Equation -> the measured state whose signal ``z`` gives its derivative.
    xs : numpy.ndarray
        Reconstructed states at the samples (K, n).
    xh : numpy.ndarray
        Reconstructed states at the half samples (K-1, n).
    z : dict of str to numpy.ndarray
        Measured state -> raw measurement (mean of its outputs), shape (K,).
    state_outputs : dict of int to list of int
        State index -> indices of the outputs measuring it.
    starts : numpy.ndarray
        First sample of each window (W,).
    L : int
        Window length in samples.
    valid : numpy.ndarray
        Windows whose states stay clear of the hard limits (W,) bool.
    D : numpy.ndarray
        Measured side of every testable equation per window (W, neq), normalised.
    noise_std : numpy.ndarray
        Sensor noise std per output estimated from the log (second differences).
    """

    model: Model
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    dt: float
    equations: list
    kind: dict
    source: dict
    xs: np.ndarray
    xh: np.ndarray
    z: dict
    state_outputs: dict
    starts: np.ndarray
    L: int
    valid: np.ndarray
    D: np.ndarray
    noise_std: np.ndarray
    phi: np.ndarray = field(repr=False, default=None)
    psi: np.ndarray = field(repr=False, default=None)
    window: float = 0.05
    smooth: float = 0.025

    @property
    def n_windows(self) -> int:
        return len(self.starts)

    def window_times(self) -> np.ndarray:
        """Centre time of each window."""
        return self.t[0] + (self.starts + self.L / 2) * self.dt

    def split(self, fraction: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Calibration and validation window masks and the split time.

        Windows wholly before ``t0 + fraction*(t_end - t0)`` calibrate; windows wholly after
        validate.
        """
        K = len(self.t)
        k_split = int(np.floor(fraction * K))
        ends = self.starts + self.L + 1
        cal = self.valid & (ends <= k_split)
        val = self.valid & (self.starts >= k_split)
        return cal, val, float(self.t[min(k_split, K - 1)])


def split_valid(data: "EquationData", fraction: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Split by the share of *usable* windows when the time split leaves too few.

    A log whose end is unusable for the equation test (a sensor lost, the plant held at a
    limit) leaves the held-back part of :meth:`EquationData.split` empty. Then the split
    is placed at the start of the usable window that leaves ``fraction`` of the usable
    windows before it.
    """
    idx = np.flatnonzero(data.valid)
    if len(idx) < 2:
        return data.split(fraction)
    k = int(min(max(np.floor(fraction * len(idx)), 1), len(idx) - 1))
    k_split = int(data.starts[idx[k]])
    ends = data.starts + data.L + 1
    cal = data.valid & (ends <= k_split)
    val = data.valid & (data.starts >= k_split)
    return cal, val, float(data.t[k_split])


def measured_states(model: Model) -> dict[int, list[int]]:
    """State index -> indices of the outputs that measure it: ``y_j = g(x_i, p)``
    invertible over the state's range (:func:`fdigen.model.sensor_maps.sensor_maps`:
    ``y = x``, a level in volts ``y = kc*x``, ``y = kc*x + off``), in the file's order."""
    from fdigen.model.sensor_maps import sensor_maps

    return {model.state_index(name): sorted(model.output_index(m.output) for m in maps)
            for name, maps in sensor_maps(model).items()}


def sensor_gain(model: Model, j: int) -> float:
    """``dg/dx`` of output ``j``'s map at the operating point (1 for ``y = x``): an
    offset ``c`` of that sensor reads as ``c / g`` on its state (exact for linear maps)."""
    from fdigen.model.sensor_maps import state_of_output

    m = state_of_output(model, model.outputs[j].name)
    return 1.0 if m is None else float(m.gain)


def state_values(model: Model, outs, y) -> np.ndarray:
    """A measured state at each sample from its sensors ``outs``: the mean of
    ``x = g_j^{-1}(y_j)`` (the sensors' own columns when every map is ``y = x``), with the
    maps' parameters at their nominal values."""
    from fdigen.model.sensor_maps import state_of_output

    y = np.asarray(y, dtype=float)
    maps = [state_of_output(model, model.outputs[j].name) for j in outs]
    if all(m.identity for m in maps):
        return y[:, outs].mean(axis=1)
    cols = []
    for j, m in zip(outs, maps):
        inv = m.inverse.xreplace(model.parameter_values)
        f = safe_lambdify([model.outputs[j].symbol], inv, modules="numpy")
        cols.append(np.broadcast_to(np.asarray(f(y[:, j]), dtype=float), (len(y),)))
    return np.mean(cols, axis=0)


def _odd(n: int) -> int:
    n = max(int(n), 5)
    return n if n % 2 else n + 1


def chain_gain(model: Model, expr, state) -> float | None:
    """``c`` when ``expr = c x`` for the state ``x`` and a nonzero constant ``c`` of the
    parameters (``dx/dt = v``: 1; a gearbox's ``dth/dt = w/N``: ``1/N``), else ``None``:
    then ``x = (dz/dt)/c`` from the measured ``z``. Only an expression that reads the state
    can be it; ``simplify`` is tried last, and its failures (sympy raised on a valve's
    ``max(... sign(u) ..., 0)``: "The argument 'nan' is not comparable", an internal error
    of a user's discover) read as "not the state"."""
    if expr == state:
        return 1.0
    if state not in expr.free_symbols or not expr.free_symbols - {state} <= set(model.p):
        return None
    c = sp.diff(expr, state)
    if state in c.free_symbols:
        return None
    try:
        rest = sp.expand(expr - c * state)
        if rest != 0 and sp.simplify(rest) != 0:
            return None
        value = float(c.xreplace(model.parameter_values))
    except (ValueError, TypeError, ZeroDivisionError, RecursionError):
        return None
    return value if np.isfinite(value) and value != 0 else None


def prepare(model: Model, t, u, y, *, window: float = 0.05, smooth: float = 0.025,
            limit_margin: float = 0.01) -> EquationData:
    """Reconstruct the states and cut the log into modulating-function windows.

    Parameters
    ----------
    model : Model
    t, u, y : array_like
        Time (K,), inputs (K, m) and outputs (K, p) in the model's order (a
        :class:`fdigen.sim.log.Log`'s fields).
    window : float
        Window length [s] (default 50 ms: 20 Hz, above the cylinder's 8 Hz pneumatic mode).
    smooth : float
        Savitzky-Golay (cubic) length [s] of the state reconstruction.
    limit_margin : float
        Windows whose states come closer than this share of their limit span to a hard
        limit (end stop, supply, atmosphere) are left out: there the model is clamped.

    Raises
    ------
    FdigenError
        If a state is neither measured nor the derivative of a measured state, or the log
        is too short for two windows.
    """
    t = np.asarray(t, dtype=float)
    u = np.asarray(u, dtype=float).reshape(len(t), -1)
    y = np.asarray(y, dtype=float).reshape(len(t), -1)
    K = len(t)
    dt = float(np.median(np.diff(t)))
    n = len(model.states)
    meas = measured_states(model)
    ws = _odd(round(smooth / dt))
    if K < 4 * ws:
        raise FdigenError(f"log too short for the equation test ({K} samples)")
    xs = np.full((K, n), np.nan)
    z = {}
    for i, outs in meas.items():
        z[model.states[i].name] = state_values(model, outs, y)
        xs[:, i] = signal.savgol_filter(z[model.states[i].name], ws, 3)
    rhs = model.f()
    kind, source, equations = {}, {}, []
    derived, gain = {}, {}
    for i in meas:
        # kinematic chain: dx_i/dt = c x_j of one unmeasured state -> x_j = (dz_i/dt)/c
        for j, s in enumerate(model.states):
            c = None if j in meas else chain_gain(model, rhs[i], s.symbol)
            if c is not None:
                derived[j], gain[model.states[j].name] = i, c
    for j, i in derived.items():
        xs[:, j] = signal.savgol_filter(z[model.states[i].name], ws, 3, deriv=1,
                                        delta=dt) / gain[model.states[j].name]
    missing = [model.states[i].name for i in range(n) if np.isnan(xs[0, i])]
    if missing:
        raise FdigenError(f"state {missing[0]} is neither measured nor the derivative of a "
                          "measured state: the equation error cannot be formed")
    for i, s in enumerate(model.states):
        if i in meas and i not in derived.values():
            kind[s.name], source[s.name] = "first", s.name
            equations.append(s.name)
        elif i in derived:
            kind[s.name], source[s.name] = "second", model.states[derived[i]].name
            equations.append(s.name)
    # the states over each interval: midpoints, a fast state's exact mean (interval_means)
    xh, _ = interval_means(model, xs, z, meas, u, dt)

    L = max(int(round(window / dt)), 8)
    starts = np.arange(1, K - L - 2, L)
    if len(starts) < 8:
        raise FdigenError(f"log too short: {len(starts)} windows of {window} s")
    phi = np.sin(np.pi * (np.arange(L) + 0.5) / L) ** 2
    psi = np.sin(np.pi * np.arange(L + 1) / L) ** 2

    # windows clear of the hard limits
    pvals = model.parameter_values
    valid = np.ones(len(starts), dtype=bool)
    idx = starts[:, None] + np.arange(L + 1)[None, :]
    for i, s in enumerate(model.states):
        if not s.limits:
            continue
        lo, hi = (float(sp.sympify(b).xreplace(pvals)) for b in s.limits)
        margin = limit_margin * (hi - lo)
        seg = xs[idx, i]
        valid &= np.all((seg > lo + margin) & (seg < hi - margin), axis=1)

    D = np.zeros((len(starts), len(equations)))
    for q, name in enumerate(equations):
        zz = z[source[name]]
        if kind[name] == "first":
            inc = np.diff(zz)[idx[:, :L]]
            D[:, q] = inc @ phi / (dt * phi.sum())
        else:
            d2 = np.zeros(K)
            d2[1:-1] = (zz[2:] - 2 * zz[1:-1] + zz[:-2]) / dt
            D[:, q] = d2[idx] @ psi / (dt * psi.sum() * gain[name])

    noise = noise_level(y)
    return EquationData(model, t, u, y, dt, equations, kind, source, xs, xh, z, meas,
                        starts, L, valid, D, noise, phi, psi, window, smooth)


# -- the model's side: f_i with effects, numerically ---------------------------------------

class EquationModel:
    """The testable equations of a model plus library effects, evaluated with numpy.

    ``f_i`` of every testable equation is built symbolically (``model.f()`` plus each
    effect's state terms, definitions expanded) and lambdified once; output offsets shift
    the reconstructed state they measure (``x_i = y - off``).

    Parameters
    ----------
    data : EquationData
    effects : sequence of LibraryEffect
    """

    def __init__(self, data: EquationData, effects=()):
        model = data.model
        self.data = data
        self.effects = tuple(effects)
        self.names = [q.name for q in model.parameters]
        self.defaults = {q.name: float(q.value) for q in model.parameters}
        self.effect_params = []
        for e in self.effects:
            for p in e.parameters:
                if p.name not in self.effect_params:
                    self.effect_params.append(p.name)
                    self.defaults[p.name] = 0.0
        self.names += self.effect_params
        rhs = model.f()
        self.offsets = []  # (parameter symbol name, state index, sign)
        for e in self.effects:
            terms = e.terms(model)
            for target, term in terms.items():
                if target in {s.name for s in model.states}:
                    k = model.state_index(target)
                    rhs[k] = rhs[k] + model.expand(term)
                else:
                    j = model.output_index(target)
                    state = [i for i, outs in measured_states(model).items() if j in outs]
                    free = {str(s) for s in term.free_symbols}
                    if len(state) != 1 or not free <= set(e.parameter_names) \
                            or len(free) != 1:
                        raise FdigenError(f"effect '{e.name}': only constant offsets of "
                                          "outputs that measure a state are supported")
                    # an offset c of y = g(x) reads as c / g on the state
                    self.offsets.append((free.pop(), state[0],
                                         term / sp.Float(sensor_gain(model, j), 17)
                                         if sensor_gain(model, j) != 1.0 else term))
        xs = [s.symbol for s in model.states]
        us = [s.symbol for s in model.inputs]
        ps = [sp.Symbol(nm, real=True) for nm in self.names]
        self._args = xs + us + ps
        self.f = {}
        for name in data.equations:
            k = model.state_index(name)
            self.f[name] = safe_lambdify(self._args, rhs[k], modules="numpy")
        self.rhs = rhs

    def values(self, params: dict | None = None) -> dict:
        """All parameter values: model defaults, effect parameters 0, then ``params``."""
        vals = dict(self.defaults)
        vals.update(params or {})
        return vals

    def _states(self, x: np.ndarray, vals: dict, outs_per_state) -> np.ndarray:
        if not self.offsets:
            return x
        x = x.copy()
        for pname, i, term in self.offsets:
            off = float(term.xreplace({sp.Symbol(pname, real=True): vals[pname]}))
            # the state is the mean of its outputs; one of them carries the offset
            x[:, i] -= off / len(outs_per_state[i])
        return x

    def rhs_values(self, params: dict | None = None, grid: str = "half") -> dict:
        """``f_i`` of every testable equation on the half-sample or sample grid."""
        d = self.data
        vals = self.values(params)
        if grid == "half":
            x = self._states(d.xh, vals, d.state_outputs)
            u = d.u[:-1]
        else:
            x = self._states(d.xs, vals, d.state_outputs)
            u = np.vstack([d.u[:1], 0.5 * (d.u[1:] + d.u[:-1])])
        args = [x[:, i] for i in range(x.shape[1])] + [u[:, j] for j in range(u.shape[1])] \
            + [vals[nm] for nm in self.names]
        out = {}
        for name, fn in self.f.items():
            if grid == "half" and d.kind[name] != "first":
                continue
            if grid == "sample" and d.kind[name] != "second":
                continue
            out[name] = np.broadcast_to(np.asarray(fn(*args), dtype=float), (len(x),))
        return out

    def errors(self, params: dict | None = None) -> np.ndarray:
        """Equation errors ``E`` (W, neq) for the given parameter values."""
        d = self.data
        E = d.D.copy()
        idx = d.starts[:, None] + np.arange(d.L + 1)[None, :]
        fh = self.rhs_values(params, "half")
        fs = self.rhs_values(params, "sample") if "second" in d.kind.values() else {}
        for q, name in enumerate(d.equations):
            if d.kind[name] == "first":
                E[:, q] -= fh[name][idx[:, :d.L]] @ d.phi / d.phi.sum()
            else:
                E[:, q] -= fs[name][idx] @ d.psi / d.psi.sum()
        return E


# -- the test ------------------------------------------------------------------------------

@dataclass(frozen=True)
class EquationTest:
    """The structure test of one equation's residual.

    Attributes
    ----------
    equation : str
    description : str
    n : int
        Windows used.
    rms : float
        RMS of the residual [state unit / s].
    noise : float
        Its white-noise level, from successive differences [state unit / s].
    structure : float
        Share of the mean square that is low-frequency structure (von Neumann ``rho``).
    Q, p : float
        Portmanteau statistic (mean + Ljung-Box) and its p-value.
    located : bool
    """

    equation: str
    description: str
    n: int
    rms: float
    noise: float
    structure: float
    Q: float
    p: float
    located: bool

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def structure_statistics(e: np.ndarray, lags: int = 10) -> tuple[float, float, float, float]:
    """``(Q, p, rho, noise)`` of a residual sequence (see the module docstring)."""
    e = np.asarray(e, dtype=float)
    N = len(e)
    H = int(min(lags, max(N // 4, 1)))
    m = e.mean()
    c = e - m
    s2 = float(c @ c) / N
    if s2 <= 0 or N < 8:
        return 0.0, 1.0, 0.0, 0.0
    r = np.array([float(c[:-h] @ c[h:]) / (N * s2) for h in range(1, H + 1)])
    Q = N * m * m / s2 + N * (N + 2) * float(np.sum(r ** 2 / (N - np.arange(1, H + 1))))
    p = float(stats.chi2.sf(Q, H + 1))
    ms_diff = float(np.mean(np.diff(e) ** 2))
    rho = 1.0 - ms_diff / (2.0 * float(np.mean(e ** 2)))
    return float(Q), p, float(rho), float(np.sqrt(ms_diff / 2.0))


def locate(data: EquationData, E: np.ndarray, mask: np.ndarray, *, alpha: float = 1e-3,
           min_structure: float = 0.05, lags: int = 10) -> list[EquationTest]:
    """Test every equation's residual ``E[mask]`` for structure.

    Parameters
    ----------
    data : EquationData
    E : numpy.ndarray
        Equation errors (W, neq) of the calibrated model.
    mask : numpy.ndarray
        Windows to use (the calibration part).
    alpha : float
        Significance of the portmanteau test, per equation.
    min_structure : float
        Smallest share of structure that counts (an effect size: with tens of thousands of
        samples even a negligible mismatch becomes "significant").
    lags : int

    Returns
    -------
    list of EquationTest
        One per testable equation, in model order.
    """
    out = []
    model = data.model
    for q, name in enumerate(data.equations):
        e = E[mask, q]
        Q, p, rho, noise = structure_statistics(e, lags)
        desc = model.states[model.state_index(name)].description
        located = bool(p < alpha and rho > min_structure)
        out.append(EquationTest(name, desc, int(len(e)), float(np.sqrt(np.mean(e ** 2))),
                                noise, rho, Q, p, located))
    return out

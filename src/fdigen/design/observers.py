"""Dedicated steady-state Kalman filters on the observable part of a (sub)model.

Each filter gives one innovation residual (eqs 13-17 of the paper): the model is linearised
at the operating point, reduced to the part observable from the filter's measurement
(eq 15 for position), discretised by zero-order hold and given the steady-state gain of the
discrete algebraic Riccati equation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp

from fdigen.derive import precise
from fdigen.derive.kalman import KalmanGain, continuous_kalman_gain, discrete_kalman_gain
from fdigen.derive.linearisation import (LinearModel, discretise_noise, discretise_zoh, linearise,
                                         numeric)
from fdigen.derive.observability import (ObservableReduction, measurement_expressions,
                                         observable_reduction)
from fdigen.derive.riccati import state_scales
from fdigen.design.nonlinear_prediction import nonlinear_reason
from fdigen.model.expression import parse_expression
from fdigen.model.model import Model


@dataclass(frozen=True)
class KalmanResidual:
    """A dedicated Kalman filter and its innovation residual.

    The filter runs in the reduced coordinates ``z = T x`` of ``reduction``:

    .. math::

        e[k] = m(y[k]) - m_0 - C_r (z^-[k] - z_0),\\quad
        z^+ = z^- + M e_u[k],\\quad
        z^-[k+1] = z_0 + A_d (z^+ - z_0) + B_d (u[k] - u_0)

    where ``e`` is the residual (eqs 16-17) and ``e_u`` the innovation used for the update
    (equal to ``e`` unless the filter is updated with the voter's fused measurement).
    """

    residual: str
    model: Model
    measurement: tuple[str, ...]
    drivers: dict
    reduction: ObservableReduction
    discrete: LinearModel
    gain: KalmanGain
    continuous_gain: KalmanGain
    z0: np.ndarray
    m0: np.ndarray
    Qc: np.ndarray
    Rd: np.ndarray
    update: str
    schedule: str = "operating_point"
    #: why the prediction goes through the nonlinear model (``schedule == "nonlinear"``)
    nonlinear_reason: str | None = None


def filter_label(model: Model, kr: KalmanResidual) -> str:
    """Where a Kalman residual comes from, for a message: ``fdi.kalman.R4`` when the model
    file declares it, else the derived residual's description (a user was told about a
    ``fdi.kalman.R1`` they never wrote)."""
    if kr.residual in dict(model.fdi.get("kalman", {})):
        return f"fdi.kalman.{kr.residual}"
    states = ", ".join(s.name for s in kr.model.states)
    drivers = ", ".join(f"{k}<-{v}" for k, v in kr.drivers.items())
    return (f"derived residual {kr.residual} (Kalman filter of the equations of {states}"
            + (f" driven by {drivers}" if drivers else "") + ")")


def measurement_noise(model: Model, measurement, fused: int = 1) -> np.ndarray:
    """Covariance of measured expressions from the sensors' white noise.

    .. math:: R = J \\,\\mathrm{diag}(\\sigma^2)\\, J^T,\\qquad J = \\partial m / \\partial y

    ``fused`` > 1 divides by the number of equal sensors averaged by the voter.
    """
    outs = {o.name: o.symbol for o in model.outputs}
    exprs = [parse_expression(m, outs, source=model.source, field="fdi.measurement")
             for m in measurement]
    J = np.array(sp.Matrix(exprs).jacobian(sp.Matrix([o.symbol for o in model.outputs])),
                 dtype=float)
    sig2 = np.diag([o.noise_std ** 2 for o in model.outputs])
    return precise.matmul(J, sig2, J.T) / fused


def noiseless_sensors(model: Model, measurement, R, residual: str) -> None:
    """Refuse a Kalman filter whose measurement covariance ``R`` is singular because a
    sensor it reads declares ``noise_std = 0``, naming the sensor's field (the gain
    weighs each measurement by its noise: a noise-free one has none)."""
    if np.linalg.eigvalsh(np.atleast_2d(R)).min() > 0:
        return
    from fdigen.errors import ModelFileError

    outs = {o.name: o.symbol for o in model.outputs}
    read = set().union(*(parse_expression(m, outs, source=model.source,
                                          field="fdi.measurement").free_symbols
                         for m in measurement))
    silent = [o for o in model.outputs if o.symbol in read and o.noise_std <= 0]
    if silent:
        raise ModelFileError(
            f"the Kalman filter of residual {residual} reads {', '.join(o.name for o in silent)}"
            ", whose noise_std is 0: its gain weighs a measurement by its noise; give every "
            "sensor the filter reads its noise standard deviation (from the datasheet, or "
            "the log's scatter at rest)", model.source, f"outputs.{silent[0].name}.noise_std",
            silent[0].name)


def kalman_residual(model: Model, residual: str, measurement: tuple[str, ...],
                    process_noise: dict, dt: float, *, drivers: dict | None = None,
                    driver_noise: dict | None = None, update: str = "measurement",
                    fused: int = 1, schedule: str = "operating_point",
                    nonlinear_drivers: bool = False) -> KalmanResidual:
    """Design one dedicated steady-state Kalman filter.

    Parameters
    ----------
    model : Model
        The model (or driven sub-model) the filter is built on.
    residual : str
        Residual name (``R4``...).
    measurement : tuple of str
        Measured expressions in output names, e.g. ``("x3",)`` or ``("pp - pn",)``.
    process_noise : dict of str to float
        Continuous process noise intensity (std per sqrt(s)) of each state:
        ``Q_c = diag(q^2)``; projected to the reduced coordinates as ``T Q_c T^T``.
    dt : float
        Sample time [s].
    drivers : dict, optional
        Input name -> measured output used as an input (driven sub-models).
    driver_noise : dict, optional
        Input name -> noise std of that measured input; it enters as process noise
        ``B_i sigma_i^2 dt B_i^T`` (sampled white noise of variance ``sigma^2``).
    update, fused
        ``"voter"`` updates with the voter's fused sensors, whose noise is ``R / fused``.
    schedule : {"operating_point", "measured", "nonlinear"}
        ``"measured"``: the prediction model is re-evaluated every sample at the measured
        states (see :func:`fdigen.design.scheduled_prediction.scheduled_transition`); the gain stays
        the steady-state gain of the operating point. ``"nonlinear"``: the prediction
        integrates the model's own ``f`` (see
        :func:`fdigen.design.nonlinear_prediction.nonlinear_prediction`). Any schedule
        becomes ``"nonlinear"`` when the linearisation is not faithful
        (:func:`~fdigen.design.nonlinear_prediction.nonlinear_reason`: a non-smooth term,
        state-dependent reduced coordinates, an operating point off equilibrium, and with
        ``nonlinear_drivers`` a driver entering ``f`` nonlinearly).

    Raises
    ------
    DesignError
        If the reduced pair is not detectable or the weights are not definite.
    """
    red = observable_reduction(model, measurement)
    # (a driver's input in the sub-model is named by its sensor: {state: output})
    reason = nonlinear_reason(model, red.T, tuple((drivers or {}).values())
                              if nonlinear_drivers else ())
    if reason is not None or schedule == "nonlinear":
        schedule = "nonlinear"
    lin = linearise(model)
    T = red.T_num
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name] for s in (*model.states, *model.inputs)})
    cont = LinearModel(red.A_num, red.B_num, red.C_num,
                       feedthrough(model, measurement, point), red.E_num,
                       np.zeros((red.C_num.shape[0], 0)),
                       precise.matmul(T, lin.x0), lin.u0, np.zeros(0))
    disc = discretise_zoh(cont, dt)
    Qc_full = np.diag([process_noise[s.name] ** 2 for s in model.states])
    Qc = precise.matmul(T, Qc_full, T.T)
    if driver_noise:
        for k, s in enumerate(model.inputs):
            sig = driver_noise.get(s.name, 0.0)
            if sig:
                b = red.B_num[:, k:k + 1]
                Qc = Qc + precise.matmul(b, b.T) * sig ** 2 * dt
    Qd = discretise_noise(red.A_num, Qc, dt)
    Rd = measurement_noise(model, measurement, fused)
    noiseless_sensors(model, measurement, Rd, residual)
    what = f"Kalman filter {residual} (measurement {', '.join(measurement)})"
    scale = state_scales(model.states, T)
    gain = discrete_kalman_gain(disc.A, disc.C, Qd, Rd, what, scale)
    cgain = continuous_kalman_gain(red.A_num, red.C_num, Qc, Rd * dt, what, scale)
    m0 = numeric(sp.Matrix(measurement_expressions(model, measurement)), point).ravel()
    return KalmanResidual(residual, model, tuple(measurement), dict(drivers or {}), red, disc,
                          gain, cgain, cont.x0, m0, Qc, Rd, update, schedule,
                          reason)


def feedthrough(model: Model, measurement: tuple[str, ...], point: dict) -> np.ndarray:
    """Direct feedthrough of the inputs into the measured expressions at ``point``,

    .. math:: D_r = \\partial m(h(x, u)) / \\partial u

    (a battery's terminal voltage ``OCV(SOC) - R0 I`` measures the current ``I``: the
    filter's prediction must add ``D_r (u - u_0)``, or a healthy log under load leaves
    the residual at ``R0 |I|``). Zero for a sensor of states only."""
    exprs = sp.Matrix(measurement_expressions(model, measurement))
    D = np.zeros((exprs.shape[0], len(model.inputs)))
    for j, s in enumerate(model.inputs):
        col = exprs.diff(s.symbol)
        if col.is_zero_matrix:
            continue
        D[:, j] = np.asarray(col.xreplace(point).evalf(), dtype=float).ravel()
    return D


def residual_noise_level(kr: KalmanResidual) -> float:
    """Standard deviation of a Kalman residual on a model without error: the noise level.

    .. math:: \\sigma_r = \\sqrt{C_r P C_r^T + R_1}

    ``P`` the steady-state a-priori error covariance and ``R_1`` the noise of the compared
    measurement itself (for a filter updated with the voter's fused sensors, that of one
    sensor, not of the fused ones; otherwise ``sigma_r^2`` is the innovation covariance
    ``S``). A healthy residual's RMS near this level is a filter whose prediction holds.
    """
    R1 = measurement_noise(kr.model, kr.measurement, 1)
    C = kr.discrete.C
    return float(np.sqrt((C @ kr.gain.P @ C.T + R1)[0, 0]))

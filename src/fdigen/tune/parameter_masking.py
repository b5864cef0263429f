"""Faults that the parameter spread masks: what no fixed-threshold design can detect.

The thresholds of a design must accept every healthy plant whose uncertain parameters lie
within the tolerance (that is what ``fdigen tune`` designs them for). A fault whose effect
on the measurements, after its onset, is what some such healthy plant would show anyway
cannot be told from it by any residual with a fixed threshold: the campaign's miss is then
not a defect of the residuals but of the knowledge of the plant, and the remedy is to
narrow the tolerance (calibrate the plant, ``fdigen commission``), not to lower a threshold.

With ``y_0`` the noise-free closed-loop run of the nominal model, ``y_f`` the same run with
the fault switched on at ``t_0`` (a step at its test size, or a drift at its campaign
rate), ``S_j = (y(p_j^+) - y(p_j^-)) / 2`` the secant sensitivity to uncertain parameter
``j`` over its tolerance (``p_j^\\pm = p_j (1 \\pm tol_j)``, clipped to its bounds), and
``W = diag(1/sigma_i)`` the sensor noise, the best explanation of the fault by the spread
over the samples after the onset is

.. math:: \\delta^* = \\arg\\min_{|\\delta_j| \\le 1} \\sum_{k \\ge k_0}
          \\| W (y_f[k] - y_0[k] - S[k] \\delta) \\|^2

(a bounded linear least-squares problem, SciPy's ``lsq_linear``), and the fault is
**masked** when the remainder ``e = y_f - y_0 - S delta^*`` stays below the noise in every
RMS window of the design (``N`` samples) on every sensor:

.. math:: \\max_{i, k} \\frac{1}{\\sigma_i}\\sqrt{\\frac{1}{N}\\sum_{l=k-N+1}^{k} e_i[l]^2}
          < 1.

It is an estimate (one demand profile, the parameters' effect linearised over their
range, a parameter error present from the start compared with a fault that starts at
``t_0``): a masked fault may still be caught by a detector that learns the parameters
from the fault-free part of the run, and a fault that is not masked may still be missed
by a given design. It says which misses a better residual cannot fix.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

from fdigen.design.evaluation import moving_rms


def _spread_values(model, tolerance: float, per: dict) -> list:
    """(parameter, relative tolerance, low value, high value) of every uncertain
    parameter, as the campaign spreads them (:func:`fdigen.tune.cases.perturbed_parameters`)."""
    out = []
    for q in model.parameters:
        if not q.uncertain:
            continue
        tol = float(per.get(q.name, tolerance))
        lo, hi = q.value * (1.0 - tol), q.value * (1.0 + tol)
        if q.bounds is not None:
            lo, hi = (min(max(v, q.bounds[0]), q.bounds[1]) for v in (lo, hi))
        out.append((q.name, tol, float(lo), float(hi)))
    return out


def masking_of_fault_cases(model, cases, *, tolerance: float, tolerances: dict | None = None,
                           duration: float, window: int, t_fault: float | None = None) -> dict:
    """Whether the parameter spread masks each fault case (see the module docstring).

    Parameters
    ----------
    model : Model
    cases : sequence of (fault name, size, ramp)
        ``size`` is the step's size or the drift's rate (units per second).
    tolerance : float
        Relative spread of the uncertain parameters (``--tolerance``).
    tolerances : dict, optional
        Parameters with their own spread.
    duration : float
        Run length [s]; the fault starts at ``t_fault`` (default: half of it).
    window : int
        The design's RMS window ``N`` [samples].

    Returns
    -------
    dict
        ``(fault, size, ramp)`` -> ``masked`` (bool), ``below_noise`` (the effect itself
        stays under the noise), ``remainder`` and ``effect`` (the
        largest window RMS over the noise of the remainder and of the fault's effect
        itself), ``remainder_rms`` (the RMS over the noise of the remainder over every
        sample after the onset: the minimised objective), ``parameters`` (name -> the
        relative error of the best explanation, ``delta_j tol_j``).
    """
    from fdigen.sim.plant import FaultEvent, simulate

    per = dict(tolerances or {})
    t0 = float(duration / 2 if t_fault is None else t_fault)

    def run(faults=(), parameters=None):
        return simulate(model, duration, faults=faults, parameters=parameters,
                        noise=False).y

    y0 = run()
    dt = float(model.fdi.get("sample_time", 1e-3))
    k0 = int(round(t0 / dt))
    sigma = np.array([o.noise_std or 0.0 for o in model.outputs], dtype=float)
    scale = np.maximum(np.abs(y0).max(axis=0), 1e-300)
    sigma = np.where(sigma > 0, sigma, 1e-9 * scale)
    spread = _spread_values(model, tolerance, per)
    columns, names, tols = [], [], []
    for name, tol, lo, hi in spread:
        d = (run(parameters={name: hi}) - run(parameters={name: lo})) / 2.0
        columns.append((d[k0:] / sigma).ravel())
        names.append(name)
        tols.append(tol)
    S = np.column_stack(columns) if columns else np.zeros(((len(y0) - k0) * y0.shape[1], 0))
    out = {}
    for fault, size, ramp in cases:
        yf = run(faults=(FaultEvent(fault, t0, float(size), bool(ramp)),))
        effect = (yf - y0)[k0:] / sigma
        b = effect.ravel()
        if S.shape[1] and np.any(S):
            delta = lsq_linear(S, b, bounds=(-1.0, 1.0)).x
        else:
            delta = np.zeros(S.shape[1])
        rem = (b - S @ delta).reshape(effect.shape)
        r_max = float(moving_rms(rem, window).max()) if rem.size else 0.0
        e_max = float(moving_rms(effect, window).max()) if effect.size else 0.0
        out[(fault, float(size), bool(ramp))] = {
            "masked": bool(r_max < 1.0),
            "below_noise": bool(e_max < 1.0),
            "remainder": r_max,
            "effect": e_max,
            "remainder_rms": float(np.sqrt(np.mean(rem ** 2))) if rem.size else 0.0,
            "parameters": {n: float(d * t) for n, d, t in zip(names, delta, tols)},
        }
    return out


def calibrated_spread(model) -> bool:
    """Whether every uncertain parameter of ``model`` has its own ``tolerance`` (a
    commissioned model file: the spread is already the calibration's)."""
    uncertain = [q for q in model.parameters if q.uncertain]
    return bool(uncertain) and all(q.tolerance is not None for q in uncertain)


def masking_text(fault: str, kind: str, size_text: str, entry: dict,
                 calibrated: bool = False) -> str:
    """One line for an engineer, e.g. ``s1 drift at 3.89e-05 m/s: masked by the
    parameter spread ...``; with ``calibrated`` (:func:`calibrated_spread`) the remedy is
    not a calibration the model has had already (a user's commissioned tanks were sent
    back to `fdigen commission`)."""
    pars = ", ".join(f"{n} {100 * v:+.1f} %" for n, v in entry["parameters"].items()
                     if abs(v) > 1e-4)
    if entry.get("below_noise"):
        return (f"{fault} {kind} of {size_text}: its effect stays under the sensor noise "
                f"in every RMS window of the run ({entry['effect']:.2g} sigma): no residual "
                "can see it at this size and run length, whatever the parameters; a larger "
                "test_size (test_rate for a drift) or longer runs (--duration) test "
                "something detectable")
    if entry["masked"]:
        remedy = ("the spread is the calibration's already (the parameters' own "
                  "tolerances): a longer or richer healthy log narrows it, or a larger "
                  "test_size tests what this plant can show" if calibrated else
                  "narrow it by calibration (fdigen commission)")
        return (f"{fault} {kind} of {size_text}: masked by the parameter spread (a healthy "
                f"plant with {pars or 'its nominal parameters'} reads the same within the "
                f"noise: remainder {entry['remainder']:.3g} sigma, effect "
                f"{entry['effect']:.2g} sigma); no threshold can detect it at this "
                f"tolerance: {remedy}")
    remedy = ("a residual decoupled from the parameters, or another realignment ([fdi] "
              "realign_noise_scale), can detect it; the parameters are calibrated already"
              if calibrated else "calibrated parameters (fdigen commission narrows the "
              "spread and the thresholds) or a residual decoupled from them can detect it")
    return (f"{fault} {kind} of {size_text}: not masked by the parameter spread (remainder "
            f"{entry['remainder']:.3g} sigma after the best healthy explanation"
            f"{': ' + pars if pars else ''}): the miss is the design's, not the data's; "
            + remedy)

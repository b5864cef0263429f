"""Report: errors of the model before and after the discovered effect, and a figure.

Output error with periodic re-initialisation
--------------------------------------------
The calibrated model (nominal, then augmented) is simulated driven by the *measured*
command ``u[k]`` (held over ``[t_k, t_k+1)``, RK4 with sub-steps, states clamped to their
hard limits as in the plant), over the validation part only, and compared with the
measured outputs:

.. math::

    \\mathrm{RMS}_j = \\sqrt{\\frac{1}{|V|}\\sum_{k \\in V}
    \\big(y_j[k] - h_j(\\hat x_{sim}[k])\\big)^2 }.

The cylinder integrates, so an open-loop simulation drifts whatever the model; the
simulation is therefore re-initialised from the reconstructed measured state every
``reinit`` seconds (default 1 s) and the error measures what the model predicts over one
such horizon. The same segments and initial states are used before and after.

FDI residuals
-------------
The generated FDI core (``fdi_runner(design, backend)``) of the original design and of the
augmented design is run over the whole log and the RMS of each residual (R1..R5, and the
derived ones) is taken over the validation part: a model that matches the rig better
leaves smaller healthy residuals, hence room for tighter thresholds.
"""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import sympy as sp

from fdigen.discover.initial_state import fit_samples, fitted_start, start_fitter
from fdigen.files.atomic import atomic_path
from fdigen.model.model import Model


def _rhs_and_outputs(model: Model, effects, values: dict):
    """Numeric CasADi functions ``f(x, u)`` and ``h(x, u)`` of the model with effects on
    (an output may read an input: a pump's outlet pressure its speed)."""
    from fdigen.backends.casadi_backend.convert import sympy_to_casadi

    rhs = model.f()
    out = model.h()
    for e in effects:
        for target, term in e.terms(model).items():
            term = model.expand(term)
            if target in {s.name for s in model.states}:
                k = model.state_index(target)
                rhs[k] = rhs[k] + term
            else:
                k = model.output_index(target)
                out[k] = out[k] + term
    n, m = len(model.states), len(model.inputs)
    x = ca.SX.sym("x", n)
    u = ca.SX.sym("u", m)
    mapping = {s.symbol: x[i] for i, s in enumerate(model.states)}
    mapping.update({s.symbol: u[i] for i, s in enumerate(model.inputs)})
    names = {str(s) for s in rhs.free_symbols | out.free_symbols}
    for name in names:
        if name in values:
            mapping[sp.Symbol(name, real=True)] = ca.SX(float(values[name]))
    f = ca.vertcat(*[sympy_to_casadi(rhs[i], mapping) for i in range(n)])
    h = ca.vertcat(*[sympy_to_casadi(out[i], mapping) for i in range(len(model.outputs))])
    lim = []
    pv = {sp.Symbol(k, real=True): float(v) for k, v in values.items()}
    for s in model.states:
        if s.limits:
            lim.append(tuple(float(sp.sympify(b).xreplace(pv)) for b in s.limits))
        else:
            lim.append(None)
    return ca.Function("f", [x, u], [f]), ca.Function("h", [x, u], [h]), lim


#: RK4 step times the largest |eigenvalue| of df/dx kept by the output-error simulation
#: (RK4 is stable up to 2.79 on the negative real axis).
RK4_STABLE = 1.5
#: Fewest and most RK4 sub-steps per sample of the output-error simulation.
MIN_SUBSTEPS, MAX_SUBSTEPS = 4, 400


def stiffness_substeps(f, n: int, m: int, xs: np.ndarray, us: np.ndarray, dt: float,
                       points: int = 400) -> tuple[int, float]:
    """RK4 sub-steps per sample from the model's stiffness over the data.

    .. math:: \\lambda_{max} = \\max_k \\max |\\mathrm{eig}(\\partial f/\\partial x
              (x_k, u_k))|, \\qquad
              N = \\min(\\max(\\lceil \\lambda_{max}\\, dt / 1.5 \\rceil, 4), 400)

    over (a subsample of) the reconstructed states ``xs`` and commands ``us``: a fixed
    number of sub-steps is unstable for a stiff model (viscous ``Ff/M`` of thousands of
    1/s, a steep friction sign), and an unstable simulation reports errors worse than
    the uncalibrated model's.

    Returns
    -------
    (int, float)
        Sub-steps and ``lambda_max`` [1/s].
    """
    x = ca.SX.sym("x", n)
    u = ca.SX.sym("u", m)
    jac = ca.Function("J", [x, u], [ca.jacobian(f(x, u), x)])
    step = max(len(xs) // points, 1)
    X, U = xs[::step], us[::step]
    ok = np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(U), axis=1)
    X, U = X[ok], U[ok]
    if not len(X):
        return MIN_SUBSTEPS, float("nan")
    J = np.array(jac.map(len(X))(X.T, U.T)).reshape(n, len(X), n).transpose(1, 0, 2)
    with np.errstate(all="ignore"):
        ev = np.linalg.eigvals(J[np.all(np.isfinite(J), axis=(1, 2))])
    lam = float(np.max(np.abs(ev))) if ev.size else float("nan")
    if not np.isfinite(lam):
        return MIN_SUBSTEPS, lam
    need = int(np.ceil(lam * dt / RK4_STABLE))
    return int(min(max(need, MIN_SUBSTEPS), MAX_SUBSTEPS)), lam


def output_error(data, effects, values: dict, mask_samples: np.ndarray, *,
                 reinit: float = 1.0, substeps: int | None = None) -> dict:
    """Output-error RMS per output column on the samples ``mask_samples``.

    Parameters
    ----------
    data : EquationData
        The prepared log (states reconstructed at the samples).
    effects : sequence of LibraryEffect
    values : dict
        Every parameter value (model and effects).
    mask_samples : numpy.ndarray
        Samples (bool, length K) over which the error is taken; the simulation restarts
        every ``reinit`` seconds from the first of them.
    reinit : float
        Re-initialisation period [s].
    substeps : int, optional
        RK4 sub-steps per sample; default from the model's stiffness over the data
        (:func:`stiffness_substeps`).

    Returns
    -------
    dict
        ``{"rms": {column: value}, "t": times, "y_sim": (K_v, p), "y": (K_v, p),
        "substeps": N, "stiffness": lambda_max}``.
    """
    from fdigen.discover.locate import sensor_gain

    model = data.model
    f, h, lim = _rhs_and_outputs(model, effects, values)
    n = len(model.states)
    dt = data.dt
    lam = None
    if substeps is None:
        substeps, lam = stiffness_substeps(f, n, len(model.inputs), data.xs, data.u, dt)
    N = max(int(round(reinit / dt)), 1)
    idx = np.flatnonzero(mask_samples)
    k0s = idx[::N]
    k0s = k0s[k0s + 1 < len(data.t)]
    x = ca.SX.sym("x", n)
    uu = ca.SX.sym("u", len(model.inputs))
    hs = dt / substeps
    xs = x
    for _ in range(substeps):
        k1 = f(xs, uu)
        k2 = f(xs + hs / 2 * k1, uu)
        k3 = f(xs + hs / 2 * k2, uu)
        k4 = f(xs + hs * k3, uu)
        xs = xs + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xs = ca.vertcat(*[xs[i] if lim[i] is None else
                          ca.fmin(ca.fmax(xs[i], lim[i][0]), lim[i][1]) for i in range(n)])
    step = ca.Function("step", [x, uu], [xs, h(x, uu)])     # y_k = h(x_k, u_k)
    run = step.mapaccum("seg", N)
    # initial states: the reconstruction, output offsets removed (where each fit starts)
    x0 = data.xs.copy()
    for e in effects:
        for target, term in e.terms(model).items():
            if target in {o.name for o in model.outputs}:
                j = model.output_index(target)
                off = float(model.expand(term).xreplace(
                    {sp.Symbol(k, real=True): float(v) for k, v in values.items()}))
                for i, outs in data.state_outputs.items():
                    if j in outs:   # an offset c of y = g(x) reads as c / g on the state
                        x0[:, i] -= off / sensor_gain(model, j) / len(outs)
    K = len(data.t)
    y_sim = np.full_like(data.y, np.nan)
    # each start fitted on the segment's first samples (discover/initial_state.py)
    M = fit_samples(n, N)
    fit = start_fitter(step, n, len(model.inputs), M)
    sigma = np.asarray(data.noise_std, dtype=float)
    for k0 in k0s:
        k1 = min(k0 + N, K)
        ublock = np.zeros((len(model.inputs), N))
        ublock[:, :k1 - k0] = data.u[k0:k1].T
        if k1 - k0 < N:
            ublock[:, k1 - k0:] = data.u[k1 - 1][:, None]
        start = x0[k0]
        if k1 - k0 >= M:
            start = fitted_start(fit, start, ublock[:, :M], data.y[k0:k0 + M].T, sigma,
                                 lim)
        _, ys = run(start, ublock)
        y_sim[k0:k1] = np.array(ys).T[:k1 - k0]
    use = mask_samples & np.all(np.isfinite(y_sim), axis=1)
    err = data.y[use] - y_sim[use]
    rms = {o.column: float(np.sqrt(np.mean(err[:, j] ** 2)))
           for j, o in enumerate(model.outputs)}
    return {"rms": rms, "t": data.t[use], "y_sim": y_sim[use], "y": data.y[use],
            "substeps": int(substeps), "stiffness": lam}


def fdi_residual_rms(design, u, y, mask_samples, backend: str = "c"):
    """RMS over ``mask_samples`` of every residual of ``design`` run over the whole log.

    Returns
    -------
    (dict, numpy.ndarray, list of str)
        Residual name -> RMS, the raw residuals (K, n_residuals), and the residuals whose
        latched flag is up at the end of the log (a healthy log should raise none).
    """
    from fdigen.detect import fdi_runner

    out = fdi_runner(design, backend).run(u, y)
    r = np.asarray(out["r"], dtype=float)
    rms = {name: float(np.sqrt(np.mean(r[mask_samples, i] ** 2)))
           for i, name in enumerate(design.residual_names)}
    flags = np.asarray(out["flags"], dtype=np.int64)
    last = int(np.bitwise_or.reduce(flags)) if len(flags) else 0
    raised = [name for i, name in enumerate(design.residual_names) if (last >> i) & 1]
    return rms, r, raised


def plot(path, data, E_before, E_after, t_split: float, *, fdi_before=None, fdi_after=None,
         residual_names=(), title: str = "") -> Path:
    """Draw the equation errors (and the FDI residuals) before and after, as a PNG.

    Left column: each tested equation's windowed error ``E_i`` with the calibrated nominal
    model and with the augmented one. Right column (if given): the FDI residuals R1..R5
    of the original and augmented designs. The validation part is shaded.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    tw = data.window_times()
    neq = len(data.equations)
    names = [n for n in residual_names if n in ("R1", "R2", "R3", "R4", "R5")]
    ncol = 2 if fdi_before is not None and names else 1
    nrow = max(neq, len(names) if ncol == 2 else 0)
    fig = Figure(figsize=(6.5 * ncol, 1.8 * nrow + 0.8), dpi=100)
    axes = fig.subplots(nrow, ncol, squeeze=False, sharex=True)
    model = data.model
    for q, name in enumerate(data.equations):
        ax = axes[q, 0]
        ok = data.valid
        ax.plot(tw[ok], E_before[ok, q], lw=0.8, color="tab:red", label="before")
        ax.plot(tw[ok], E_after[ok, q], lw=0.8, color="tab:blue", label="after")
        ax.axvspan(t_split, data.t[-1], color="0.9", zorder=0)
        unit = model.states[model.state_index(name)].unit
        ax.set_ylabel(f"d{name}/dt err\n[{unit}/s]")
        if q == 0:
            ax.legend(loc="upper right", fontsize=7)
            ax.set_title("equation error (modulating windows); validation shaded", fontsize=9)
    axes[neq - 1, 0].set_xlabel("t [s]")
    axes[neq - 1, 0].tick_params(labelbottom=True)
    for q in range(neq, nrow):
        axes[q, 0].set_visible(False)
    if ncol == 2:
        t = data.t
        step = max(len(t) // 4000, 1)
        for q, name in enumerate(names):
            ax = axes[q, 1]
            i = list(residual_names).index(name)
            ax.plot(t[::step], fdi_before[::step, i], lw=0.6, color="tab:red", label="before")
            ax.plot(t[::step], fdi_after[::step, i], lw=0.6, color="tab:blue", label="after")
            ax.axvspan(t_split, t[-1], color="0.9", zorder=0)
            ax.set_ylabel(name)
            if q == 0:
                ax.legend(loc="upper right", fontsize=7)
                ax.set_title("FDI residuals: original vs augmented design", fontsize=9)
        axes[nrow - 1, 1].set_xlabel("t [s]")
        for q in range(len(names), nrow):
            axes[q, 1].set_visible(False)
    return _save(fig, path, title)


def _save(fig, path, title: str = "") -> Path:
    """Title, plain-text labels, layout, and the PNG written atomically with fdigen's
    mark."""
    from fdigen.report import PNG_MARK, plain_text

    if title:
        fig.suptitle(title, fontsize=10)
    plain_text(fig)        # model names and units are text, not TeX
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", metadata={"Software": PNG_MARK})   # fdigen's
    return path


def plot_free_run(path, model, t, y, before, after, title: str = "") -> Path:
    """The output-error loop's figure: each measured output against the free run of the
    calibrated model (before) and with the effects (after), as a PNG."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    ny = len(model.outputs)
    fig = Figure(figsize=(7.5, 1.8 * ny + 0.8), dpi=100)
    axes = fig.subplots(ny, 1, squeeze=False, sharex=True)
    step = max(len(t) // 4000, 1)
    for j, o in enumerate(model.outputs):
        ax = axes[j, 0]
        ax.plot(t[::step], y[::step, j], lw=0.6, color="0.4", label="measured")
        ax.plot(t[::step], _shown(before[::step, j]), lw=0.8, color="tab:red",
                label="calibrated")
        ax.plot(t[::step], _shown(after[::step, j]), lw=0.8, color="tab:blue",
                label="with effects")
        seen = y[:, j][np.isfinite(y[:, j])]
        if seen.size:      # the log's range: a free run that diverges leaves the axes
            lo, hi = float(seen.min()), float(seen.max())
            pad = 0.5 * (hi - lo) or max(abs(hi), 1.0)
            ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(f"{o.name}\n[{o.unit or '-'}]")
        if j == 0:
            ax.legend(loc="upper right", fontsize=7)
            ax.set_title("free-run simulation against the log (output-error loop)",
                         fontsize=9)
    axes[ny - 1, 0].set_xlabel("t [s]")
    return _save(fig, path, title)


def _shown(values):
    """A free run as drawn: values beyond 1e100 (a run that diverged) left out, which
    matplotlib's ticks cannot place (attack 12: ``arange: cannot compute length``)."""
    v = np.asarray(values, dtype=float)
    return np.where(np.abs(v) < 1e100, v, np.nan)


def text_report(result: dict) -> str:
    """A plain-text summary of a discovery result (the dict of ``discover().as_dict()``)."""
    lines = []
    r = result
    held = r["validation"] if isinstance(r["validation"], list) else \
        [r["calibration"][1], r.get("log_end", float("nan"))]
    lines.append(f"log {r['log']}: calibration {r['calibration'][0]:g}-{r['calibration'][1]:g} s,"
                 f" validation {held[0]:g}-{held[1]:g} s")
    cal = ", ".join(f"{k} = {v:.6g} +- {r['calibrated_std'].get(k, float('nan')):.2g}"
                    for k, v in r["calibrated"].items())
    lines.append(f"calibrated (nominal model): {cal}")
    lines.append("equation tests (calibrated nominal model, calibration part):")
    for t in r["tests_before"]:
        lines.append(f"  {t['equation']:6s} rms {t['rms']:.4g}  noise {t['noise']:.4g}  "
                     f"structure {t['structure']:.3f}  Q {t['Q']:.1f}  p {t['p']:.2g}"
                     + ("  <- located" if t["located"] else ""))
    lines.append(r["message"])
    if r["effects"]:
        for name in r["effects"]:
            lines.append(f"effect {name}")
        for k, v in r["parameters"].items():
            lines.append(f"  {k} = {v:.6g} +- {r['uncertainty'].get(k, float('nan')):.2g}")
    lines.append(f"output error RMS on the validation part (re-initialised every "
                 f"{r['reinit']:g} s): before -> after")
    for k in r["error_before"]:
        lines.append(f"  {k:4s} {r['error_before'][k]:.4g} -> {r['error_after'][k]:.4g}")
    free = r.get("noise_ratio_free_run")
    if free:
        # what the verdict read too: a table re-initialised every 250 s looked 10-50x
        # better than the free run on a user's hot-water tank
        reinit = r.get("noise_ratio_after") or {}
        lines.append("the same error over one free run of the validation part, in sensor "
                     "noise levels (re-initialised -> free run): "
                     + ", ".join(f"{k} {reinit.get(k, float('nan')):.3g}x -> {v:.3g}x"
                                 for k, v in free.items()))
    from fdigen.discover.output_loop_view import validation_lines

    lines.extend(validation_lines(r.get("validation")))
    if r.get("fdi_before"):
        lines.append("FDI residual RMS on the validation part: original -> augmented design")
        for k in r["fdi_before"]:
            after = r["fdi_after"].get(k)
            lines.append(f"  {k:4s} {r['fdi_before'][k]:.4g} -> "
                         + (f"{after:.4g}" if after is not None else "(not derived)"))
        lines.append("flags raised over the log: original "
                     f"[{', '.join(r['fdi_flags_before']) or 'none'}] -> augmented "
                     f"[{', '.join(r['fdi_flags_after']) or 'none'}]")
    for w in r.get("warnings", []):
        lines.append(f"warning: {w}")
    for key, label in (("model_file", "augmented model"), ("build", "generated code"),
                       ("plot", "plot")):
        if r.get(key):
            lines.append(f"{label}: {r[key]}")
    return "\n".join(lines)

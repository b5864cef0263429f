"""Thresholds against the measured healthy log: margin over its RMS, and no flag.

A campaign designs thresholds on simulated runs of the commissioned model; the rig is
not the model. The measured healthy log is the one sample of the real plant that is
known healthy, so each threshold must clear it with room to spare:

.. math:: J_i \\ge m_d \\max_k \\mathrm{RMS}_i[k]

over the whole log (the FDI core raises flags from the first sample, start-up included),
``m_d`` the data margin (default 1.5). The RMS trajectory is that of the design with
every flag off (thresholds ``NO_FLAG``: no freeze of the parallel model, as in the
healthy campaign), so it does not depend on the thresholds. A threshold below the bound is
raised to it (rounded up to three digits) and reported. Then the final design, flags on,
runs over the log: the held-back part (after the calibration split) and the whole log
must raise no flag.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from fdigen.discover.design_check import log_rms
from fdigen.tune.model_update import design_with_thresholds
from fdigen.tune.run_notes import EARLY_PEAK_FACTOR, late_start
from fdigen.tune.thresholds import round_up


def check_thresholds(model, thresholds: dict, t, u, y, t_split: float,
                     data_margin: float = 1.5) -> dict:
    """Raise thresholds to ``data_margin`` x the healthy log's max RMS; check no flag.

    Parameters
    ----------
    model : Model
        The commissioned model (its design is derived, cached).
    thresholds : dict
        Residual -> threshold from the campaign.
    t, u, y : numpy.ndarray
        The measured healthy log.
    t_split : float
        Start of the held-back part.
    data_margin : float

    Returns
    -------
    dict
        ``thresholds`` (final), ``raised`` (residual -> {from, to, log_max}), ``log_max``
        and ``log_max_held_back`` (per residual), ``ratio`` (threshold / log max),
        ``flags`` (residual -> first time raised by the final design over the log),
        ``flags_held_back``, ``quiet`` (no flag over the whole log).
    """
    from fdigen.design.cache import cached_design

    design = cached_design(model)
    names = list(design.residual_names)
    rms = log_rms(design, u, y)
    held = np.asarray(t) >= t_split
    peaks = log_peaks(rms, t, names)
    early = sorted(n for n, p in peaks.items() if p["ratio"] >= EARLY_PEAK_FACTOR)
    startup, measured = design.config.startup, None
    if not startup and early:
        measured = settled_startup(rms, t, names, early, design.config.sample_time)
        if measured:
            import dataclasses

            startup = measured
            model = dataclasses.replace(model, fdi={**model.fdi, "startup": measured})
    # the core raises no flag during its start-up: the bound is the RMS after it
    run = np.asarray(t) - float(t[0]) >= startup
    log_max = {n: float(rms[run, i].max()) for i, n in enumerate(names)}
    log_max_held = {n: float(rms[held & run, i].max()) if (held & run).any() else 0.0
                    for i, n in enumerate(names)}
    final, raised = dict(thresholds), {}
    for name, value in thresholds.items():
        need = data_margin * log_max.get(name, 0.0)
        if need > 0 and value < need:
            new, _ = round_up(need)
            raised[name] = {"from": float(value), "to": new, "log_max": log_max[name]}
            final[name] = new
    first = first_flag_times(design_with_thresholds(model, final), t, u, y)
    return {
        "data_margin": data_margin,
        "thresholds": final,
        "raised": raised,
        "log_max": log_max,
        "log_max_held_back": log_max_held,
        "ratio": {n: final[n] / log_max[n] if log_max.get(n, 0) > 0 else None
                  for n in final},
        "flags": first,
        "flags_held_back": {n: v for n, v in first.items() if v >= t_split},
        "quiet": not first,
        "peaks": peaks,
        # still early after the start-up: those it could not cover
        "early": [n for n in early if log_max[n] > 0 and peaks[n]["late_max"] > 0
                  and log_max[n] / peaks[n]["late_max"] >= EARLY_PEAK_FACTOR],
        "startup": measured,
        "startup_residuals": early if measured else [],
    }


def settled_startup(rms, t, names, early, sample_time: float) -> float | None:
    """The start-up ``[fdi] startup`` that covers the early maxima of the residuals
    ``early`` (:func:`log_peaks`), or ``None``: the largest time after which such a
    residual's RMS stays within :data:`~fdigen.tune.run_notes.SETTLED_FACTOR` of its
    maximum over the log's last third (:func:`fdigen.tune.runs.settling`, as tune's runs
    measure it), rounded up to two significant digits (whole samples). A residual still
    above that at the end of the log's first third is not a start-up: ``None`` when none
    settles by then; the others are covered.
    """
    from fdigen.tune.runs import settling

    settled = settling(rms, t)["t_settled"]
    ends = [settled[names.index(n)] for n in early if settled
            and settled[names.index(n)] is not None]
    if not ends or max(ends) <= 0:
        return None
    value = round_up(max(max(ends), sample_time), 2)[0]
    return float(f"{np.ceil(value / sample_time - 1e-9) * sample_time:.12g}")


def log_peaks(rms, t, names) -> dict:
    """Where each residual's maximum RMS over the measured log is: residual ->
    ``{"t_max", "ratio", "late_max", "first_third"}``, ``ratio`` the maximum over the
    maximum over the log's last third, ``first_third`` whether it came in the first.

    A maximum :data:`~fdigen.tune.run_notes.EARLY_PEAK_FACTOR` times the last third's
    (``early`` of
    :func:`check_thresholds`) is the FDI core's start, not the running plant: the core
    starts the states it does not measure at ``[operating_point]``. A user's battery
    started at a charge of 0.9 against an operating point of 0.6; the voltage residual read
    0.15-0.17 V for 1900 s of a 3600 s log (2.3 times its last third), set its threshold
    to 0.264 V (0.0456 V with the operating point at 0.9), and nothing said why.
    """
    rms, t = np.asarray(rms, dtype=float), np.asarray(t, dtype=float)
    K = rms.shape[0]
    if K < 6:
        return {}
    late = rms[late_start(K):]
    out = {}
    for i, n in enumerate(names):
        top, tail = float(rms[:, i].max()), float(late[:, i].max())
        if top > 0:
            k = int(rms[:, i].argmax())
            out[n] = {"t_max": float(t[k]), "late_max": tail, "first_third": k < K // 3,
                      "ratio": top / tail if tail > 0 else float("inf")}
    return out


def hidden_starts_away(model, initial: dict) -> list[str]:
    """The unmeasured states whose start on the log (discover's estimate, ``initial``) is
    more than 5 % of their range from ``[operating_point]``, as text."""
    from fdigen.discover.output_loop import hidden_states

    away = []
    for name in hidden_states(model):
        if name not in initial or name not in model.operating_point:
            continue
        x0, op = float(initial[name]), float(model.operating_point[name])
        st = next(s for s in model.states if s.name == name)
        span = (st.range[1] - st.range[0]) if st.range else max(abs(op), abs(x0), 1e-12)
        if abs(x0 - op) > 0.05 * span:
            away.append(f"{name} started at {x0:.4g} on the log against {op:.4g} at the "
                        "operating point")
    return away


def stateless_residuals(design) -> set:
    """The residuals of ``design`` that read no state of the core (a static relation of
    the sensors and inputs): their value at a sample depends on that sample alone, so a
    start of the core away from the plant cannot raise them."""
    prog = design.step
    states = set(prog.inputs.get("z", ()))
    deps: dict = {}

    def reach(expr) -> set:
        out = set()
        for s in expr.free_symbols:
            out |= deps.get(s, {s})
        return out

    for sym, expr in prog.assignments:
        deps[sym] = reach(expr)
    return {n for n, e in zip(design.residual_names, prog.outputs["r"])
            if not reach(sp.sympify(e)) & states}


def early_start_warning(peaks: dict, names: list, away: list, stateless=()) -> str:
    """The warning for thresholds the log raised at its start (``peaks``: residual ->
    ``{"t_max", "ratio"}`` of :func:`~fdigen.commission.healthy_check.log_peaks`;
    ``away``: :func:`hidden_starts_away`; ``stateless``: :func:`stateless_residuals`,
    which a start of the core cannot raise: a user's current transducer read 0.19 V on
    the log's first sample against 4.12 V predicted, and the warning blamed the hidden
    element temperature, which that residual does not read)."""
    static = [n for n in names if n in set(stateless)]
    names = [n for n in names if n not in set(stateless)]
    parts = []
    if static:
        parts.append(
            "threshold " + ", ".join(
                f"{n} (the log's maximum at {peaks[n]['t_max']:.4g} s is "
                f"{peaks[n]['ratio']:.3g} times its maximum over the log's last third)"
                for n in static)
            + " raised by the log's first samples, not by the running plant: "
            + ("it reads" if len(static) == 1 else "they read") + " no state of the core "
            "(a relation of the sensors and inputs at one sample), so the log's start "
            "itself disagrees with the model there (a sensor or transducer settling, a "
            "logger's first row). The design is that much less sensitive for the whole "
            "run: commission on a log without that start (cut its first samples), or give "
            "the core a start-up without flags ([fdi] startup, seconds)")
    if names:
        parts.append(_hidden_start_text(peaks, names, away))
    return "; ".join(parts)


def _hidden_start_text(peaks: dict, names: list, away: list) -> str:
    return ("threshold " + ", ".join(
        f"{n} (the log's maximum at {peaks[n]['t_max']:.4g} s is {peaks[n]['ratio']:.3g} "
        "times its maximum over the log's last third)" for n in names)
        + " raised by the log's start, not by the running plant: the FDI core starts the "
        "states it does not measure at [operating_point]"
        + (" (" + "; ".join(away) + ")" if away else "")
        + ", and its models take that long to follow the plant. The design is that much "
        "less sensitive for the whole run: set [operating_point] to where the rig starts, "
        "measure those states, or give the core a start-up without flags ([fdi] startup, "
        "seconds; commission sets it when the residual comes down within the log's first "
        "third)")


def startup_note(check: dict) -> str:
    """What the measured start-up (``check["startup"]`` of :func:`check_thresholds`) is
    and why it was set."""
    from fdigen.tune.run_notes import startup_words

    peaks = check["peaks"]
    return startup_words(check["startup"], "the log's",
                         [(n, peaks[n]["t_max"], peaks[n]["ratio"])
                          for n in check["startup_residuals"]],
                         "the thresholds clear the log after it")


def first_flag_times(design, t, u, y) -> dict:
    """Residual -> the time of its first flag when ``design`` (flags on) runs over the log
    ``(t, u, y)`` in the C core, as ``fdigen detect`` runs it; residuals that never flag
    are left out."""
    from fdigen.detect import fdi_runner

    flags = np.asarray(fdi_runner(design, "c").run(u, y)["flags"], dtype=np.int64)
    t = np.asarray(t)
    first = {}
    for i, n in enumerate(design.residual_names):
        on = np.flatnonzero(flags >> i & 1)
        if on.size:
            first[n] = float(t[on[0]])
    return first


def short_log_warning(seconds: float, run: float) -> str | None:
    """A warning when the commissioning log is shorter than the campaign's runs, or None.

    The thresholds are fitted to simulated runs of ``run`` seconds and checked on the log;
    a user's 6-minute log against 3600 s runs was accepted without a word, and its design
    raised a false alarm on the rig's next healthy hour."""
    if seconds >= run:
        return None
    return (f"the commissioning log holds {seconds:.4g} s of the rig; the campaign's "
            f"runs are {run:.4g} s: the calibration and the check of the thresholds on the "
            f"rig rest on {100 * seconds / run:.2g} % of a run (slow drifts, warm-up and "
            "the set-points the log does not visit are unchecked); a log at least as long "
            "as a run commissions what the design will meet")

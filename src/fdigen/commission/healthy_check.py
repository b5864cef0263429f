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

from fdigen.discover.design_check import log_rms
from fdigen.tune.model_update import design_with_thresholds
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
    log_max = {n: float(rms[:, i].max()) for i, n in enumerate(names)}
    log_max_held = {n: float(rms[held, i].max()) if held.any() else 0.0
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
    }


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

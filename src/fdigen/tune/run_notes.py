"""What a campaign says about its own runs: residuals whose healthy maximum comes from
the FDI core's start (:func:`early_peaks`), and a raise of the simulated plant's RK4
sub-steps over the tolerance box (:func:`substeps_raise`)."""

from __future__ import annotations

import numpy as np


#: A healthy maximum this many times the maximum over the run's last third, in most runs, came
#: from the start (the FDI core's unmeasured states start at the operating point).
EARLY_PEAK_FACTOR = 3.0


def late_start(K: int) -> int:
    """The first sample of a run's last third, where a start-up transient has passed: a
    maximum :data:`EARLY_PEAK_FACTOR` times that part's came from the start."""
    return 2 * int(K) // 3


def early_peaks(healthy: list[dict], names, settle: float) -> dict:
    """Residuals whose healthy maximum (after ``settle`` s) is at least
    :data:`EARLY_PEAK_FACTOR` times their maximum over the last third of the run in more
    than half the healthy runs: the threshold is set by how the core starts, not by the
    running plant. Residual -> ``{"median_t_max", "ratio"}`` (median over the runs of the
    maximum's time and of maximum / last-third maximum).

    A first-time user's Li-ion cell: the core starts its charge state at the operating
    point (0.6), the plant at [simulation] initial (0.8); its filter took 1000 s to
    converge and set thresholds 7-11 times those with a matching operating point. (The
    last third, not the second half: another user's battery took 1900 s of a 3600 s run.)
    """
    out = {}
    for n in names:
        ratios = [r["max_rms"][n] / r["max_rms_late"][n] if r["max_rms_late"][n] > 0
                  else np.inf for r in healthy if r["max_rms"][n] > 0]
        if ratios and np.mean(np.asarray(ratios) >= EARLY_PEAK_FACTOR) > 0.5:
            out[n] = {"median_t_max": float(np.median([r["t_max"][n] for r in healthy])),
                      "ratio": float(np.median(ratios)), "settle": settle}
    return out


def substeps_raise(plant, settings) -> dict | None:
    """The campaign's raise of the plant's RK4 sub-steps (:func:`fdigen.tune.cases.
    campaign_raise`) with its ``text``, or ``None``."""
    from fdigen.tune.cases import campaign_raise

    raised = campaign_raise(plant, settings)
    if raised is None:
        return None
    values = {q.name: q.value for q in plant.parameters}
    at = ", ".join(f"{k} {100 * (v / values[k] - 1):+.3g} %" if values.get(k)
                   else f"{k} = {v:.4g}"
                   for k, v in (raised["at"] or {}).items() if v != values.get(k))
    raised["text"] = (
        f"the simulated plant's RK4 sub-steps raised from {raised['nominal']} to "
        f"{raised['used']} per sample for the campaign: the plant at {at} needs "
        f"{raised['needed']} to be integrated stably"
        + ("" if raised["used"] == raised["needed"] else
           f"; the campaign uses at most {raised['used']} (4 x the model's): runs near that "
           "corner may diverge, and are then not counted; a narrower spread there, or "
           "[simulation] substeps, decides it"))
    return raised


def early_peak_text(name: str, e: dict) -> str:
    """The warning for one entry of :func:`early_peaks`."""
    return (f"{name}'s healthy maximum comes early (median at {e['median_t_max']:.4g}\u00a0s) "
            f"and is {e['ratio']:.3g} times its maximum over the last third of the runs: "
            "its threshold is set by how the FDI core starts, not by the running plant. The "
            "core starts the states it does not measure (and its parallel models) at "
            "[operating_point]; a plant that starts elsewhere ([simulation] initial, or the "
            "equilibrium of the campaign's drawn parameters) takes that long to be followed. "
            "Make them agree, measure those states, or accept a design that is this much "
            "less sensitive for the whole run")

"""What a campaign says about its own runs: residuals whose healthy maximum comes from
the FDI core's start (:func:`early_peaks`), and a raise of the simulated plant's RK4
sub-steps over the tolerance box (:func:`substeps_raise`)."""

from __future__ import annotations

import numpy as np


#: A healthy maximum this many times the maximum over the run's last third, in most runs, came
#: from the start (the FDI core's unmeasured states start at the operating point).
EARLY_PEAK_FACTOR = 3.0


#: A residual has settled from the core's start once its RMS stays within this factor of
#: its maximum over the run's last third.
SETTLED_FACTOR = 1.25


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


#: A healthy maximum after this fraction of the run, in most runs, is a residual growing
#: through the run.
LATE_PEAK_FRACTION = 0.95


def growing_residuals(healthy: list[dict], names, duration: float) -> dict:
    """Residuals whose healthy maximum comes in the last 5 % of the run in more than half
    the healthy runs: they grow through the run (an open-loop balance drifting with the
    parameter spread), so a run longer than the campaign's crosses any threshold it set.
    Residual -> ``{"runs", "of"}`` (runs with the late maximum, runs).

    A user's reactor: the volume balance R3 peaked at the last sample of all 16 healthy
    runs of 1800 s; a plant inside the tolerance (k0 +8 %) run for 7200 s crossed its
    threshold at 3075 s, a false safety stop, and tune had said nothing.
    """
    out = {}
    if not healthy or not duration:
        return out
    for n in names:
        late = [r for r in healthy if r["max_rms"].get(n, 0) > 0
                and r["t_max"][n] >= LATE_PEAK_FRACTION * duration]
        if 2 * len(late) > len(healthy):
            out[n] = {"runs": len(late), "of": len(healthy)}
    return out


def growing_text(growing: dict, duration: float) -> str:
    """The warning for :func:`growing_residuals`."""
    return (", ".join(f"{n} (in {g['runs']} of {g['of']} healthy runs)"
                      for n, g in growing.items())
            + f" peaked in the last 5 % of the run: the residual grows through a healthy run "
            f"of {duration:g} s, so a longer run crosses any threshold this campaign set (a "
            "false alarm the validation runs, as long as these, cannot show). Run the "
            "campaign as long as the plant runs between restarts (--duration), or re-align "
            "that residual's model ([fdi] realign_noise_scale)")


def campaign_startup(healthy: list[dict], names, early) -> dict | None:
    """The ``[fdi] startup`` that covers the early maxima (:func:`early_peaks`) of the
    healthy runs, and their maxima after it, or ``None``.

    .. math:: T_s = \\max_{r,\\, i \\in E} t^{r}_{\\mathrm{settled},i}

    (:func:`fdigen.tune.runs.settling`) over the residuals ``E`` of ``early`` that settle
    within the first third of every run, rounded up to two digits and then to the next
    point of the runs' ``suffix_max``; ``None`` when none does.

    Returns
    -------
    dict or None
        ``seconds`` (:math:`T_s`), ``residuals`` (those it covers), ``maxima`` (per run,
        residual -> maximum RMS after :math:`T_s`), ``settled`` (residual -> the largest
        settling time over the runs).
    """
    from fdigen.tune.thresholds import round_up

    runs = [r for r in healthy if r.get("suffix_max", {}).get("t")]
    if not runs or not early:
        return None
    settled = {}
    for n in early:
        j = list(names).index(n)
        times = [r["t_settled"][j] for r in runs]
        if all(v is not None for v in times):
            settled[n] = max(times)
    if not settled or max(settled.values()) <= 0:
        return None
    want = round_up(max(settled.values()), 2)[0]
    grid = runs[0]["suffix_max"]["t"]
    k = next((i for i, v in enumerate(grid) if v >= want - 1e-9), None)
    if k is None or any(len(r["suffix_max"]["t"]) != len(grid) for r in runs):
        return None
    return {"seconds": float(f"{grid[k]:.12g}"), "residuals": sorted(settled),
            "settled": settled,
            "maxima": [dict(zip(names, r["suffix_max"]["max"][k])) for r in runs]}


def after_startup(runs: list[dict], names, seconds: float, settle: float) -> None:
    """Each run's maxima as a core with ``seconds`` of start-up sees them (in place): the
    RMS maximum after the start-up (``suffix_max``) replaces the maximum after ``settle``
    when the start-up is the longer, else the maximum over the settling, which no longer
    includes the start-up, with it as a bound."""
    for r in runs:
        grid = r.get("suffix_max", {}).get("t") or []
        k = next((i for i, v in enumerate(grid) if v >= seconds - 1e-9), None)
        if k is None:
            continue
        after = dict(zip(names, r["suffix_max"]["max"][k]))
        if seconds >= settle:
            r["max_rms"] = after
            r["max_rms_startup"] = {n: 0.0 for n in names}
        else:
            r["max_rms_startup"] = {n: min(r["max_rms_startup"][n], after[n]) for n in names}


def startup_words(seconds: float, whose: str, peaks, after: str) -> str:
    """The note for a start-up of ``seconds`` chosen from ``peaks`` (``(residual, time of
    its maximum, maximum over the last third's)``) of ``whose`` residuals."""
    return (f"[fdi] startup = {seconds:g} s: the core raises no flag during its first "
            f"{seconds:g} s, where {whose} "
            + ", ".join(f"{n} (maximum at {t:.4g} s, {ratio:.3g} x its maximum over the "
                        "last third)" for n, t, ratio in peaks)
            + " came down from the core's start (its models follow hidden states that "
            f"start elsewhere than [operating_point]); {after}. A fault present at the "
            "start is seen only then")


def startup_text(found: dict, early: dict) -> str:
    """What :func:`campaign_startup` chose, in words."""
    return startup_words(found["seconds"], "the healthy runs'",
                         [(n, early[n]["median_t_max"], early[n]["ratio"])
                          for n in found["residuals"]],
                         "the thresholds are fitted after it (--write writes it)")


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
            "Make them agree, measure those states, give the core a start-up without "
            "flags that long ([fdi] startup, seconds; tune sets it when the residual "
            "comes down within the first third of every run), or accept a design that is "
            "this much less sensitive for the whole run")

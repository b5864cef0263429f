"""The ambiguity time a campaign measures: how long isolation takes before the default
policy acts on an ambiguity.

With ``[fdi] ambiguity = "most_severe"`` the core takes the most severe action of the
consistent classes once the ambiguity has lasted ``ambiguity_time``, by default the
confirmation time (a few samples). A fault whose first flags are also those of a fault of
a more severe class (:func:`~fdigen.design.ambiguity_exposure.severe_under_ambiguity`)
then gets that action before its own flags isolate it: users' fan motor stopped on a
0.2 V tachometer offset (isolated 1.16 s after its first flag, the tachometer's action
``accommodate``), and an oven switched from its healthy control thermocouple on the
other thermocouple's drift (``none``).

``fdigen tune`` measures the time from detection to the correct isolation of every such
fault in the campaign (sizes at and above the test size), and proposes

.. math:: T_a = 1.5 \\max_{f\\,\\text{exposed}} \\max_{\\text{runs}}
          (t_\\text{isolation} - t_\\text{detection}),

rounded up to the sample time and never below the confirmation time: a fault that
isolates gets its own class's action, and a real ambiguity still gets the most severe
action, at most ``T_a`` later. Exposed faults the campaign never isolates at the test
size are named (they keep the severe action). A proposal is not written when a fault
of the more severe classes was detected and not isolated in a campaign run
(:func:`held_back`): its action would wait the ambiguity time.
"""

from __future__ import annotations

import dataclasses
import math

#: The measured delay is multiplied by this.
MARGIN = 1.5


def exposed_faults(model, fdi_values: dict | None = None):
    """The faults the default policy may act on more severely than their class (the
    design of ``model`` with ``fdi_values`` set, thresholds irrelevant), and that design's
    configuration."""
    from fdigen.design.ambiguity_exposure import severe_under_ambiguity
    from fdigen.design.cache import cached_design
    from fdigen.tune.model_update import fill_missing_thresholds
    from fdigen.tune.settings import NO_FLAG

    if fdi_values:
        model = dataclasses.replace(model, fdi={**model.fdi, **fdi_values})
    design = cached_design(fill_missing_thresholds(model, NO_FLAG)[0])
    return severe_under_ambiguity(design), design.config


def measured_ambiguity_time(report: dict, model, fdi_values: dict | None = None
                            ) -> dict | None:
    """The proposal of the module from the campaign ``report`` of ``model``; None when the
    file sets ``ambiguity_time`` or another policy, or no fault is exposed.

    Returns
    -------
    dict or None
        ``{"seconds", "measured", "limited_by", "exposed", "never_isolated",
        "default"}``: the proposed time (None when nothing was measured or it would not
        exceed the confirmation time), the largest detection-to-isolation delay and the
        fault it belongs to, the exposed faults, those never isolated at the test size,
        and the confirmation time it replaces.
    """
    fdi = {**model.fdi, **(fdi_values or {})}
    if "ambiguity_time" in fdi or fdi.get("ambiguity", "most_severe") != "most_severe":
        return None
    faults = report.get("faults") or {}
    if not faults:
        return None
    exposed, cfg = exposed_faults(model, fdi_values)
    if not exposed:
        return None
    dt = cfg.sample_time
    default = cfg.confirm * dt
    worst, by, never = 0.0, None, []
    for name in exposed:
        entry = faults.get(name)
        if entry is None:
            continue
        delays = []
        for b in entry.get("by_size", ()):
            if float(b.get("factor", 0.0)) < 1.0 - 1e-9 or not b.get("isolated_correct"):
                continue
            iso, det = b.get("isolation_delay") or {}, b.get("detection_delay") or {}
            if iso.get("max") is not None and det.get("min") is not None:
                delays.append(max(0.0, float(iso["max"]) - float(det["min"])))
        if delays:
            if max(delays) > worst:
                worst, by = max(delays), name
        else:
            never.append(name)
    seconds = None
    if by is not None and dt > 0:
        proposed = math.ceil(MARGIN * worst / dt - 1e-9) * dt
        if proposed > default + 1e-12:
            seconds = float(f"{proposed:.6g}")
    held = held_back(faults, exposed) if seconds is not None else {}
    return {"seconds": None if held else seconds, "withheld": seconds if held else None,
            "held_back": held, "measured": worst if by else None, "limited_by": by,
            "exposed": sorted(exposed), "never_isolated": sorted(never),
            "default": default}


def held_back(faults: dict, exposed: dict) -> dict:
    """The faults of the more severe classes whose action an ambiguity time would hold
    back: ``{fault: {"waiting", "detected"}}``, the campaign's runs (at and above the test
    size) that detected the fault without isolating its class, of those that detected it.

    Such a fault gets its class's action only through the ambiguity policy, so the
    ambiguity time is the delay of that action: a user's furnace, whose heater loss
    (``safety_stop``) shared its flags with a thermocouple drift, would have waited the
    proposed 1966 s. A proposal that holds back a campaign's fault is not written."""
    severe = sorted({g for _, _, others in exposed.values() for g in others})
    out = {}
    for g in severe:
        waiting = detected = 0
        for b in (faults.get(g) or {}).get("by_size", ()):
            if float(b.get("factor", 0.0)) < 1.0 - 1e-9:
                continue
            det = int(b.get("detected", 0))
            detected += det
            waiting += max(0, det - int(b.get("isolated_correct", 0)))
        if waiting:
            out[g] = {"waiting": waiting, "detected": detected}
    return out


def ambiguity_text(found: dict, written: str = "--write writes it") -> str:
    """One paragraph on the proposal (``written``: what becomes of it)."""
    parts = []
    if found.get("held_back"):
        held = ", ".join(f"{g} (detected and not isolated in {e['waiting']} of "
                         f"{e['detected']} runs)" for g, e in found["held_back"].items())
        parts.append(
            f"ambiguity time NOT written: {found['withheld']:g} s ({MARGIN:g} x the "
            f"{found['measured']:.4g} s {found['limited_by']} takes from detection to "
            f"isolation) would hold back the more severe action of {held}: their "
            "class's action comes only through the ambiguity policy, so it would wait that "
            f"long. The exposed faults ({', '.join(found['exposed'])}) keep the more severe "
            f"action after {found['default']:g} s (confirm); setting [fdi] ambiguity_time "
            "yourself trades one against the other, a residual that separates them "
            "(`fdigen inspect`) removes the trade")
    if found["seconds"] is not None:
        parts.append(
            f"ambiguity time: {found['seconds']:g} s ({MARGIN:g} x the longest time from "
            f"detection to isolation of a fault the default policy could act on too "
            f"severely, {found['measured']:.4g} s for {found['limited_by']}; it was "
            f"{found['default']:g} s, the confirmation time): such a fault gets its own "
            "class's action once isolated, a lasting ambiguity the most severe action at "
            f"most {found['seconds']:g} s after its first flag ([fdi] ambiguity_time; "
            f"{written})")
    if found["never_isolated"]:
        parts.append(
            f"{', '.join(found['never_isolated'])}: their first flags are also those of a "
            "class with a more severe action, and the campaign never isolated them at the "
            "test size, so no ambiguity time spares them that action (ambiguity = "
            "\"wait\" would, at the price of waiting on a real fault of that class too; "
            "`fdigen inspect` names the sensor that would separate them where no residual "
            "does, and `fdigen inspect --sensitivity` the size from which the residuals "
            "that do separate them cross their thresholds)")
    return "; ".join(parts)

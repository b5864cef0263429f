"""Summary of the fault campaign: detection and isolation per fault and per fault size.

Holds :func:`summarise_faults` and its helpers :func:`_stats` (n/min/median/max of the
delays) and :func:`_count`.
"""

from __future__ import annotations

import numpy as np

from fdigen.design.evaluation import HORIZON_NONE


def _stats(values) -> dict:
    v = [x for x in values if x is not None]
    if not v:
        return {"n": 0, "min": None, "median": None, "max": None}
    return {"n": len(v), "min": float(np.min(v)), "median": float(np.median(v)),
            "max": float(np.max(v))}


def _count(items) -> dict:
    out = {}
    for x in items:
        out[x] = out.get(x, 0) + 1
    return dict(sorted(out.items()))


def summarise_faults(results: list[dict]) -> dict:
    """Per fault: detection and isolation over the campaign, and per size.

    Returns
    -------
    dict
        fault -> ``class``, ``runs``, ``detected``, ``missed``, ``detection_delay``
        (``n``/``min``/``median``/``max`` in s), ``isolated_correct``,
        ``false_isolations``, ``not_isolated``, ``isolation_delay``,
        ``false_alarms_before_onset``, ``off_signature`` and
        ``off_signature_before_isolation`` (residual -> runs in which a residual outside
        the fault's structural signature was raised, at all / before the isolation was
        confirmed: the latter block isolation), ``by_size`` (list of the same per size).
    """
    out = {}
    by_fault = {}
    for r in results:
        by_fault.setdefault(r["fault"], []).append(r)

    def block(rs):
        return {
            "runs": len(rs),
            "detected": sum(r["detected"] for r in rs),
            "missed": sum(not r["detected"] for r in rs),
            "detection_delay": _stats([r["detection_delay"] for r in rs]),
            "isolated_correct": sum(r["isolation_correct"] for r in rs),
            "false_isolations": sum(wrong_isolation(r) for r in rs),
            "isolated_before_onset": sum(isolated_before_onset(r) for r in rs),
            "not_isolated": sum(r["isolated"] == "none" for r in rs),
            "unexplained": sum(r.get("t_unexplained") is not None for r in rs),
            "action_taken": sum(bool(r.get("action")) for r in rs),
            "isolation_delay": _stats([r["isolation_delay"] for r in rs
                                       if r["isolation_correct"]]),
            "false_alarms_before_onset": sum(r["false_alarm_before_onset"] for r in rs),
            "isolated_as": sorted({r["isolated"] for r in rs}),
            "off_signature_before_isolation": _count(
                [x for r in rs for x in r.get("off_signature_before_isolation", ())]),
            "off_signature": _count([x for r in rs for x in r.get("off_signature", ())]),
            "fault_isolated": sum(bool(r.get("fault_isolated")) for r in rs),
            # the narrowest set the table allows for this fault (the same in every run)
            "fault_set_best": next((r["fault_set_best"] for r in rs
                                    if r.get("fault_set_best")), []),
            "fault_inconsistent": sum(r.get("fault_consistent") is False for r in rs),
            "entry_delay_max": _entry_delays(rs),
        }

    for name, rs in by_fault.items():
        entry = {"class": rs[0]["fault_class"], "ramp": any(r["ramp"] for r in rs),
                 **block(rs)}
        sizes = []
        for ramp, size in sorted({(bool(r["ramp"]), r["size"]) for r in rs},
                                 key=lambda k: (k[0], abs(k[1]))):
            sub = [r for r in rs if bool(r["ramp"]) == ramp and r["size"] == size]
            b = block(sub)
            sizes.append({"size": size, "factor": sub[0]["factor"],
                          "kind": "ramp" if ramp else "step",
                          "detection_rate": b["detected"] / b["runs"],
                          "isolation_rate": b["isolated_correct"] / b["runs"], **b})
        entry["by_size"] = sizes
        at_test = [r for r in rs if r["factor"] == 1.0]
        entry["isolation_rate_at_test_size"] = (
            sum(r["isolation_correct"] for r in at_test) / len(at_test) if at_test else None)
        out[name] = entry
    return out


def poorly_isolated(faults: dict, class_isolable, limit: float = 0.9) -> dict:
    """Class-isolable faults isolated in fewer than ``limit`` of their runs at test size.

    Parameters
    ----------
    faults : dict
        :func:`summarise_faults`'s result.
    class_isolable : collection of str
        Faults whose signature is strongly isolated from every fault of another class.

    Returns
    -------
    dict
        fault -> its isolation rate at test size (factor 1, steps and ramps together).
    """
    return {name: f["isolation_rate_at_test_size"] for name, f in faults.items()
            if name in class_isolable and f["isolation_rate_at_test_size"] is not None
            and f["isolation_rate_at_test_size"] < limit}


def unreached_separators(design, fault_runs, poorly: dict) -> dict:
    """For each poorly isolated fault, the residuals that would separate it from the
    faults of other classes (in its signature, outside theirs) and what became of them
    in the fault's runs at the test size: ``fault -> {residual: text}``, ``"0.74 of its
    threshold"`` (the largest RMS reached) or ``"late: 412 s after the first flag,
    horizon 30 s"`` (raised after its validity horizon, so the class decision left it
    out). Separators that did their job in every run are left out.

    A user's boiler: the level-transmitter offset was "class-isolable but isolated in
    0 %", and nothing said why.
    """
    table, ev = design.signature_table, design.evaluation
    limit = dict(zip(ev.residuals, (float(v) for v in ev.thresholds)))
    dt = design.config.sample_time
    horizon = dict(zip(ev.residuals, ev.horizons)) if ev.horizons else {}
    cls = {f.name: f.fault_class for f in design.model.faults}
    out = {}
    for name in poorly:
        sep = set()
        for g, sig in table.items():
            if cls.get(g) != cls.get(name):
                sep |= set(table[name]) - set(sig)
        sep = {r for r in sep if not r.startswith("nf_") and limit.get(r, 0) > 0}
        runs = [r for r in fault_runs if r["fault"] == name and r.get("factor") == 1.0]
        notes = {}
        for res in sorted(sep):
            reached = max((run["max_rms"].get(res, 0.0) for run in runs), default=0.0)
            if reached < limit[res]:
                notes[res] = f"{reached / limit[res]:.2f} of its threshold"
                continue
            late, raised = [], 0
            for run in runs:
                t_r = (run.get("t_raised") or {}).get(res)
                if t_r is None or run.get("detection_delay") is None:
                    continue
                raised += 1
                after = t_r - (run["t0"] + run["detection_delay"])
                h = horizon.get(res)
                if h is not None and h < HORIZON_NONE and after > h * dt:
                    late.append((after, h * dt))
            if late and len(late) == raised:   # raised only after its horizon
                after, h = max(late)
                notes[res] = f"late: {after:.4g} s after the first flag, horizon {h:.4g} s"
        if notes:
            out[name] = notes
    return out


def _entry_delays(rs) -> dict:
    """Largest delay after the onset of each signature entry's flag, over the runs."""
    out = {}
    for r in rs:
        for res, d in (r.get("entry_delays") or {}).items():
            out[res] = max(out.get(res, d), d)
    return dict(sorted(out.items()))


def isolated_before_onset(run: dict) -> bool:
    """Whether the run's class was isolated before its fault started: a false alarm's
    isolation (the run never tested the fault)."""
    return run.get("t_isolated") is not None and run["t_isolated"] < run["t0"]


def wrong_isolation(run: dict) -> bool:
    """A class other than the injected fault's isolated after the fault started (an
    isolation before it is a false alarm's, counted as such)."""
    return run.get("isolated", "none") not in ("none", run["fault_class"]) \
        and not isolated_before_onset(run)


def wrong_isolations_by_class(results: list[dict]) -> dict:
    """Class -> fault runs isolated as that class, after the fault started, while another
    class's fault was injected (0 for every class in a sound design; see
    ``docs/isolation.md``)."""
    out = {}
    for r in results:
        if wrong_isolation(r):
            out[r["isolated"]] = out.get(r["isolated"], 0) + 1
    return dict(sorted(out.items()))

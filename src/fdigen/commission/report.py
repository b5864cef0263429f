"""The text report of ``fdigen commission``: what was found, thresholds, delays, false alarms."""

from __future__ import annotations


def _g(v, fmt=".3g") -> str:
    return "-" if v is None else format(v, fmt)


def delays_by_kind(d: dict) -> str:
    """`` (steps 0.3, ramps 146)``: the median detection delay of each kind of a sensor
    fault's cases, when it ran as steps and as ramps (a user read "level_tx 2/2 detected,
    detection 146" of an offset their own log showed flagged 0.3 s after its onset: the
    median of a step's and a ramp's delays); nothing for one kind."""
    import statistics

    kinds = {}
    for b in d.get("by_size") or ():
        if b.get("detection_delay") is not None:
            kinds.setdefault(b.get("kind") or "step", []).append(float(b["detection_delay"]))
    if len(kinds) < 2:
        return ""
    order = sorted(kinds.items(), key=lambda kv: kv[0] != "step")
    return " (" + ", ".join(f"{k}s {_g(statistics.median(v))}" for k, v in order) + ")"


def text_report(r: dict) -> str:
    """Human-readable summary of :func:`fdigen.commission.pipeline.commission`'s result."""
    from fdigen.commission.validation_logs import validation_text

    lines = [f"commissioned model: {r['model_file']}"]
    eff = ", ".join(r["effects"]) or "no effect (model calibrated only)"
    lines.append(f"found: {eff}")
    if r.get("explains") is False and r.get("noise_ratio"):
        # a user's servo with a backlash the library lacks: "found: no effect" and
        # "usable", while discover said 12.4x the noise
        worst, ratio = max(r["noise_ratio"].items(), key=lambda kv: kv[1])
        named = any(worst in w for w in r.get("warnings") or ())
        lines.append(f"fit: the commissioned model does not explain the log ({worst} at "
                     f"{ratio:.3g}x its sensor noise): the thresholds carry the model's "
                     "error, not only the noise; "
                     + ("discover's warnings name what may be missing" if named else
                        f"no warning of discover concerns {worst}: what the model lacks "
                        "there is outside discover's effect library (docs/discover.md "
                        "lists it; a sensor's lag, radiation, a quadratic pipe friction "
                        "are not in it): write that term into the model (a lag as a state "
                        "of its own) and commission again"))

    def pm(k):   # a parameter held at its datasheet value has no interval
        sd = r["uncertainty"].get(k)
        return " (held)" if sd is None else f" +- {sd:.2g}"

    pars = ", ".join(f"{k} = {v:.5g}{pm(k)}"
                     for k, v in r["parameters"].items())
    lines.append(f"parameters: {pars}")
    c = r["campaign"]
    lines.append(f"campaign: {c['runs']} healthy runs of {c['duration']:g} s, parameters "
                 + (", ".join(f"{k} +-{100 * v:.3g} %"
                              for k, v in sorted(c.get("tolerances", {}).items()))
                    or f"+-{100 * c['tolerance']:.3g} %")
                 + f", {c['fault_runs']} fault runs")
    hc = r["healthy_check"]
    lines.append(f"thresholds (datasheet design -> campaign -> final; final / measured "
                 f"healthy max RMS, >= {hc['data_margin']:g}):")
    for n, v in r["thresholds"].items():
        before = r["thresholds_before"].get(n)
        ratio = hc["ratio"].get(n)
        mark = "  raised by the log" if n in r["raised"] else ""
        lines.append(f"  {n:6s} {_g(before):>10s} -> {_g(r['thresholds_campaign'].get(n)):>10s}"
                     f" -> {_g(v):>10s}   x{_g(ratio, '.2f')}{mark}")
    lines.append("measured healthy log with the final thresholds: "
                 + ("no flag" if hc["quiet"] else "flags " + ", ".join(
                     f"{k} at {t:.3f} s" for k, t in hc["flags"].items())))
    for c in r.get("validation_logs") or ():
        worst = max(c["peak_over_threshold"].items(), key=lambda kv: kv[1],
                    default=(None, 0.0))
        lines.append(f"healthy validation log {c['log']} with the final thresholds: "
                     + ("FLAGS (false alarms) " + ", ".join(
                         f"{k} at {t:.6g} s" for k, t in c["flags"].items())
                        if not c["quiet"] else validation_text(c))
                     + (f" (largest RMS over its threshold: {worst[0]} at "
                        f"{100 * worst[1]:.3g} %)" if worst[0] else ""))
    fa = r["false_alarm"]
    lines.append(f"false alarms: {fa['validation_false_alarms']}/{fa['validation_runs']} fresh "
                 f"simulated healthy runs (95 % upper bound {fa['validation_upper_95']:.2g} "
                 f"per {fa['run_duration']:g} s run; fitted at the campaign thresholds "
                 f"{_g(fa['fitted_campaign_thresholds'], '.2g')})")
    acc = r.get("substeps_accuracy")
    if acc:
        lines.append(("" if acc["converged"] else "warning: ") + acc["text"])
    lines.append("faults (campaign): detected, isolated to the right class, median delays "
                 "[s] (detection over the detected runs, isolation over the isolated ones)")
    for name, d in r["delays"].items():
        lines.append(f"  {name:26s} {d['detected']}/{d['runs']} detected, "
                     f"{d['isolated_correct']}/{d['runs']} isolated ({d['class']}"
                     + (f"; {d['false_isolations']}/{d['runs']} WRONG"
                        if d.get("false_isolations") else "") + "), "
                     f"detection {_g(d['detection_delay_median'])}{delays_by_kind(d)}, isolation "
                     f"{_g(d['isolation_delay_median'])}")
    if r.get("sensitivity"):
        lines.append("fault sensitivity (campaign: smallest size detected / isolated in every "
                     "run, largest isolation delay at that size)")
        lines.extend(f"  {e['text']}" for e in r["sensitivity"].values())
    for w in r["warnings"]:
        lines.append(f"warning: {w}")
    v = r.get("verdict")
    for lim in (v or {}).get("limits", ()):
        lines.append(f"DETECTION ONLY: {lim}")
    if v and not v["usable"]:
        lines.append("REFUSED: this design is of no use as it stands:")
        lines.extend(f"  - {f}" for f in v["failures"])
        lines.append("what would fix it:")
        lines.extend(f"  - {f}" for f in v["fixes"])
    if r.get("build"):
        lines.append(f"generated code: {r['build']}")
    lines.append(f"time: {r['timing']['total']:.1f} s")
    return "\n".join(lines)

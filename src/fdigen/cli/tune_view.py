"""The text view of a ``fdigen tune`` report: the realignment search's paragraph and the
tables and warnings ``_print_tune`` prints (:mod:`fdigen.cli.tune_cmd` runs the command).
"""

from __future__ import annotations


def realign_text(search: dict) -> str:
    """The realignment search (:mod:`fdigen.tune.realign_search`): one line per scale
    tried, and which was taken and why (a user's CSTR read one sentence of counts in which
    0.2 was taken "while tying on every count": its thresholds were narrower)."""
    def cases(score):
        return ", ".join(f"{f} {k}" for f, k in score["detected"]) or "none"

    from fdigen.tune.realign_search import WIDE, drifts_absorbed

    b = search["before"]

    def slower(score):
        late = drifts_absorbed(b, score)
        lost = score.get("slow_drifts_lost") or []
        wide = score.get("wide_thresholds") or []
        return ((f", drifts detected later (absorbed): {', '.join(late)}" if late else "")
                + (f", slow drifts lost: {', '.join(lost)}" if lost else "")
                + (f", thresholds of {100 * WIDE:g} % of their span or more: "
                   f"{', '.join(wide)}" if wide else ""))

    def line(label, score):
        return (f"  {label}: detected {cases(score)}; isolated {len(score['isolated'])} "
                f"cases; wrong isolations {score['wrong_isolations']}; validation false "
                f"alarms {score['validation_false_alarms']}" + slower(score))

    reason = (search.get("reason")
              or "a fault was missed at its test size, not masked by the parameter "
              "spread")
    lines = [f"realignment search ({reason}): the same campaign with each "
             "[fdi] realign_noise_scale",
             line(f"now {search['current_scale']:g}", b)]
    lines += [line(f"{t['scale']:g}", t["score"]) for t in search["tried"]]
    if search["taken"]:
        chosen = next(t["score"] for t in search["tried"] if t["scale"] == search["scale"])
        why = []
        if set(map(tuple, chosen["detected"])) > set(map(tuple, b["detected"])):
            why.append("detects more cases")
        if len(chosen["isolated"]) > len(b["isolated"]):
            why.append("isolates more cases")
        if len(chosen.get("wide_thresholds") or []) < len(b.get("wide_thresholds") or []):
            why.append("has fewer thresholds of a large part of their sensor's span")
        lines.append(f"  -> {search['scale']:g} taken: it "
                     + (" and ".join(why) or "is better")
                     + ", with nothing worse (the thresholds below are that design's; "
                     "--write writes the scale too)")
    else:
        lines.append("  -> none taken (none detects every case detected now and detects or "
                     "isolates more, or has fewer wide thresholds, with no more wrong "
                     "isolations, false alarms or wide thresholds and no drift absorbed)")
    return "\n".join(lines)


def _print_tune(rep):
    from fdigen.tune.pipeline import left_domain_text
    from fdigen.tune.run_notes import early_peak_text, growing_text

    from fdigen.console import NBSP, console, print_table, say

    def g(v, fmt=".3g"):
        return "-" if v is None else format(v, fmt)

    con = console()
    st = rep["threshold_statistics"]
    s = rep["settings"]
    say(con, f"{rep['model']}: thresholds from {st['runs']} healthy runs of "
             f"{s['duration']:g}{NBSP}s (alpha {s['false_alarm_rate']:g}/run, "
             f"{st['alpha_per_residual']:.2g}/residual, margin {st['margin']:g}; run "
             f"length: {s.get('duration_source', '--duration')})")
    for warning in s.get("warnings", ()):
        say(con, warning)
    rows = []
    vertices = any("vertex_max" in st["residuals"][n] for n in rep["residuals"])
    for name in rep["residuals"]:
        f = st["residuals"][name]
        gev = f.get("gev")
        rows.append((name, g(f["current"]), g(f["empirical_max"]))
                    + ((g(f.get("vertex_max")),) if vertices else ())
                    + (g(f["empirical_quantile"]), g((f.get("gumbel") or {}).get("quantile")),
                       "-" if not gev else f"{gev['quantile']:.3g} ({gev['xi']:+.2f})",
                       f["basis"], rep["threshold_text"][name],
                       g(f["ratio_to_current"], ".2f")))
    cols = ("residual", "current", "healthy max") + (("vertex max",) if vertices else ()) \
        + ("empirical q", "Gumbel q", "GEV q (xi)", "basis", "tuned", "x current")
    print_table(con, [(col, "left" if col in ("residual", "basis") else "right")
                      for col in cols], rows)
    if vertices:
        say(con, "vertex max: the largest RMS of the healthy runs at the vertices of the "
                 "parameter tolerance (no threshold is set below it)")
    fa = rep["false_alarm"]
    from fdigen.tune.settings import NO_FLAG

    unset = all(st["residuals"][n]["current"] is None or st["residuals"][n]["current"]
                >= NO_FLAG for n in rep["residuals"])
    say(con, f"false alarms per {fa['run_duration']:g}{NBSP}s run: target "
             f"{fa['target_per_run']:g}; fitted {g(fa['fitted'])} ({fa['basis']}); validation "
             f"{fa['validation_false_alarms']}/{fa['validation_runs']} (95{NBSP}% upper bound "
             f"{fa['validation_upper_95']:.2g}); "
             + ("the model had no thresholds before this tune" if unset else
                f"healthy runs exceeding the current thresholds: "
                f"{fa['healthy_runs_current_thresholds_exceeded']}/{st['runs']}"))
    from fdigen.tune.sensor_span import span_warning, wide_warning

    for text in (span_warning(rep.get("thresholds_beyond_span") or {}),
                 wide_warning(rep.get("thresholds_wide") or {})):
        if text:
            say(con, "warning: " + text)
    if rep.get("substeps"):
        raised = rep["substeps"]
        say(con, ("" if raised["used"] == raised["needed"] else "warning: ") + raised["text"])
    if rep.get("substeps_accuracy"):
        acc = rep["substeps_accuracy"]
        say(con, ("" if acc["converged"] else "warning: ") + acc["text"])
    if rep.get("startup"):
        su = rep["startup"]
        say(con, f"start-up: [fdi] startup = {su['seconds']:g} s (no flag before it; "
                 f"{', '.join(su['residuals'])} came down from the core's start by then, "
                 "the thresholds are fitted after it)")
    if fa.get("growing"):
        say(con, "warning: " + growing_text(fa["growing"], fa["run_duration"]))
    for name, e in fa.get("early_peaks", {}).items():
        say(con, "warning: " + early_peak_text(name, e))
    say(con, "Fault campaign with the tuned thresholds (delays in s: median [max])")
    rows = []
    for name, f in rep["faults"].items():
        dd, idl = f["detection_delay"], f["isolation_delay"]
        sizes = ", ".join(f"{b['size']:.3g}" + ("/s" if b.get("kind") == "ramp" else "")
                          for b in f["by_size"])
        rows.append((name, sizes, str(f["runs"]), str(f["detected"]), str(f["missed"]),
                     "-" if not dd["n"] else f"{dd['median']:.3f} [{dd['max']:.3f}]",
                     str(f["isolated_correct"]), str(f["false_isolations"]),
                     str(f["not_isolated"]),
                     "-" if not idl["n"] else f"{idl['median']:.3f} [{idl['max']:.3f}]",
                     str(f["false_alarms_before_onset"]),
                     ", ".join(f"{r} ({n})" for r, n in
                               f["off_signature_before_isolation"].items()) or "-"))
    print_table(con, [(col, "left" if col in ("fault", "off-signature before isolation")
                       else "right")
                      for col in ("fault", "sizes", "runs", "detected", "missed",
                                  "detection delay", "class ok", "class wrong", "no class",
                                  "isolation delay", "FA before",
                                  "off-signature before isolation")], rows)
    say(con, "class ok / class wrong / no class: runs in which the core's class decision "
             "named the fault's class / another class / no class (the flags never singled "
             "out one class, e.g. two classes share a signature); FA before: runs that "
             "raised a flag before their fault started")
    if fa.get("validation_false_alarms"):
        say(con, f"warning: {fa['validation_false_alarms']} of {fa['validation_runs']} fresh "
                 "healthy runs raised a flag with the tuned thresholds (target "
                 f"{100 * rep['settings']['false_alarm_rate']:g} % per run): they do not hold "
                 "yet; more healthy runs (--runs) give thresholds that do")
    if rep.get("left_domain"):
        say(con, "warning: " + left_domain_text(rep["left_domain"]))
    early = sum(f["false_alarms_before_onset"] for f in rep["faults"].values())
    runs = sum(f["runs"] for f in rep["faults"].values())
    if early:
        say(con, f"warning: {early} of {runs} fault runs raised a flag before their fault "
                 "started: false alarms of the tuned thresholds that the validation runs "
                 f"({fa['validation_false_alarms']}/{fa['validation_runs']}) did not show; "
                 "more healthy runs (--runs) and validation runs (--validation-runs) "
                 "give thresholds that hold")
    rows = [(name, b.get("kind", "step"),
             f"{b['size']:.3g}" + ("/s" if b.get("kind") == "ramp" else ""),
             f"{b['factor']:g}", str(b["runs"]), f"{100 * b['detected'] / b['runs']:.0f} %",
             f"{100 * b['isolated_correct'] / b['runs']:.0f} %", str(b["false_isolations"]))
            for name, f in rep["faults"].items() for b in f["by_size"]]
    if rows:
        say(con, "Detection and isolation per fault, kind and size (ramps in units per second)")
        print_table(con, [(col, "left" if col in ("fault", "kind") else "right")
                          for col in ("fault", "kind", "size", "x test", "runs", "detected",
                                      "class ok", "class wrong")], rows)
    for name, rate in (rep.get("poorly_isolated") or {}).items():
        short = (rep.get("unreached_separators") or {}).get(name) or {}
        say(con, f"warning: {name} is class-isolable but isolated in {100 * rate:.0f} % of "
                 "its runs at its test size (< 90 %)"
            + (": in those runs the residuals that separate it from the other classes "
               "gave " + ", ".join(f"{r} {v}" for r, v in short.items())
               + " (below its threshold: a larger test_size, or thresholds lowered by a "
               "narrower parameter spread, `fdigen commission`; late: a frozen model's "
               "drift could raise it too, so the class decision does not read it)"
               if short else ""))
    for entry in rep.get("parameter_masking") or ():
        say(con, "warning: missed at its test size: " + entry["text"])
    def narrowest(n, f):   # a set of several faults is no isolation (a user's quarter car)
        best = [g for g in f.get("fault_set_best") or () if g != n]
        return f" (to {n} or {' or '.join(best)})" if best else ""

    iso = {n: f"{f['fault_isolated']}/{f['runs']}{narrowest(n, f)}"
           for n, f in rep["faults"].items()}
    if iso:
        say(con, "consistent faults narrowed to the fault's signature (the set of faults "
                 "the flags allow is as narrow as the signature table allows, which may "
                 "hold other faults; not the class decision): "
                 + ", ".join(f"{n} {v}" for n, v in iso.items()))
    if rep.get("sensitivity"):
        say(con, "Fault sensitivity (campaign: smallest size detected / isolated in every "
                 "run, largest isolation delay at that size):")
        for entry in rep["sensitivity"].values():
            say(con, f"  {entry['text']}")
    wrong = rep.get("wrong_isolations_by_class") or {}
    if wrong:
        say(con, "warning: wrong isolations (class isolated while another "
                 "class's fault was injected): "
                 + ", ".join(f"{c} {n}" for c, n in wrong.items()))
    else:
        say(con, "wrong isolations: 0 in every class")
    hz = rep.get("frozen_horizon")
    if hz:
        never = [n for n, e in hz["earliest"].items() if e is None]
        say(con, f"validity horizons of frozen residuals ({hz['trials']} healthy freezes"
                 + (f", {hz['fault_runs']} fault runs" if "fault_runs" in hz else "")
                 + "; the campaign above used them): "
                 + (", ".join(f"{n} {v:g}{NBSP}s" for n, v in hz["horizons"].items())
                    or "none crossed")
                 + (f"; never crossed: {', '.join(never)}" if never else ""))
    if rep.get("short_horizons"):
        say(con, "warning: validity horizons shorter than one RMS window ("
                 + ", ".join(f"{n} {v:g}{NBSP}s" for n, v in rep["short_horizons"].items())
                 + "): once any flag freezes the parallel models, these residuals' flags "
                 "are no evidence for the class decision almost at once; a stronger "
                 "realignment ([fdi] realign_noise_scale) or a more accurate model keeps "
                 "them useful longer")
    for name in rep["residuals"]:
        f = st["residuals"][name]
        if f.get("warning") or f.get("note"):
            say(con, f"{name}: {f.get('note') or ''} {f.get('warning') or ''}".strip())
    t = rep["timing"]
    say(con, f"{rep['executor']}: {t['samples']} samples in {t['total']:.0f}{NBSP}s "
             f"({g(t['samples_per_second_per_core'], '.3g')} simulated samples/s per core)")

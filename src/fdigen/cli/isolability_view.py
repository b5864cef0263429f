"""`fdigen inspect`: the isolability it prints (achievable and achieved matrices, the pairs
no residual separates, the sensors that would, and those the running filters do not)."""

from __future__ import annotations


def print_settled(con, iso):
    """The faults Kalman residuals see only while their filters settle, and the pairs the
    table isolates only through those (:mod:`fdigen.design.settled_response`)."""
    from fdigen.console import say

    for res, entries in (iso.get("settled_responses") or {}).items():
        for fault, e in entries.items():
            if e["seen"]:
                continue
            limit = (f"its threshold {e['threshold']:.3g}" if e["threshold"] is not None
                     else f"3 times its noise ({3 * e['noise']:.3g})")
            say(con, f"warning: {res} sees a constant {fault} only while its filter "
                     f"settles (its filter of {', '.join(e['hidden'])} takes it for a "
                     "shifted estimate): at the test size its moving RMS rises by "
                     f"{e['rms_peak']:.3g} over a noise of {e['noise']:.3g}, below "
                     f"{limit}, and then returns to the noise: a step of that size never "
                     "flags it")
    pairs = iso.get("transient_only_pairs") or []
    if pairs:
        say(con, "isolable by the table, not by the running filters (the separating "
                 "residuals above do not flag the fault at its test size): "
                 + ", ".join(f"{a} from {b}" for a, b in pairs)
                 + "; a sensor on the filters' unmeasured states, or a residual that "
                 "does not estimate them, would separate them")


def print_isolability(con, iso):
    """Achievable and achieved isolability matrices, the pairs no residual can separate
    and the sensors that would."""
    from fdigen.console import print_table, say

    faults = iso["faults"]
    for key, title in (("achievable", "achievable (structure of the model, rank-checked)"),
                       ("achieved", "achieved (signature table)")):
        say(con, f"Isolability {title}: row isolable from column (diagonal: detectable)")
        print_table(con, [("fault", "left"), *((str(j + 1), "center")
                                               for j, _ in enumerate(faults))],
                    [[f"{i + 1} {f}", *[("x" if v else ".") for v in iso[key][i]]]
                     for i, f in enumerate(faults)])
    pairs = iso["achievable_non_isolable"]
    transient = iso.get("transient_only_pairs") or []
    say(con, f"ordered pairs not isolable: {len(iso['achieved_non_isolable'])} achieved, "
             f"{len(pairs)} achievable" + ("" if iso["achieved_non_isolable"] == pairs
                                           else " (different pairs: below)")
        + (f"; {len(transient)} more the table isolates and the running filters do not "
           "(below)" if transient else ""))
    for key, text in (("achievable_not_achieved", "achievable, not achieved by the residuals"),
                      ("achieved_not_achievable", "achieved, not achievable (a defect: the "
                                                  "table claims more than the structure)"),
                      ("isolable_only_when_the_sensor_dies",
                       "isolable only when the sensor dies (its validity flag nf_*: NaN or "
                       "out of range)")):
        if iso.get(key):
            say(con, f"{text}: " + ", ".join(f"{a} from {b}" for a, b in iso[key]))
    for g, why in (iso.get("not_achieved_reasons") or {}).items():
        say(con, f"  {why}")
    print_settled(con, iso)
    hidden = [x for x in iso.get("states", ()) if x not in set(iso.get("measured_states", ()))]
    if iso.get("achievable_not_achieved") and hidden:
        # a user's ball screw: all pairs achievable, none achieved, and no word of why
        say(con, "  fdigen's residuals (sub-models driven by directly measured states, "
                 "combinations cancelling a fault in two balances, static relations, the "
                 "whole model on one sensor) do not realise these tests: they run through "
                 f"the unmeasured {', '.join(hidden)}, which these constructions "
                 "eliminate only through a directly measured state (a sensor that reads a "
                 "combination, as an accelerometer reads a force balance, drives no "
                 "sub-model); a sensor on one of them, or a declared [fdi.parity] or "
                 "[fdi.kalman] residual on the relation you know (a momentum balance "
                 "read by the accelerometer), gives fdigen a residual to build")
    if pairs:
        say(con, "no residual of any kind separates: "
                 + ", ".join(f"{a} from {b}" for a, b in pairs))
        same = {frozenset(e["pair"]) for e in iso.get("not_isolable_by_direction", ())
                if e["same_direction"]}
        by_direction = {tuple(e["pair"]) for e in iso.get("not_isolable_by_direction", ())}
        if by_direction:
            say(con, "  of which the structure allows a test but the equations do not: "
                     + ", ".join(f"{a} from {b}" for a, b in sorted(by_direction))
                     + " (the linearised model's rank test refuses them at the operating "
                       "point and around it)")
        for entry in iso["sensor_placement"]:
            a, b = entry["pair"]
            if frozenset((a, b)) in same and not entry["sensors"]:
                say(con, f"  {a} from {b}: no sensor separates them: both act on the plant "
                         "in the same direction at every point (their effects on every state "
                         "and output differ only by a gain: they enter through the same "
                         "combination of the equations)")
                continue
            measured = set(iso.get("measured_states", ()))
            defined = set(iso.get("definition_sensors", ()))
            sensors = ", ".join(f"{v[:-4]} as the actuator delivers it ({v})"
                                if v.endswith("_eff") else
                                f"{v} (a second one: it is measured)" if v in measured
                                else f"{v} (the model's definition: what a sensor of that "
                                     "quantity reads)" if v in defined
                                else v for v in entry["sensors"])
            say(con, f"  {a} from {b}: " + (f"a sensor on {sensors}" if sensors
                                             else "no single extra sensor separates them"))
    for entry in iso.get("refused_candidates", ()):
        say(con, f"candidate refused: {entry['candidate']}: {entry['reason']}")

"""What commission does not commit of what discover found.

Three cases write the calibrated model without effects instead of the augmented one:

* a **tie**: the log does not decide between the chosen effect and another (a user's
  heater: a -3.66 degC offset of a healthy thermocouple, tied with the heat loss the rig
  really had); committing one would write a guess into the plant's model;
* a **declared plant fault**: the chosen effect is, term for term, one of the model's
  own plant faults (:mod:`fdigen.discover.declared_faults`; a user's two tanks:
  ``leak_sqrt_h1``, the shape of ``leak1``); a commissioned model with it would read that
  fault as normal. The verdict then refuses the design (the log is of a faulty rig, or
  shows what the library lacks);
* a tie of the output-error loop between a sensor's effect and a plant's (a user's drive
  train, on a log whose speed never reversed: ``sensor_offset_i_meas = 0.24 V`` chosen
  over the constant load torque and dry friction the rig had, dBIC -15.2 against -14.4,
  and written into the current sensor's map); ties of one kind (a load torque on either
  inertia of a stiff shaft) are committed, as the loop chose;
* effects that make the free-run output error larger (:func:`unconfirmed_effects`), in
  units of the sensors' noise, on the log or on a validation log: the equation errors
  they reduce are not the outputs' error. A user's pump rig (round 33):
  ``sensor_offset_n_enc = -859 rpm`` at its bound beside ``external_load``, with the
  current's free-run error 0.45 -> 2.06 V, were committed, and the campaign then spread
  the pump head +-90 %.

And one case keeps a calibrated parameter's datasheet value (:func:`bound_decided`): a
model parameter whose estimate ended at its search bound, where the bound, not the log,
decided it (a user's battery on a 4-minute log: capacity 1e5 C at its lower bound against
1.73e5 on the datasheet and 1.8e5 in truth, committed and spread +-14 %; the campaign then
simulated a 28 Ah module and every fault went undetected). The output-error loop keeps
such values itself and fits the others again with them held
(:mod:`fdigen.discover.held_values`); this covers the equation-error path.
"""

from __future__ import annotations

from fdigen.discover.declared_faults import withheld
from fdigen.discover.fit_report import unconfirmed_effects


def not_committed(info: dict, equation_path: bool, model=None) -> tuple[list, list, list]:
    """``(withheld for the log, declared plant faults, warnings)`` of discover's result
    ``info`` (of ``model``): the first are the ties and the unconfirmed effects."""
    effects = list(info["effects"])
    if equation_path:
        # (a tie one free run of the validation part decided is not one: committed)
        tied = [t for t in info.get("ties") or () if t.get("chosen") in effects
                and "tied_with" in t and not t.get("decided_by_free_run")]
    else:
        tied = []
        for t in info.get("ties") or ():
            if t.get("chosen") in effects and t.get("acts_on") and t.get("other_acts_on") \
                    and t["acts_on"] != t["other_acts_on"]:
                mine = next((x for x in tied if x["chosen"] == t["chosen"]), None)
                if mine is None:
                    mine = {"chosen": t["chosen"], "delta_bic": t["chosen_delta_bic"],
                            "tied_with": {}}
                    tied.append(mine)
                mine["tied_with"][t["other"]] = t["delta_bic"]
    faulty = withheld(info.get("declared_faults") or [])
    notes = []
    why = unconfirmed_effects(info, model)
    if tied:
        notes.append(
            "not committed: " + "; ".join(
                f"{t['chosen']} (dBIC {t['delta_bic']:.1f}) ties with "
                + ", ".join(f"{o} ({d:.1f})" for o, d in t["tied_with"].items())
                for t in tied)
            + ": the log does not decide between them, so the commissioned model is the "
            "calibrated one without effects (its thresholds carry the error the effect "
            "would explain); a log that separates them (discover's warnings name the "
            "excitation) lets commission commit the right one")
    if faulty:
        notes.append(
            "not committed: " + "; ".join(
                f"{f['effect']} is the declared fault {f['fault']} (size {f['size']:.4g})"
                for f in faulty)
            + ": a commissioned model with it would read that fault as normal; the "
            "commissioned model is the calibrated one without effects. Check the rig for "
            "it, or find what the library lacks (discover's warnings)")
    if why and not tied and not faulty:
        notes.append(f"not committed: {', '.join(effects)}: " + "; ".join(why)
                     + ": the commissioned model is the calibrated one without effects "
                     "(its thresholds carry the error the effects would explain)")
        tied = [{"chosen": e, "unconfirmed": why} for e in effects]
    return tied, faulty, notes


def bound_decided(info: dict, model) -> dict:
    """The uncertain model parameters of ``model`` whose estimate in discover's result
    ``info`` sits on its search bound (``on_bound`` of its ``at_bounds``): name ->
    ``(estimate, datasheet value)``. Commission commits the datasheet value for them and
    spreads them by the declared tolerance (they have no interval of the log's)."""
    own = {q.name: float(q.value) for q in model.parameters if q.uncertain}
    return {b["parameter"]: (float(b["value"]), own[b["parameter"]])
            for b in info.get("at_bounds") or ()
            if b.get("on_bound") and b["parameter"] in own
            and own[b["parameter"]] != float(b["value"])}

"""Faults the default ambiguity policy may act on more severely than their class asks.

With ``[fdi] ambiguity = "most_severe"`` the core takes the most severe action among the
classes consistent with the flags once the ambiguity has lasted ``ambiguity_time``
(default: ``confirm`` samples). A fault ``f`` whose class-level signature ``S_f`` shares
a flag with the signature ``S_g`` of a fault ``g`` of another class whose action is more
severe,

.. math:: S_f \\cap S_g \\ne \\emptyset,\\qquad a(g) > a(f),

leaves ``g`` consistent while only the shared flags are up: if the flags that exclude
``g`` take longer than the ambiguity time, the action of ``g`` is taken (a level-sensor
offset declared ``none`` stops the plant because its first flag is also a leak's).
"""

from __future__ import annotations

from fdigen.design.evaluation import class_level_masks


def severe_under_ambiguity(design) -> dict:
    """Fault -> (its class's action, the more severe action it may get, the faults of
    other classes that share a class-level flag with it), for every exposed fault; empty
    under ``ambiguity = "wait"``."""
    cfg, ev = design.config, design.evaluation
    if cfg.ambiguity != "most_severe":
        return {}
    level = class_level_masks(ev, design.model.outputs)
    cls = {f.name: f.fault_class for f in design.model.faults}
    code = dict(zip(ev.classes, ev.action_codes))
    act = dict(zip(ev.classes, ev.actions))
    out = {}
    for f in ev.fault_names:
        worse = [g for g in ev.fault_names if cls[g] != cls[f] and level[f] & level[g]
                 and code[cls[g]] > code[cls[f]]]
        if worse:
            top = max(code[cls[g]] for g in worse)
            out[f] = (act[cls[f]], next(act[cls[g]] for g in worse if code[cls[g]] == top),
                      tuple(worse))
    return out


def hold_warnings(design) -> tuple:
    """A warning when ``[fdi] hold_windows`` is set on a design whose parallel models are
    not re-aligned (``realign_noise_scale = 0``, the default): there is no correction to
    hold, the key does nothing."""
    cfg = design.config
    if cfg.hold_windows and not cfg.realign_noise_scale:
        return (f"[fdi] hold_windows = {cfg.hold_windows} does nothing: the parallel models "
                "are not re-aligned (realign_noise_scale = 0, the default), so there is no "
                "correction to hold; set realign_noise_scale (e.g. 0.05) to re-align them",)
    return ()


def accommodations_in_doubt(design) -> list:
    """Pairs of classes that both call for ``accommodate`` and share a class-level flag:
    while only shared flags are up, both are consistent, every policy takes
    ``accommodate`` (the same action code) and the core names no class, so the controller
    is told to accommodate without being told which sensor (a user's quadrotor: a
    barometer drift got the range finder's ``accommodate``; a receiver's leak that of its
    healthy transmitter)."""
    ev = design.evaluation
    level = class_level_masks(ev, design.model.outputs)
    cls = {f.name: f.fault_class for f in design.model.faults}
    act = dict(zip(ev.classes, ev.actions))
    pairs = []
    for k, f in enumerate(ev.fault_names):
        for g in ev.fault_names[k + 1:]:
            a, b = cls[f], cls[g]
            if a != b and act[a] == act[b] == "accommodate" and level[f] & level[g]:
                pair = tuple(sorted((a, b)))
                if pair not in pairs:
                    pairs.append(pair)
    return pairs


def ambiguity_warnings(design) -> tuple:
    """A warning when the default policy may act on a fault more severely than its class,
    with the ambiguity time left at its default; one when two classes to accommodate
    share their first flags; or nothing."""
    cfg = design.config
    doubt = accommodations_in_doubt(design)
    out = (("accommodate without a class: " + "; ".join(f"{a} and {b}" for a, b in doubt)
            + " both call for accommodate and share their first flags, so until the flags "
            "tell them apart the core reports action accommodate with fault class 0 (none "
            "isolated): a controller that acts on it must not guess which sensor to stop "
            "using (read the consistent faults, or treat it as a loss of both); a residual "
            "that separates them (`fdigen inspect` names the sensor) removes the doubt",)
           if doubt else ())
    exposed = severe_under_ambiguity(design)
    if not exposed or cfg.ambiguity_time is not None:
        return out
    wait = cfg.confirm * cfg.sample_time
    listed = "; ".join(f"{f} ({own} -> {severe}, its first flags also fit "
                       f"{', '.join(others)})" for f, (own, severe, others) in exposed.items())
    return out + (f"ambiguity = \"most_severe\" takes the most severe action of the "
                  f"consistent classes after {wait:g} s (confirm): {listed}. A fault whose "
                  "isolation takes longer gets that action; set [fdi] ambiguity_time above "
                  "the isolation delays `fdigen tune` measures, or ambiguity = \"wait\" "
                  "(acts only when every consistent class calls for the same action)",)

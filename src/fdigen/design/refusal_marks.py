"""The ``[fdi] refused`` marks: who wrote one, and what every command says first.

``fdigen commission`` refuses a useless design, ``fdigen tune --write`` thresholds that
failed their checks (:data:`TUNE_REFUSAL`), ``fdigen discover`` thresholds it read from its
log without designing them (:data:`DISCOVER_REFUSAL`). ``detect``, ``build`` and
``inspect`` say :func:`refused_text` before anything else.
"""

from __future__ import annotations


#: How the ``[fdi] refused`` text ``fdigen tune --write`` writes begins: tune removes a
#: mark only when it begins so (a commission's refusal is the engineer's to lift).
TUNE_REFUSAL = "fdigen tune:"

#: How the mark ``fdigen discover`` writes begins when it filled thresholds from its log
#: (not designed: no false-alarm campaign, no fault campaign); a passing ``fdigen tune
#: --write`` lifts it too.
DISCOVER_REFUSAL = "fdigen discover:"


#: The mark ``fdigen commission`` writes with the commissioned file's first version and
#: replaces by its verdict at the end: a run stopped on the way (Ctrl-C during the fault
#: campaign) left a file with its final thresholds that ``detect`` ran in silence.
COMMISSION_UNFINISHED = ("fdigen commission: unfinished (stopped before its fault campaign "
                         "and verdict; run it again)")


def refused_text(reason: str) -> str:
    """What ``detect``, ``build`` and ``inspect`` say first about a design ``fdigen
    commission`` or ``fdigen tune --write`` refused (``[fdi] refused``)."""
    why = reason.strip().rstrip(".") or "(no reason given)"
    if why.startswith(DISCOVER_REFUSAL):
        # a user's hydraulic axis ran `detect` on discover's file: R5 at 121 mm of a
        # 160 mm range, blind to a 40 % valve loss, and nothing said the thresholds were
        # the log's
        return ("this design's thresholds were NOT designed ([fdi] refused in the model "
                f"file, by `fdigen discover`): {why[len(DISCOVER_REFUSAL):].strip()}. Its "
                "flags are not to be trusted (a passing `fdigen tune --write` removes the "
                "mark; deleting the key accepts the design as it stands)")
    if why.startswith(TUNE_REFUSAL):
        body = why[len(TUNE_REFUSAL):].strip()
        # the advice fits the failure: more runs fix false alarms, not a blind design (a
        # user's drone refused for a rotor fault never detected was told to add runs)
        fixes = []
        if "raised a flag" in body or "healthy" in body:
            fixes.append("false alarms: tune again with more healthy runs (--runs) until "
                         "the validation holds")
        if "detected in" in body or "never detected" in body:
            fixes.append("a fault the thresholds do not see at its test size: a sensor "
                         "that reads it (`fdigen inspect`), a narrower parameter spread "
                         "(calibration: `fdigen commission`), or the size that matters "
                         "as its test_size")
        if "sensor's span" in body:
            fixes.append("thresholds as wide as their sensor: calibrate the uncertain "
                         "parameters (`fdigen commission`) or re-align the parallel models "
                         "([fdi] realign_noise_scale)")
        if "another class" in body:
            fixes.append("wrong isolations: a longer confirmation ([fdi] confirm), the "
                         "residual that separates the classes (`fdigen inspect`), or, where "
                         "a derived filter reads a measured state through a nonlinearity "
                         "and the plant leaves its range, [fdi] nonlinear_drivers = true")
        advice = "; ".join(fixes) or "fix what it names and tune again"
        return ("this design was REFUSED by `fdigen tune` ([fdi] refused in the model "
                f"file): {body}. Its flags are not to be trusted; {advice} (a passing "
                "`fdigen tune --write` removes the mark; deleting the key accepts the "
                "design as it stands)")
    return ("this design was REFUSED by `fdigen commission` ([fdi] refused in the model "
            f"file): {why}. Its flags and diagnoses are not to be trusted; fix what the "
            "refusal names and commission again (deleting the key accepts the design as it "
            "stands)")

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
        return ("this design was REFUSED by `fdigen tune` ([fdi] refused in the model "
                f"file): {why[len(TUNE_REFUSAL):].strip()}. Its flags are not to be "
                "trusted; tune again with more healthy runs (--runs) until the validation "
                "holds (a passing `fdigen tune --write` removes the mark; deleting the key "
                "accepts the design as it stands)")
    return ("this design was REFUSED by `fdigen commission` ([fdi] refused in the model "
            f"file): {why}. Its flags and diagnoses are not to be trusted; fix what the "
            "refusal names and commission again (deleting the key accepts the design as it "
            "stands)")

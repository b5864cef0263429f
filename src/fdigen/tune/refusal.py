"""The refusal ``fdigen tune --write`` writes with thresholds that fail their own checks.

Before, ``tune --write`` wrote thresholds that raised flags on its own fresh healthy runs
with a "FAILED validation" comment in the table's header and nothing else: ``detect`` and
``build`` then used them in silence (a user's furnace, 2 of 3 validation runs flagged).
Now the same failures that make ``fdigen commission`` refuse a design make ``tune --write``
write ``[fdi] refused`` (:data:`~fdigen.design.config.TUNE_REFUSAL` first), which
``detect``, ``build`` and ``inspect`` say before anything else:

* a validation run (a fresh healthy run, never used to set the thresholds) raised a flag;
* a fault run raised a flag before its fault started (a false alarm the validation did
  not show);
* a threshold of a residual comparing one sensor is at least the span that sensor covers
  over the declared ranges (no fault that keeps the reading in range crosses it);
* a declared fault is detected in none of its runs at its test size (the design cannot see
  what it was asked to: a user's conveyor, its shunt offset "never detected", was written
  unrefused while ``fdigen commission`` refuses the same campaign);
* a fault run was isolated as another class (the design would act on the wrong fault).

These are the failures :func:`fdigen.commission.verdict.design_verdict` refuses by, read
from tune's own campaign.

A later ``tune --write`` whose thresholds pass removes a mark that tune wrote, or that
``fdigen discover`` wrote over thresholds it read from its log; a mark ``fdigen
commission`` wrote stays (its reasons are not all tune's to judge).
"""

from __future__ import annotations

#: ``refusal_value``'s answer when the file's ``refused`` key is to be left as it is.
KEEP = object()


def tune_failures(rep: dict) -> list[str]:
    """The reasons a tune report's thresholds are not to be used, one sentence each."""
    fa = rep.get("false_alarm") or {}
    out = []
    if fa.get("validation_false_alarms"):
        out.append(f"{fa['validation_false_alarms']} of {fa['validation_runs']} fresh "
                   "healthy validation runs raised a flag with the tuned thresholds")
    faults = rep.get("faults") or {}
    early = sum(int(f.get("false_alarms_before_onset", 0)) for f in faults.values())
    if early:
        runs = sum(int(f.get("runs", 0)) for f in faults.values())
        out.append(f"{early} of {runs} fault runs raised a flag before their fault started")
    beyond = rep.get("thresholds_beyond_span") or {}
    if beyond:
        out.append("thresholds at least their sensor's span: " + ", ".join(
            f"{r} = {e['threshold']:.3g} against {e['output']}'s {e['span']:.3g}"
            for r, e in sorted(beyond.items())))
    blind = [(name, sum(int(b["runs"]) for b in at)) for name, f in sorted(faults.items())
             for at in [[b for b in f.get("by_size", ())
                         if abs(float(b["factor"]) - 1.0) < 1e-9]]
             if at and not sum(int(b["detected"]) for b in at)]
    if blind:
        out.append("faults detected in none of their runs at their test size: " + ", ".join(
            f"{name} (0 of {runs})" for name, runs in blind))
    wrong = [(name, int(f["false_isolations"]), int(f.get("runs", 0)))
             for name, f in sorted(faults.items()) if int(f.get("false_isolations") or 0)]
    if wrong:
        out.append("fault runs isolated as another class: " + ", ".join(
            f"{name} in {k} of {n}" for name, k, n in wrong))
    return out


def refusal_value(rep: dict, current: str):
    """The ``[fdi] refused`` value ``tune --write`` writes for report ``rep`` over the
    file's ``current`` value: the text of the failures, None (remove tune's own old mark)
    or :data:`KEEP`."""
    from fdigen.design.config import DISCOVER_REFUSAL, TUNE_REFUSAL

    failures = tune_failures(rep)
    if failures:
        text = f"{TUNE_REFUSAL} " + "; ".join(failures) + "."
        return "".join(c if c.isprintable() else " " for c in text)[:4000]
    if current.strip().startswith((TUNE_REFUSAL, DISCOVER_REFUSAL)):
        return None                  # (discover's: thresholds from its log, now designed)
    return KEEP

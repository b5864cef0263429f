"""The held correction, tried when frozen parallel models cost a campaign its isolation.

At the first flag every parallel model's realignment stops, and the model drifts at the
rate of its parameter error: the validity horizons (``docs/isolation.md``, section 5)
bound how long a frozen residual's flag is evidence. Where they are short, a fault whose
second residual rises later than that is never isolated: a user's CSTR (Arrhenius
kinetics, 60 s RMS window at 1 s) had horizons of 38-55 s, shorter than one window, and
its jacket fouling ended "detected, not isolated" because every parity flag after the
first one counted as late. ``[fdi] hold_windows`` keeps the correction that balanced the
parameter error held once frozen (section 13); it is off by default because its length is
a per-plant trade, so the campaign decides:

* :func:`hold_to_try`: the model has no held correction, the campaign measured validity
  horizons and some residual crossed its threshold once frozen, and some class-isolable
  fault is isolated in fewer than 90 % of its runs at its test size;
* the same campaign (same seed, runs, sizes and horizon runs) on the model with
  ``hold_windows = 1`` (the average over one RMS window: the length that held on the
  cylinder, whose operating point moves within seconds, and on the tanks);
* taken only by :func:`~fdigen.tune.filter_search.isolates_more`: every case detected as
  before, more runs isolated, no more wrong isolations, no more validation false alarms.

Measured on that CSTR (8 healthy runs, 4 validation runs, 2 horizon runs, seed 0, sizes
0.25-2x, 2 onsets): horizons RT 60, RTj 64.8, RCa 80, R3 47.2 s without, none crossed
with it; class isolated in 25 of 48 fault runs (18 without), 0 wrong either way, and no
flag outside the fault's signature before its isolation (11 runs had one without).
"""

from __future__ import annotations

from fdigen.tune.filter_search import isolates_more, isolation_score
from fdigen.tune.realign_search import campaign_with

#: The held correction's length tried, in RMS windows.
HOLD_WINDOWS = 1


def hold_to_try(report: dict, model) -> bool:
    """Whether the campaign ``report`` of ``model`` calls for the search (see the module)."""
    if float(model.fdi.get("hold_windows", 0) or 0) > 0 or not report.get("faults"):
        return False
    horizons = (report.get("frozen_horizon") or {}).get("horizons") or {}
    return bool(horizons) and bool(report.get("poorly_isolated"))


def search_held_correction(path, report: dict, model, run, say=lambda msg: None,
                           fdi_values: dict | None = None) -> dict | None:
    """Run the campaign again with ``[fdi] hold_windows`` when :func:`hold_to_try` says
    so; ``run(model_path)`` runs the same campaign on another model file; ``fdi_values``
    are ``[fdi]`` values already chosen, kept.

    Returns
    -------
    dict or None
        ``{"windows", "before", "after", "taken", "report"}``; None when nothing was
        tried.
    """
    if not hold_to_try(report, model):
        return None
    short = ", ".join(f"{n} {h:g} s" for n, h in report["frozen_horizon"]["horizons"].items())
    say(f"held correction search: the same campaign with [fdi] hold_windows = "
        f"{HOLD_WINDOWS} (frozen residuals cross their thresholds after {short}, and "
        "class-isolable faults are isolated in fewer than 90 % of their runs)")
    alt = campaign_with(path, {**(fdi_values or {}), "hold_windows": HOLD_WINDOWS}, run,
                        "fdigen-hold-")
    before, after = isolation_score(report), isolation_score(alt)
    return {"windows": HOLD_WINDOWS, "before": before, "after": after,
            "horizons_after": dict((alt.get("frozen_horizon") or {}).get("horizons") or {}),
            "taken": isolates_more(before, after), "report": alt}


def hold_text(search: dict) -> str:
    """One paragraph on the held correction search."""
    def line(s):
        return (f"isolated in {s['isolated_runs']} runs at the test size, wrong isolations "
                f"{s['wrong_isolations']}, validation false alarms "
                f"{s['validation_false_alarms']}")

    after = ", ".join(f"{n} {h:g} s" for n, h in search["horizons_after"].items())
    return (f"held correction search: with hold_windows = {search['windows']} "
            f"{line(search['after'])}, horizons {after or 'none crossed'} (without: "
            f"{line(search['before'])})"
            + ": " + (f"taken ([fdi] hold_windows = {search['windows']}; --write writes it)"
                      if search["taken"] else "not taken (not better on every count)"))

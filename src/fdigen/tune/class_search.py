"""Structural residuals in the class decision, tried when a campaign leaves class-isolable
faults unisolated.

The residuals that bring the signature table to the model's structural isolability
(``isolate_structurally``) name faults but do not decide classes by default
(``docs/isolation.md``, section 4): on the cylinder two of them, parallel models that
integrate a chamber flow twice, drifted past their thresholds once frozen and a
validation campaign isolated a pressure-sensor drift as the pneumatic class. Since then a
frozen residual's flag is only evidence within its validity horizon (section 5), and on
other plants the structural residual is the one that separates a class: the three tanks'
R6, the T1 + T2 volume blind to the clogging between them, is what tells a level-2
offset from the clogging. Which holds on a given plant is measured, so the campaign
decides:

* :func:`structural_to_try`: when the design has fault-level residuals, they do not
  decide classes yet, and some fault that would be class-isolable with them is isolated
  in fewer than 90 % of its runs at its test size;
* the same campaign (same seed, runs and sizes) on the model with ``[fdi]
  structural_classes = true``;
* taken only by :func:`~fdigen.tune.filter_search.isolates_more`: every case detected as
  before, more runs isolated, no more wrong isolations, no more validation false alarms.

Measured on the three tanks (10 healthy runs, 10 validation runs, seed 3, 2 onsets at
0.5, 1 and 2 times the test size): level sensor 2's steps isolated in 6 of 6 runs (1
without), its drifts 3 of 6 (1), the leak 2 of 6 (0), the pump 1 of 6 (0), level sensor
1's drift 1 of 6 (0); no wrong isolation and no validation false alarm either way.
"""

from __future__ import annotations

from fdigen.tune.filter_search import isolates_more, isolation_score
from fdigen.tune.realign_search import campaign_with


def structural_to_try(report: dict, model) -> bool:
    """Whether the campaign ``report`` of ``model`` calls for the search (see the module)."""
    import dataclasses

    from fdigen.design.cache import cached_design
    from fdigen.tune.fault_summary import poorly_isolated
    from fdigen.tune.model_update import fill_missing_thresholds
    from fdigen.tune.pipeline import class_isolable_faults
    from fdigen.tune.settings import NO_FLAG

    if model.fdi.get("structural_classes") or not report.get("faults"):
        return False
    # the file's thresholds may be missing (tune designs them): the table needs none
    filled = fill_missing_thresholds(model, NO_FLAG)[0]
    ev = cached_design(filled).evaluation
    validity = {f"nf_{o.name}" for o in model.outputs}
    if all(ev.class_flags >> i & 1 for i, n in enumerate(ev.residuals) if n not in validity):
        return False
    # the faults the class decision could isolate with them (the heat exchanger's
    # thermometers and hot-loop losses are not class-isolable without), isolated in
    # fewer than 90 % of their runs
    alt = cached_design(dataclasses.replace(filled, fdi={**filled.fdi,
                                                         "structural_classes": True}))
    return bool(poorly_isolated(report["faults"], class_isolable_faults(alt)))


def search_structural_classes(path, report: dict, model, run, say=lambda msg: None,
                              fdi_values: dict | None = None) -> dict | None:
    """Run the campaign again with the structural residuals deciding classes when
    :func:`structural_to_try` says so; ``run(model_path)`` runs the same campaign on
    another model file; ``fdi_values`` are ``[fdi]`` values already chosen, kept.

    Returns
    -------
    dict or None
        ``{"before", "after", "taken", "report"}``; None when nothing was tried.
    """
    if not structural_to_try(report, model):
        return None
    say("class decision search: the same campaign with [fdi] structural_classes = true "
        "(class-isolable faults isolated in fewer than 90 % of their runs)")
    alt = campaign_with(path, {**(fdi_values or {}), "structural_classes": True}, run,
                        "fdigen-classes-")
    before, after = isolation_score(report), isolation_score(alt)
    return {"before": before, "after": after, "taken": isolates_more(before, after),
            "report": alt}


def class_text(search: dict) -> str:
    """One paragraph on the class decision search."""
    def line(s):
        return (f"isolated in {s['isolated_runs']} runs at the test size, wrong isolations "
                f"{s['wrong_isolations']}, validation false alarms "
                f"{s['validation_false_alarms']}")

    return ("class decision search: with the structural residuals deciding classes "
            f"{line(search['after'])} (without: {line(search['before'])}): "
            + ("taken ([fdi] structural_classes = true; --write writes it)"
               if search["taken"] else "not taken (not better on every count)"))

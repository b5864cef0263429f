"""commission's class decision: the structural residuals decide classes when the
campaign says so, as ``fdigen tune``'s class decision search does
(:mod:`fdigen.tune.class_search`): the validation and fault campaign runs again on the
commissioned model with ``[fdi] structural_classes = true`` when a fault that would be
class-isolable with it is isolated in fewer than 90 % of its runs (the trigger,
:func:`~fdigen.tune.class_search.structural_to_try`), and the commissioned file takes it
only when
every case is still detected, more runs are isolated, and there are no more wrong
isolations and no more validation false alarms."""

from __future__ import annotations

import dataclasses


def campaign_report(camp: dict) -> dict:
    """commission's campaign summary in the form the searches score (a tune report's
    ``faults``, ``false_alarm``, ``wrong_isolations_by_class``)."""
    wrong = {}
    for f in camp["faults"].values():
        if f.get("false_isolations"):
            wrong[f["class"]] = wrong.get(f["class"], 0) + int(f["false_isolations"])
    return {"faults": camp["faults"],
            "false_alarm": {"validation_false_alarms": camp["validation_false_alarms"]},
            "wrong_isolations_by_class": wrong}


def choose_class_decision(path, model, camp: dict, run, say=lambda msg: None):
    """``(model, campaign, note)``: the commissioned model (its file ``path`` rewritten
    with the key when taken), the campaign that goes with it, and one sentence, or
    ``None`` when nothing was tried; ``run(model)`` runs the validation and fault
    campaign on a model."""
    from fdigen.files.model_write import write_model_text
    from fdigen.model.model_file import load_model
    from fdigen.tune.class_search import structural_to_try
    from fdigen.tune.filter_search import isolates_more, isolation_score
    from fdigen.tune.model_update import updated_model_text

    before = campaign_report(camp)
    if not structural_to_try(before, model):
        return model, camp, None
    say("  class decision: the same campaign with the structural residuals deciding "
        "classes ([fdi] structural_classes = true)")
    alt_model = dataclasses.replace(model, fdi={**model.fdi, "structural_classes": True})
    alt = run(alt_model)
    after = campaign_report(alt)
    s0, s1 = isolation_score(before), isolation_score(after)
    taken = isolates_more(s0, s1)
    note = (f"class decision: with the structural residuals deciding classes, isolated in "
            f"{s1['isolated_runs']} runs at the test size (without: {s0['isolated_runs']}), "
            f"wrong isolations {s1['wrong_isolations']} ({s0['wrong_isolations']}): "
            + ("taken ([fdi] structural_classes = true in the commissioned model)" if taken
               else "not taken (not better on every count)"))
    if not taken:
        return model, camp, note
    write_model_text(path, updated_model_text(path.read_text(encoding="utf-8"), {},
                                              fdi_values={"structural_classes": True}))
    return load_model(path), alt, note

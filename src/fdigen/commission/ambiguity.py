"""The ambiguity time of a commissioned design, from its own fault campaign.

``commission`` measures it as ``fdigen tune`` does (:mod:`fdigen.tune.ambiguity_time`):
1.5 x the longest time from detection to isolation of a fault the default ambiguity
policy could act on more severely than its class, written into the commissioned file's
``[fdi] ambiguity_time``.
"""

from __future__ import annotations


def measured_ambiguity_time(path, model, camp: dict):
    """``(model, note)``: the commissioned file ``path`` with the ambiguity time its
    campaign measures (:mod:`fdigen.tune.ambiguity_time`, as ``tune`` proposes it), and
    the sentence saying so; ``(model, None)`` when nothing is to be said."""
    from fdigen.files.model_write import write_model_text
    from fdigen.model.model_file import load_model
    from fdigen.tune.ambiguity_time import ambiguity_text, measured_ambiguity_time as measure
    from fdigen.tune.model_update import updated_model_text

    found = measure(camp, model)
    if found is None or (found["seconds"] is None and not found["never_isolated"]
                         and not found["held_back"]):
        return model, None
    if found["seconds"] is not None:
        write_model_text(path, updated_model_text(path.read_text(encoding="utf-8"), {},
                                                  fdi_values={"ambiguity_time":
                                                              found["seconds"]}))
        model = load_model(path)
    return model, ambiguity_text(found, "written into the commissioned file")

"""A derived design set to a model that differs only in what its evaluation reads.

``tune`` and ``commission`` derive the same model several times with other threshold
values, measured validity horizons, or the structural residuals deciding classes: one
``commission`` of the cylinder derived it seven times (124 s of its 285 s under the
profiler). Those ``[fdi]`` entries enter only the evaluation (the comparison
``|rms| > threshold``, each residual's late mask, which residuals decide classes), never
the step program, the residuals or the signature table:

* ``thresholds``: the values (the residuals named must be the same: a missing or stray
  threshold is a refusal of the derivation);
* ``frozen_horizon``: the values (the same residuals named);
* ``structural_classes``.

:func:`retargeted` rebuilds the evaluation of a derived design for such a model exactly as
the derivation would (``tests/test_design_reuse.py`` compares the two, C bytes included),
and :func:`evaluation_key` is what two such models share.
"""

from __future__ import annotations

import dataclasses


def evaluation_key(model) -> str:
    """The hash of ``model`` with the values of the evaluation-only entries left out (the
    residuals they name kept): equal for two models one :func:`retargeted` serves."""
    from fdigen.model.model_file import model_hash

    fdi = dict(model.fdi)
    for table in ("thresholds", "frozen_horizon"):
        if table in fdi:
            fdi[table] = sorted(dict(fdi[table]))
    fdi.pop("structural_classes", None)
    fdi.pop("refused", None)            # commission's verdict, printed, never derived
    return model_hash(dataclasses.replace(model, fdi=fdi))


def retargeted(design, model):
    """``design`` (derived from a model with the same :func:`evaluation_key`) for
    ``model``: its configuration read from ``model`` and its evaluation rebuilt, as
    :func:`~fdigen.design.fdi_design.fdi_design` builds them."""
    from fdigen.design.config import read_fdi_config
    from fdigen.design.evaluation import build_evaluation
    from fdigen.design.fdi_design import class_deciding

    cfg = read_fdi_config(model)
    names = design.residual_names
    faults = [f.name for f in model.faults]
    table = design.signature_table
    validity = tuple(f"nf_{o.name}" for o in model.outputs)
    fault_level = () if cfg.structural_classes else class_deciding(
        table, faults, validity, names, tuple(
            e["residual"] for e in design.extra_residuals
            if e["purpose"].endswith("structural isolability")))
    return dataclasses.replace(design, model=model, config=cfg, evaluation=build_evaluation(
        model, cfg, names, table, fault_level))

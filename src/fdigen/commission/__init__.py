"""Commissioning FDI on a new rig: from one healthy log to a design that stays quiet.

``fdigen commission HEALTHY.csv`` (:func:`fdigen.commission.pipeline.commission`):

1. :func:`fdigen.discover.discover` calibrates the model's uncertain parameters on the
   healthy log and finds the effects the model lacks;
2. the commissioned model file is written: the augmented (or only calibrated) model, the
   effect parameters marked uncertain;
3. :mod:`fdigen.tune` designs the thresholds for *that* plant by a Monte Carlo campaign
   (the commissioned model simulated with its effects, calibrated parameters spread by
   their uncertainty);
4. :mod:`~fdigen.commission.healthy_check` checks them against the measured healthy log
   itself (each threshold at least ``data_margin`` times the log's maximum RMS, raised if
   needed; no flag over the log);
5. :mod:`~fdigen.commission.faults` runs the validation and fault campaigns with the
   final thresholds (false alarms, detection and isolation delays per fault), the model
   is built, and :mod:`~fdigen.commission.report` reports.

Nothing heavy is imported here.
"""

__all__ = ["commission", "CommissionSettings"]


def __getattr__(name):
    if name in __all__:
        from fdigen.commission import pipeline

        return getattr(pipeline, name)
    raise AttributeError(name)

"""Close the loop with measured data: find the effect the model lacks, add it, report.

``fdigen discover LOG.csv`` (:func:`fdigen.discover.pipeline.discover`):

1. :mod:`~fdigen.discover.calibrate` estimates the model's ``uncertain`` parameters on the
   first part of the log by equation error (modulating-function windows);
2. :mod:`~fdigen.discover.locate` tests each model equation's error for structure beyond
   white noise;
3. :mod:`~fdigen.discover.explain` picks the library effect(s)
   (:mod:`~fdigen.discover.effects`) by BIC, checked on the held-back part;
4. :mod:`~fdigen.discover.augment` writes the augmented model file and rebuilds the code;
5. :mod:`~fdigen.discover.report` reports output error and FDI residuals before and after.

Nothing heavy is imported here.
"""

__all__ = ["discover", "DiscoverSettings", "DiscoveryResult", "library", "get_effect"]


def __getattr__(name):
    if name in ("discover", "DiscoverSettings", "DiscoveryResult"):
        from fdigen.discover import pipeline

        return getattr(pipeline, name)
    if name in ("library", "get_effect"):
        from fdigen.discover import effects

        return getattr(effects, name)
    raise AttributeError(name)

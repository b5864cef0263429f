"""fdigen: symbolic model-to-code generator for model-based fault detection and isolation.

The data flow one way: ``model`` (what the engineer writes) -> ``derive`` (linearisation,
observability, Kalman gains) -> ``design`` (the backend-neutral FDI step) -> ``backends``
(reference, CasADi, C) -> ``verify`` (numeric equivalence). Nothing runs on import.
"""

__version__ = "0.1.0"

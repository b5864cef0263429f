"""Make an augmented model's FDI design derivable: fall back where a scheduled filter cannot be.

A discovered effect can change what the design may derive. A leak to ambient makes the
pressure filter's reduced coordinates depend on the state (the observable combination of
``Pp`` and ``Pn`` is weighted by the chamber volumes), and a steep friction sign can make a
scheduled prediction unstable at a corner of its schedule. The Kalman filter's prediction
scheduled on the measured state (``schedule = "measured"``) is then refused by the design
(:func:`fdigen.design.scheduled_prediction.scheduled_transition`).

:func:`ensure_design` derives the design of the augmented file and, for each filter so
refused, switches that filter to its operating-point prediction
(``[fdi.kalman.<R>] schedule = "operating_point"``, the unscheduled steady-state filter)
in the file, with a comment and a warning saying so, and derives again. A threshold of
a residual the original design derived and the augmented one does not (an effect can
change which sub-models separate the classes) is removed from the file, with a warning.
Any other design error is raised as it is.
"""

from __future__ import annotations

import re
from pathlib import Path

from fdigen.errors import DesignError, ModelFileError

_PATTERNS = (re.compile(r"Kalman filter (\w+): cannot schedule"),
             re.compile(r"fdi\.kalman\.(\w+)\.schedule"))


def _refused_filter(exc: Exception) -> str | None:
    for pat in _PATTERNS:
        m = pat.search(str(exc))
        if m:
            return m.group(1)
    return None


def unschedule(text: str, residual: str, reason: str) -> str:
    """The model file text with ``[fdi.kalman.<residual>] schedule = "operating_point"``."""
    import tomlkit

    doc = tomlkit.parse(text)
    table = doc["fdi"]["kalman"][residual]
    table["schedule"] = "operating_point"
    table["schedule"].comment(f"fdigen: unscheduled, {reason}"[:200])
    return tomlkit.dumps(doc)


def drop_threshold(text: str, residual: str) -> str:
    """The model file text without ``[fdi.thresholds] <residual>`` (and its residual key)."""
    import tomlkit

    doc = tomlkit.parse(text)
    del doc["fdi"]["thresholds"][residual]
    if residual in doc["fdi"].get("residual_keys", {}):
        del doc["fdi"]["residual_keys"][residual]
    return tomlkit.dumps(doc)


def _stray_threshold(exc: Exception, model) -> str | None:
    """The residual whose threshold the design refused as not derived, or as written for
    another residual (:mod:`fdigen.design.residual_identity`), if that is ``exc``."""
    stale = getattr(exc, "stale_residuals", ())
    if stale:
        return stale[0]
    if not isinstance(exc, ModelFileError) or exc.field != "fdi.thresholds":
        return None
    name = exc.symbol
    if name in dict(model.fdi.get("thresholds", {})) and "does not derive" in str(exc):
        return name
    return None


def ensure_design(path, model, log=None):
    """Derive the FDI design of the model file ``path``; unschedule refused filters.

    Parameters
    ----------
    path : Path
        The augmented model file (rewritten in place if a filter is unscheduled).
    model : Model
        Its parsed model.
    log : callable, optional
        Progress messages.

    Returns
    -------
    (Model, FdiDesign, list of str)
        The (possibly updated) model, its design and the warnings.
    """
    from fdigen.design.cache import cached_design
    from fdigen.files.model_write import write_model_text as write_text
    from fdigen.model.model_file import load_model

    say = log or (lambda msg: None)
    path = Path(path)
    warnings = []
    done = set()
    while True:
        try:
            return model, cached_design(model), warnings
        except ModelFileError as exc:
            stray = _stray_threshold(exc, model)
            if stray is None or stray in done:
                raise
            msg = (f"the augmented design does not derive residual {stray}"
                   + (" as the threshold was written for" if getattr(exc, "stale_residuals", ())
                      else "") + ": its threshold is removed from the augmented model file")
            say(msg)
            warnings.append(msg)
            done.add(stray)
            write_text(path, drop_threshold(path.read_text(), stray))
            model = load_model(path)
        except DesignError as exc:
            residual = _refused_filter(exc)
            kalman = dict(model.fdi.get("kalman", {}))
            if residual is None or residual in done or residual not in kalman:
                raise
            reason = str(exc).split(": ", 1)[-1].split(";")[0]
            msg = (f"Kalman filter {residual}: its scheduled prediction is refused for the "
                   f"augmented model ({reason}); it predicts with the operating point's "
                   "matrices instead (schedule = \"operating_point\")")
            say(msg)
            warnings.append(msg)
            done.add(residual)
            write_text(path, unschedule(path.read_text(), residual, reason))
            model = load_model(path)

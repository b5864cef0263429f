r"""Make an augmented model's FDI design derivable: fall back where a scheduled filter cannot be.

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
A residual the augmented design derives and the file has no threshold for (the derived
residuals depend on the model: a new residual, or one whose threshold was written for
another residual and removed) gets a threshold from the log the model was augmented on,
when it is given:

.. math:: J_i = m_d \max_k \mathrm{RMS}_i[k]

(``m_d`` = 1.5, rounded up to three digits), the moving RMS of the design with every flag
off run over the log, as ``fdigen commission`` checks its thresholds against a healthy log
(:mod:`fdigen.commission.healthy_check`); a warning names each and says that
``fdigen tune`` or ``fdigen commission`` designs them against the parameter spread.
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
    """The model file text without ``[fdi.thresholds] <residual>`` (and its residual key and
    frozen horizon)."""
    import tomlkit

    doc = tomlkit.parse(text)
    del doc["fdi"]["thresholds"][residual]
    for table in ("residual_keys", "frozen_horizon"):
        if residual in doc["fdi"].get(table, {}):
            del doc["fdi"][table][residual]
    return tomlkit.dumps(doc)


#: A threshold read from a log is this many times the residual's largest RMS over it.
LOG_MARGIN = 1.5


def log_rms(design, u, y):
    """RMS trajectories ``(K, n_residuals)`` of ``design`` over the log with every flag
    off (every threshold :data:`~fdigen.tune.settings.NO_FLAG`: no latched flag, no frozen
    parallel model), so they do not depend on the thresholds."""
    import numpy as np

    from fdigen.detect import fdi_runner
    from fdigen.tune.model_update import flags_off

    return np.asarray(fdi_runner(flags_off(design), "c").run(u, y)["rms"], dtype=float)


def log_thresholds(model, residuals, u, y, margin: float = LOG_MARGIN) -> tuple[dict, dict]:
    """Thresholds ``margin x max_k RMS_i[k]`` of ``residuals`` over the log ``(u, y)``.

    The RMS is that of ``model``'s design with every flag off (every threshold
    :data:`~fdigen.tune.settings.NO_FLAG`: no latched flag, no frozen parallel model), so
    it does not depend on the thresholds being designed.

    Returns
    -------
    (dict, dict)
        Residual -> threshold, and residual -> key (:mod:`fdigen.design.residual_identity`)
        of every derived residual of the design.

    Raises
    ------
    DesignError
        If a residual's RMS over the log is not finite and positive (no threshold can be
        read from it).
    """
    import numpy as np

    from fdigen.design.cache import cached_design
    from fdigen.design.residual_identity import residual_keys
    from fdigen.tune.model_update import fill_missing_thresholds
    from fdigen.tune.settings import NO_FLAG
    from fdigen.tune.thresholds import round_up

    filled, _ = fill_missing_thresholds(model, NO_FLAG)
    design = cached_design(filled)
    names = list(design.residual_names)
    rms = log_rms(design, u, y)
    out = {}
    for name in residuals:
        col = rms[:, names.index(name)]
        peak = float(np.max(col)) if len(col) and np.isfinite(col).all() else float("nan")
        if not (peak > 0):
            raise DesignError(f"residual {name} of the augmented design has no finite "
                              f"positive RMS over the log (max {peak!r}): its threshold "
                              "cannot be read from the log; design it with `fdigen tune "
                              "--model FILE --write`")
        out[name] = round_up(margin * peak)[0]
    return out, residual_keys(design.extra_residuals)


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


def ensure_design(path, model, log=None, data=None):
    """Derive the FDI design of the model file ``path``; unschedule refused filters.

    Parameters
    ----------
    path : Path
        The augmented model file (rewritten in place if a filter is unscheduled).
    model : Model
        Its parsed model.
    log : callable, optional
        Progress messages.
    data : (numpy.ndarray, numpy.ndarray), optional
        The log ``(u, y)`` the model was augmented on: thresholds the design needs and
        the file lacks are read from it (:func:`log_thresholds`); without it the design's
        refusal is raised.

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
    done, filled = set(), set()
    while True:
        try:
            return model, cached_design(model), warnings
        except ModelFileError as exc:
            missing = tuple(getattr(exc, "missing_thresholds", ()))
            if missing and data is not None and not set(missing) & filled:
                # a declared residual without a threshold (a model not tuned yet)
                model = _fill_from_log(path, model, missing, data, say, warnings)
                filled.update(missing)
                continue
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
            missing = tuple(getattr(exc, "missing_thresholds", ()))
            if missing and data is not None and not set(missing) & filled:
                model = _fill_from_log(path, model, missing, data, say, warnings)
                filled.update(missing)
                continue
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


#: how the note of :func:`_fill_from_log` starts (commission, which designs those
#: thresholds itself next, leaves it out of its warnings)
PLACEHOLDER_NOTE = "the augmented design has residual(s)"


def _fill_from_log(path, model, missing, data, say, warnings):
    """Write into the model file ``path`` the thresholds of the residuals ``missing``,
    read from the log ``data`` (:func:`log_thresholds`); return the model read back."""
    from fdigen.model.model_file import load_model
    from fdigen.tune.model_update import write_thresholds

    values, keys = log_thresholds(model, missing, *data)
    msg = (PLACEHOLDER_NOTE + " " + ", ".join(
        f"{n} (threshold {v:.3g})" for n, v in values.items())
        + f" without a threshold in the file: set to {LOG_MARGIN:g} x their "
        "largest moving RMS over the log, flags off; `fdigen tune --model FILE "
        "--write` or `fdigen commission` designs them against the parameter "
        "spread")
    say(msg)
    warnings.append(msg)
    every = {**{n: float(v) for n, v in model.fdi.get("thresholds", {}).items()}, **values}
    mark = None
    if "refused" not in model.fdi:
        # the file reads as a designed one otherwise: a user's axis ran `detect` on it,
        # blind to a 40 % valve loss, and nothing said so
        from fdigen.design.config import DISCOVER_REFUSAL

        mark = {"refused": f"{DISCOVER_REFUSAL} thresholds of " + ", ".join(values)
                + f" read from the log ({LOG_MARGIN:g} x its largest RMS, flags off), "
                "not designed against the parameter spread nor checked on fresh healthy "
                "runs: `fdigen tune --model FILE --write` or `fdigen commission` designs "
                "them."}
    write_thresholds(path, every, keys={n: k for n, k in keys.items() if n in every},
                     fdi_values=mark)
    return load_model(path)


def design_on_the_log(model, u, y, say, warnings):
    """The FDI design of the model as given, its missing thresholds (a derived residual the
    file has none for: a model not tuned yet) read from the log as
    :func:`log_thresholds` does for the augmented model, in
    memory (a user's tanks: the augmented model was written and built, then discover
    ended with exit 2 on the original's missing threshold)."""
    from fdigen.design.cache import cached_design

    try:
        return cached_design(model)
    except (DesignError, ModelFileError) as exc:
        if not getattr(exc, "missing_thresholds", ()):
            raise
    from fdigen.tune.model_update import design_with_thresholds, fill_missing_thresholds
    from fdigen.tune.settings import NO_FLAG

    # every missing one: the file's residuals first, then the derived ones the design
    # refuses only once those have thresholds (a user's two tanks: R1, R2, then R3)
    _, missing = fill_missing_thresholds(model, NO_FLAG)
    values, _ = log_thresholds(model, missing, u, y)
    msg = ("the model file has no threshold for " + ", ".join(
        f"{n} (set to {v:.3g})" for n, v in values.items()) + f": the design before "
        f"discovery uses {LOG_MARGIN:g} x their largest moving RMS over the log; `fdigen "
        "tune --model FILE --write` designs them")
    say(msg)
    warnings.append(msg)
    every = {**{n: float(v) for n, v in model.fdi.get("thresholds", {}).items()}, **values}
    return design_with_thresholds(model, every)

"""Thresholds into the model: the TOML file and the rebuilt design.

Holds :func:`thresholds_snippet` (the ``[fdi.thresholds]`` table as TOML),
:func:`updated_model_text` and :func:`write_thresholds` (the model file updated in place
with tomlkit, layout and comments kept, returning the diff) and
:func:`design_with_thresholds` (the FDI design rebuilt with replaced thresholds) and
:func:`fill_missing_thresholds` (a model whose missing thresholds are set to a value
that never flags, so that a model file without them can be tuned).
"""

from __future__ import annotations

import dataclasses
import difflib
from pathlib import Path

from fdigen.errors import FdigenError
from fdigen.files.model_write import write_model_text
from fdigen.tune.thresholds import _literal


def thresholds_snippet(thresholds: dict, current: dict | None = None,
                       text: dict | None = None) -> str:
    """The ``[fdi.thresholds]`` table as TOML (with the current values as comments)."""
    lines = ["[fdi.thresholds]"]
    for name, value in thresholds.items():
        lit = (text or {}).get(name) or _literal(value)
        note = "" if current is None or name not in current else f"  # was {current[name]:g}"
        lines.append(f"{name} = {lit}{note}")
    return "\n".join(lines) + "\n"


def updated_model_text(text: str, thresholds: dict, literals: dict | None = None,
                       horizons: dict | None = None, keys: dict | None = None,
                       horizon_note: str | None = None,
                       threshold_note: str | None = None,
                       fdi_values: dict | None = None) -> str:
    """``text`` (a model file) with the ``[fdi.thresholds]`` values replaced or added (the
    table is created when the file has none), and, with
    ``horizons``, the ``[fdi.frozen_horizon]`` table set to exactly them).

    Uses tomlkit: comments, key order and layout are kept, and the comment column of each
    changed line stays where it was when there is room. With ``keys`` (derived residual ->
    what it is, :mod:`fdigen.design.residual_identity`), ``[fdi.residual_keys]`` is set to
    exactly them (created after ``[fdi.thresholds]``), and ``thresholds`` are then all the
    design's: a threshold of a residual not among them is removed. With ``horizon_note``
    (how the horizons were measured), the ``[fdi.frozen_horizon]`` header's comment is set
    to it whenever the table is written, so that it never describes an older measurement.
    ``threshold_note`` does the same for the ``[fdi.thresholds]`` header when its comment is
    fdigen's (it names `fdigen tune`) or missing; a comment of the user's own is kept.
    ``fdi_values`` sets plain ``[fdi]`` keys (``realign_noise_scale`` chosen by tune's
    realignment search) in place, or after the table's last key; a value None removes
    the key.
    """
    import tomlkit
    from tomlkit.items import Float, Trivia

    doc = tomlkit.parse(text)
    if "fdi" not in doc:
        raise FdigenError("the model file has no [fdi] table")
    created = "thresholds" not in doc["fdi"]
    if created:                          # a model not tuned yet: the table is made here
        _new_subtable(doc["fdi"], "thresholds")
    table = doc["fdi"]["thresholds"]
    for name, value in thresholds.items():
        lit = (literals or {}).get(name) or _literal(float(value))
        if name in table and float(table[name]) == float(lit):
            continue            # unchanged: keep the file's own spelling
        if name in table:
            old = table[name]
            t = old.trivia
            trivia = Trivia(indent=t.indent, comment_ws=t.comment_ws, comment=t.comment,
                            trail=t.trail)
            if trivia.comment:
                width = len(old.as_string()) + len(trivia.comment_ws)
                trivia.comment_ws = " " * max(width - len(lit), 1)
            table[name] = Float(float(lit), trivia, lit)
        else:
            table[name] = Float(float(lit), Trivia(), lit)
    if threshold_note and (not table.trivia.comment or "fdigen tune" in table.trivia.comment):
        if table.trivia.comment != f"# {threshold_note}":
            ws = table.trivia.comment_ws or " "
            table.comment(threshold_note)
            table.trivia.comment_ws = ws
    if created:
        table.add(tomlkit.nl())
    if horizons is not None and (horizons or "frozen_horizon" in doc["fdi"]):
        # (no horizon measured and none declared: no empty table is written)
        fdi = doc["fdi"]
        new_hz = "frozen_horizon" not in fdi
        if new_hz:
            _new_subtable(fdi, "frozen_horizon", after="thresholds")
        hz = fdi["frozen_horizon"]
        for name in [k for k in hz if k not in horizons]:
            del hz[name]
        for name, value in horizons.items():
            if name not in hz or float(hz[name]) != float(value):
                hz[name] = float(value)
        if horizon_note and hz.trivia.comment != f"# {horizon_note}":
            ws = hz.trivia.comment_ws or " "
            hz.comment(horizon_note)
            hz.trivia.comment_ws = ws
        if new_hz:
            hz.add(tomlkit.nl())
    if keys is not None:    # the whole design's thresholds: a residual it lacks goes
        for name in [k for k in table if k not in thresholds]:
            del table[name]
        _set_table(doc["fdi"], "residual_keys", keys,
                   "frozen_horizon" if "frozen_horizon" in doc["fdi"] else "thresholds")
    for key, value in (fdi_values or {}).items():
        if value is None:             # a key to remove (tune's own refusal, lifted)
            if key in doc["fdi"]:
                del doc["fdi"][key]
        else:
            doc["fdi"][key] = value
    out = tomlkit.dumps(doc)
    replaced = ("thresholds", "frozen_horizon", "residual_keys", *(fdi_values or {}))
    try:
        _check_edit(text, out, replaced)
    except FdigenError:
        # dotted keys (`fdi.window = 20`): new sub-tables appended at the end of the file
        # (TOML lets a [fdi.thresholds] header define a sub-table of a table made by
        # dotted keys; at the end, no existing key can fall into it)
        if any(t in tomlkit.parse(text).get("fdi", {}) for t in replaced) or fdi_values:
            raise
        tail = tomlkit.document()
        tail.add("fdi", tomlkit.table(is_super_table=True))
        tail["fdi"]["thresholds"] = {
            name: Float(float(lit), Trivia(), lit) for name, lit in
            ((n, (literals or {}).get(n) or _literal(float(v))) for n, v in thresholds.items())}
        if threshold_note:
            tail["fdi"]["thresholds"].comment(threshold_note)
        if horizons:
            hz = tomlkit.table()
            for k, v in horizons.items():
                hz[k] = float(v)
            if horizon_note:
                hz.comment(horizon_note)
            tail["fdi"]["frozen_horizon"] = hz
        if keys:
            tail["fdi"]["residual_keys"] = dict(keys)
        out = text.rstrip("\n") + "\n\n" + tomlkit.dumps(tail)
        _check_edit(text, out, replaced)
    return out


def _set_table(fdi, name: str, values: dict, after: str = "thresholds"):
    """``fdi[name]`` set to exactly ``values`` (unchanged entries keep their spelling); a
    table absent and not needed is not created, a new one is placed after ``fdi[after]``
    (so that it does not land between the comment that closes ``[fdi]`` and the table the
    comment introduces)."""
    import tomlkit

    if name not in fdi:
        if not values:
            return
        new = tomlkit.table()
        for key, value in values.items():
            new[key] = value
        new.add(tomlkit.nl())
        try:
            fdi.value._insert_after(after, name, new)
        except (KeyError, AttributeError, ValueError):
            fdi[name] = new
        return
    tab = fdi[name]
    for key in [k for k in tab if k not in values]:
        del tab[key]
    for key, value in values.items():
        if key not in tab or tab[key] != value:
            tab[key] = value


def _new_subtable(fdi, name: str, after: str | None = None) -> None:
    """Add the empty table ``[fdi.<name>]`` right after ``[fdi.<after>]`` (else after
    the first sub-table of ``[fdi]``), not at the end of ``[fdi]``: the comment lines
    at the end of the last sub-table belong to the table that follows it."""
    import tomlkit
    from tomlkit.items import Table

    table = tomlkit.table()     # the caller fills it, then ends it with a blank line
    subtables = [k for k, v in fdi.items() if isinstance(v, Table)]
    anchor = after if after in subtables else (subtables[0] if subtables else None)
    try:
        if anchor is None:
            raise KeyError(name)
        fdi.value._insert_after(anchor, name, table)
    except (KeyError, AttributeError, ValueError):   # no super-table (dotted keys)
        fdi[name] = table


def _check_edit(old: str, new: str, replaced: tuple[str, ...]) -> None:
    """Refuse an edit that changed anything but ``[fdi.<replaced>]``: parsed (tomllib),
    the new text must hold the old document with only those tables set.

    A model written with dotted keys (``fdi.window = 20``) once had every key after the
    inserted table moved into it: the file still parsed, and meant something else.
    """
    import tomllib

    def rest(text):
        data = tomllib.loads(text)
        fdi = dict(data.get("fdi", {}))
        for key in replaced:
            fdi.pop(key, None)
        return {**data, "fdi": fdi}

    tables = tomllib.loads(new).get("fdi", {})
    nested = any(isinstance(v, (dict, list)) for t in replaced
                 if isinstance(tables.get(t), dict)
                 for v in tables[t].values())   # keys that fell into them
    if nested or rest(old) != rest(new):
        raise FdigenError("cannot add the tuned tables to this model file without changing "
                          "its meaning (its layout, e.g. dotted keys such as "
                          "'fdi.window = 20', does not take a new [fdi.thresholds] table "
                          "safely); write the [fdi] keys under an [fdi] table header, or "
                          "paste the tables printed by `fdigen tune` (without --write)")


def write_thresholds(path, thresholds: dict, literals: dict | None = None,
                     dry_run: bool = False, horizons: dict | None = None,
                     keys: dict | None = None, expected_digest: str | None = None,
                     horizon_note: str | None = None,
                     threshold_note: str | None = None,
                     fdi_values: dict | None = None) -> str:
    """Update the ``[fdi.thresholds]`` table of the model file at ``path`` in place.

    With ``expected_digest`` (the :func:`~fdigen.files.model_write.file_digest` of the
    file the thresholds were tuned on) the write is refused
    (:class:`~fdigen.files.model_write.ModelChangedError`) when the file changed since,
    checked under an exclusive lock.

    Returns the unified diff of the change (written only without ``dry_run``).
    """
    import hashlib

    path = Path(path)
    raw = path.read_bytes()
    old = raw.decode("utf-8")
    new = updated_model_text(old, thresholds, literals, horizons, keys, horizon_note,
                             threshold_note, fdi_values)
    diff = "".join(difflib.unified_diff(old.splitlines(True), new.splitlines(True),
                                        f"a/{path.name}", f"b/{path.name}"))
    if not dry_run and (new != old or expected_digest is not None):
        # atomic, parsed back, locked; a symlinked model file: its target, mode kept
        write_model_text(path, new, expected_digest if expected_digest is not None
                         else hashlib.sha256(raw).hexdigest(), check_input=True)
    return diff


def model_with_thresholds(model, thresholds: dict, drop=()):
    """``model`` with the entries of ``[fdi.thresholds]`` named in ``thresholds`` set, and
    the thresholds, residual keys and frozen horizons of the residuals in ``drop`` (written
    for other residuals) removed."""
    fdi = dict(model.fdi)
    fdi["thresholds"] = {**{k: v for k, v in dict(fdi.get("thresholds", {})).items()
                            if k not in drop},
                         **{k: float(v) for k, v in thresholds.items()}}
    for table in ("residual_keys", "frozen_horizon") if drop else ():
        if table in fdi:
            fdi[table] = {k: v for k, v in dict(fdi[table]).items() if k not in drop}
    return dataclasses.replace(model, fdi=fdi)


def model_with_horizons(model, horizons: dict):
    """``model`` with ``[fdi.frozen_horizon]`` set to exactly ``horizons`` (residual ->
    seconds), as ``tune --write`` writes it."""
    fdi = dict(model.fdi)
    fdi["frozen_horizon"] = {k: float(v) for k, v in horizons.items()}
    return dataclasses.replace(model, fdi=fdi)


def design_with_horizons(design, horizons: dict):
    """``design`` with ``[fdi.frozen_horizon]`` set to exactly ``horizons``, without
    deriving it again: the horizons enter only the evaluation (the late mask of each
    residual), never the step program (:func:`fdigen.design.retarget.retargeted`).
    Equal to the derivation of :func:`model_with_horizons`
    (``tests/test_frozen_horizon.py``)."""
    from fdigen.design.retarget import retargeted

    return retargeted(design, model_with_horizons(design.model, horizons))


def design_with_thresholds(model, thresholds: dict):
    """The FDI design of ``model`` with ``[fdi.thresholds]`` replaced (cached; set on a
    design of this process that differs only in threshold values rather than derived
    again: :mod:`fdigen.design.retarget`)."""
    from fdigen.design.cache import cached_design

    return cached_design(model_with_thresholds(model, thresholds))


def flags_off(design):
    """``design`` with every threshold its model file sets at
    :data:`~fdigen.tune.settings.NO_FLAG`: no flag rises, so no parallel model freezes,
    and each residual's RMS is its own response (the healthy campaign's design, a log's
    RMS before its thresholds exist, a fault's response to scale)."""
    from fdigen.tune.settings import NO_FLAG

    return design_with_thresholds(design.model, {
        n: NO_FLAG for n in design.residual_names if n in design.config.thresholds})


def fill_missing_thresholds(model, value: float, rounds: int = 8):
    """``model`` with every threshold its design needs and the file lacks set to ``value``.

    A model file without thresholds (a new model, or a design that now derives a residual
    the file has no threshold for, or one whose threshold was written for another residual:
    ``stale_residuals``, :mod:`fdigen.design.residual_identity`) is refused by the design with the list of the missing
    ones (``missing_thresholds`` of the error). This sets them, the residuals the file
    names first, then the derived ones (known only once the design is derived), so that
    ``fdigen tune`` can run its healthy campaign (``value`` = a threshold that never
    flags) and design them.

    Returns
    -------
    (Model, tuple of str)
        The model and the residuals whose thresholds were set.
    """
    from fdigen.design.cache import cached_design

    filled, dropped = [], []
    for _ in range(rounds):
        try:
            cached_design(model)
            return model, tuple(filled)
        except FdigenError as exc:
            stale = [n for n in getattr(exc, "stale_residuals", ()) if n not in dropped]
            missing = [n for n in getattr(exc, "missing_thresholds", ()) if n not in filled]
            if not missing and not stale:
                raise
            filled += missing
            dropped += stale
            model = model_with_thresholds(model, dict.fromkeys(missing, value), stale)
    cached_design(model)
    return model, tuple(filled)


def threshold_note(settings: dict, false_alarm: dict | None = None) -> str:
    """The ``[fdi.thresholds]`` header comment for a tune run (its ``settings`` as in the
    report): the command's campaign and the design rule; with ``false_alarm`` (the
    report's) validation runs that raised a flag are written too, so the file never
    presents thresholds that failed their own validation as tuned (a user's quadruple
    tank: 5 of 10, written without a word)."""
    tol = settings.get("tolerance")
    own = dict(settings.get("tolerances") or ())
    spread = (f"+-{tol * 100:g} % on the uncertain parameters, " if tol else "")
    if own:
        spread = ("own tolerances on " + ", ".join(sorted(own))
                  + (f", +-{tol * 100:g} % on the other uncertain parameters" if tol else "")
                  + ", ")
    fa = false_alarm or {}
    failed = ""
    if fa.get("validation_false_alarms"):
        failed = (f"; FAILED validation: {fa['validation_false_alarms']} of "
                  f"{fa['validation_runs']} healthy runs raised a flag")
    # the options that shape the campaign, where not their defaults (a user re-ran the
    # comment's command and got another campaign: round 41)
    extra = ""
    for key, flag, default in (("validation_runs", "--validation-runs", 10),
                               ("fault_starts", "--fault-starts", 2),
                               ("horizon_runs", "--horizon-runs", 10)):
        if key in settings and settings[key] != default:
            extra += f" {flag} {settings[key]}"
    sizes = settings.get("fault_factors")
    if sizes is not None and tuple(float(v) for v in sizes) != (0.25, 0.5, 1.0, 2.0):
        extra += " --fault-sizes " + ",".join(f"{float(v):g}" for v in sizes)
    return (f"from `fdigen tune --runs {settings['runs']} --duration "
            f"{settings['duration']:g} --seed {settings['seed']}{extra} --write` (" + spread
            + f"{settings['false_alarm_rate'] * 100:g} % false alarms per run, margin "
            f"{settings['margin']:g}{failed})")


def horizon_note(frozen_horizon: dict, spread: float | None = None,
                 duration: float | None = None) -> str:
    """The ``[fdi.frozen_horizon]`` header comment for a measurement
    (:func:`fdigen.tune.frozen_horizon.frozen_horizons`' result, optionally combined with
    fault runs): what ran and the rule ``H = earliest time to threshold / margin``."""
    fr = ", ".join(f"{f:g}" for f in frozen_horizon["fractions"])
    text = (f"s; `fdigen tune`: {frozen_horizon['trials']} freezes of "
            f"{frozen_horizon['runs']} healthy runs"
            + (f" (+-{spread * 100:g} %)" if spread else "")
            + f" at {fr} of each" + (f" {duration:g} s" if duration else "") + " run")
    if frozen_horizon.get("fault_runs"):
        text += f" and {frozen_horizon['fault_runs']} fault runs at test size"
    return text + f", earliest time to threshold / {frozen_horizon['margin']:g}"

"""The commissioned model file: its text, written once the campaigns have measured what
goes into it, and the mark of a design ``fdigen commission`` refused."""

from __future__ import annotations

from fdigen.commission.spread import round_up


def commissioned_text(text: str, uncertain: list, thresholds: dict, literals: dict,
                      origin: str, note: str, keys: dict | None = None,
                      horizons: dict | None = None, horizon_note: str | None = None,
                      tolerances: dict | None = None, fdi_values: dict | None = None) -> str:
    """The model file text with ``uncertain = true`` on ``uncertain`` and the thresholds
    (with ``keys``, the derived residuals' keys: :mod:`fdigen.design.residual_identity`;
    with ``horizons``, ``[fdi.frozen_horizon]`` set to exactly them; with ``tolerances``,
    each parameter's ``tolerance``, rounded up to 3 digits, so that ``fdigen tune`` on the
    commissioned file spreads the parameters as the commissioning did; ``fdi_values``:
    further ``[fdi]`` keys, the measured ``startup``)."""
    import tomlkit

    from fdigen.backends.escape import comment_text
    from fdigen.tune.model_update import updated_model_text

    doc = tomlkit.parse(text)
    for name in uncertain:
        entry = doc["parameters"][name]
        if not entry.get("uncertain", False):
            entry["uncertain"] = True
    for name, tol in (tolerances or {}).items():
        doc["parameters"][name]["tolerance"] = round_up(tol)
    text = updated_model_text(tomlkit.dumps(doc), thresholds, literals, keys=keys,
                              horizons=horizons, horizon_note=horizon_note,
                              fdi_values=fdi_values)
    origin = comment_text(origin, "#")   # a log's name: one line, no TOML can follow
    return f"# Commissioned by `fdigen commission` from {origin}: {note}\n" + text


def _horizon_table(rep: dict, tol: float, duration: float) -> dict:
    """``horizons`` and ``horizon_note`` of :func:`commissioned_text` from the threshold
    campaign's report (none measured: the file's table is left as it is)."""
    from fdigen.tune.model_update import horizon_note

    hz = rep.get("frozen_horizon")
    if not hz:
        return {}
    return {"horizons": hz["horizons"], "horizon_note": horizon_note(hz, tol, duration)}


def with_values(text: str, values: dict) -> str:
    """The model file text with ``[parameters]`` ``name.value`` set to ``values[name]``
    (a TOML document edit: comments and layout kept)."""
    import tomlkit

    doc = tomlkit.parse(text)
    for name, value in values.items():
        doc["parameters"][name]["value"] = float(value)
    return tomlkit.dumps(doc)


def mark_refusal(path, verdict: dict) -> None:
    """Write the refusal into the commissioned file ``path`` (``[fdi] refused``: the
    failures, one sentence each), or take an old one out of a usable design's file.

    A refused design's file was written without a mark, and ``detect`` ran it in silence:
    a user's pump rig, whose thresholds were 14 times its current sensor's span, was
    "diagnosis: none" on the logs of both its faults."""
    import tomlkit

    from fdigen.files.model_write import write_model_text

    text = path.read_text(encoding="utf-8")
    doc = tomlkit.parse(text)
    fdi = doc.get("fdi")
    if fdi is None:
        return
    if verdict["usable"]:
        if "refused" not in fdi:
            return
        del fdi["refused"]
    else:
        reason = " ".join(f.rstrip(".") + "." for f in verdict["failures"])
        fdi["refused"] = "".join(c if c.isprintable() else " " for c in reason)[:4000]
    write_model_text(path, tomlkit.dumps(doc))

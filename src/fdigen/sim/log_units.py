"""The unit check of a log: the magnitude of each output that measures a state against
that state's range and limits (pressures in bar or kPa for a model in Pa, positions in mm
for metres, levels in mm for a model in cm)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import sympy as sp

from fdigen.errors import LogError
from fdigen.model.model import Model
from fdigen.model.sensor_maps import state_of_output

#: Factor of the unit check: see :func:`check_units`.
UNIT_FACTOR = 50.0


def sensor_span(model: Model, output):
    """``(largest magnitude of the range, lower limit)`` of the state an output measures,
    as the sensor reads them (through its map, e.g. ``kc*h``), or ``None``."""
    sm = state_of_output(model, output.name)
    if sm is None:
        return None
    state = model.states[model.state_index(sm.state)]
    if not state.range:
        return None

    def read(v):
        at = sm.forward.xreplace({state.symbol: sp.Float(v)})
        return float(at.xreplace(model.parameter_values))

    hi = max(abs(read(float(v))) for v in state.range)
    lo = bounds = None
    if state.limits:
        try:
            ends = [read(sp.sympify(v).xreplace(model.parameter_values))
                    for v in state.limits]
            # the smallest reading over the limits: a falling map's (an NTC in ohm) is
            # at the upper limit, and its lower limit's 2e5 ohm refused every log
            lo, bounds = min(ends), (min(ends), max(ends))
        except (TypeError, ValueError, sp.SympifyError):
            lo = bounds = None
    return hi, lo, bounds


def check_units(path: Path, model: Model, y: np.ndarray) -> None:
    """Magnitudes of the outputs that measure a state against that state (wrong units).

    Too large: the median magnitude exceeds :data:`UNIT_FACTOR` times the largest
    magnitude of the state's ``range`` (positions in mm). Too small, only for states
    with a positive hard lower limit (absolute pressures, at least ``Patm``): the 90th
    percentile of the magnitude is below that limit over :data:`UNIT_FACTOR` (pressures in
    bar, kPa or MPa). A sensor that reads zero for part of the log (a signal loss) does not
    trip the check.
    """
    for j, o in enumerate(model.outputs):
        span = sensor_span(model, o)
        if span is None:
            continue
        mag = np.abs(y[:, j])
        if not np.isfinite(mag).any():
            continue
        med, q90 = (float(v) for v in np.nanpercentile(mag, [50, 90]))
        hi, lo, bounds = span
        beyond = 0.0
        if bounds is not None and bounds[1] > bounds[0]:
            width = bounds[1] - bounds[0]
            vals = y[np.isfinite(y[:, j]), j]
            beyond = float(np.mean((vals > bounds[1] + width) | (vals < bounds[0] - width)))
        if med > UNIT_FACTOR * hi:
            seen, expected = f"median magnitude {med:.4g}", f"up to about {hi:.4g}"
        elif lo is not None and lo > 0 and q90 < lo / UNIT_FACTOR:
            seen, expected = f"90 % of magnitudes below {q90:.4g}", f"at least {lo:.4g}"
        elif beyond >= 0.9:
            # a level log in mm for a model in cm: 10x, far inside the 50x above, yet
            # no tank of 30 cm reads 233 (a user's detect said "unexplained")
            seen = (f"{100 * beyond:.0f} % of the values more than the limits' width "
                    f"outside the limits, median magnitude {med:.4g}")
            expected = f"within {bounds[0]:.4g} to {bounds[1]:.4g}"
        else:
            continue
        raise LogError(
            f"{path}, column {o.column!r}: values look like the wrong unit ({seen}, "
            f"expected {expected} {o.unit}); a log is in the model's units (those of its "
            "outputs), or this is another column")


def is_units_row(row, width: int) -> bool:
    """Whether the first row under the header is a row of units (``s,%,V,A``): as many
    fields as the header, at least one neither empty nor a number, and no number but
    ``1``, the unit of a dimensionless quantity (a user's valve opening: ``s,1,degC``
    was read as data, "column 't': not a number ('s')")."""
    if len(row) != width:
        return False
    words = 0
    for f in row:
        f = f.strip()
        if not f:
            continue
        try:
            float(f)
        except ValueError:
            words += 1
            continue
        if f != "1":
            return False
    return words > 0


def _unit_key(unit: str) -> str:
    """A unit spelled for comparison: no spaces, brackets or degree signs, lower case."""
    key = "".join(unit.split()).strip("[]()").lower().replace("°", "deg")
    return {"degc": "degc", "degreec": "degc", "celsius": "degc", "sec": "s",
            "secs": "s", "seconds": "s", "second": "s", "percent": "%", "pct": "%",
            "permille": "‰", "-": "1"}.get(key, key)


#: Units of one quantity that differ by more than a spelling (a scale or an offset).
_SAME_QUANTITY = ({"pa", "kpa", "mpa", "hpa", "bar", "mbar", "psi", "atm"},
                  {"m", "cm", "mm", "km", "um", "in", "ft"},
                  {"degc", "k", "degf"},
                  {"l/min", "l/s", "l/h", "m3/s", "m3/h", "m^3/s", "m^3/h"},
                  {"rpm", "rad/s", "hz", "deg/s"},
                  {"s", "ms", "min", "h"},
                  {"rad", "deg", "degree", "degrees", "mrad", "rev"},
                  {"1", "%", "‰", "ppm"})
_PREFIXES = ("m", "k", "u", "µ", "μ", "c", "n", "g", "d", "h")


def _other_scale(given: str, unit: str) -> bool:
    """Whether ``given`` names another scale of ``unit`` (``mV`` for ``V``, ``bar`` for
    ``Pa``); a spelling fdigen cannot compare (``rad s-1`` for ``rad/s``) is not."""
    g, u = _unit_key(given), _unit_key(unit)
    if g == u:
        return False
    if any(g in group and u in group for group in _SAME_QUANTITY):
        return True
    return any(g == p + u or u == p + g for p in _PREFIXES)


def check_units_row(path: Path, model: Model, row, units: dict,
                    time_units: dict | None = None, source: str = "the log's row of units"
                    ) -> float:
    """The log's row of units (``row``, header column -> unit) against the model's units
    of the columns it uses: a column in another scale of the unit is refused, naming both
    (a log in mV for a model in V would be read 1000x off); a spelling that cannot be
    compared (``rad s-1``) is read as the model's.

    The time column is the exception: time is in seconds, and a unit of ``time_units``
    (unit -> factor to seconds: ``ms``, ``us``, ``min``, ``h``) is converted, not refused
    (a user's logger stamped in ms and could declare it nowhere). Returns the factor that
    converts the time column to seconds (1 without a time unit). ``row`` and ``source``
    say where the units were read (an HDF5 log's ``units`` attributes:
    ``row="datasets"``, ``source="their units attributes"``).
    """
    time_units = time_units or {}
    where = f"row {row}" if isinstance(row, int) else str(row)
    units = {c: _plain(path, where, c, u, source) for c, u in units.items()}
    given_t = units.get("t", "")
    scale = time_units.get(given_t, time_units.get(_unit_key(given_t)))
    if given_t and scale is None and (_other_scale(given_t, "s")
                                      or _other_dimension(given_t, "s")):
        raise LogError(f"{path}, {where}: {source} gives the time column "
                       f"'t' in {given_t!r}, which fdigen does not convert: one of "
                       + ", ".join(repr(u) for u in time_units))
    declared = {}
    for item in (*model.inputs, *model.outputs):
        if getattr(item, "unit", None):
            declared[item.column] = item.unit
    for column, unit in declared.items():
        given = units.get(column, "")
        if given and _other_scale(given, unit):
            raise LogError(f"{path}, {where}: {source} gives column "
                           f"{column!r} in {given!r}, the model's is {unit!r}: convert the "
                           "column (a log is in the model's units) or declare the unit the "
                           "logger writes in the model file")
        if given and _other_dimension(given, unit):
            # a voltage logged under a pressure's unit: another quantity, not a scale
            raise LogError(f"{path}, {where}: {source} gives column "
                           f"{column!r} in {given!r}, another quantity than the model's "
                           f"{unit!r}: the column is not what the model reads there (or its "
                           "unit is mislabelled)")
    return 1.0 if scale is None else float(scale)


def _plain(path, where, column, unit: str, source: str = "the log's row of units") -> str:
    """A row-of-units field as compared: NFKC-normalised (a full-width ``ｍｍ`` is ``mm``),
    stripped; ``""`` for ``-`` (no unit given). An invisible or control character is
    refused: a unit that reads as another than it is."""
    import unicodedata

    text = unicodedata.normalize("NFKC", str(unit)).strip()
    if any(unicodedata.category(ch) in ("Cc", "Cf", "Co", "Cs") for ch in text):
        raise LogError(f"{path}, {where}: {source} gives column "
                       f"{str(column)[:40]!r} a unit with an invisible or control character "
                       f"({text.encode('unicode_escape').decode()[:60]})")
    return "" if text == "-" else text


def _other_dimension(given: str, unit: str) -> bool:
    """Whether ``given`` and ``unit`` are both units fdigen can read
    (:func:`fdigen.model.dimensions.dimension`) of different physical dimensions."""
    from fdigen.model.dimensions import dimension

    a, b = dimension(given), dimension(unit)
    return a is not None and b is not None and a != b

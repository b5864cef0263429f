"""The fields of a CSV log as numbers: plain ASCII decimal numbers only, the required
columns checked (the first bad field named by row and column), the numeric extras kept."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fdigen.errors import LogError


def nonfinite_note(missing_ok: bool) -> str:
    """Why a non-finite value is refused: with ``missing_ok`` (the tolerant readers of
    ``detect`` and the data loop) a NaN is a missing sample and only Inf is refused."""
    if missing_ok:
        return "(Inf is not accepted; a NaN or an empty field is read as a missing sample)"
    return "(NaN and Inf are not accepted in logs)"


def _plain_number(text: str) -> bool:
    """ASCII, no digit separator: Python's ``float`` also reads ``1_0`` as 10 and
    Arabic-Indic or full-width digits (security round 4: a log's ``1_0`` changed a
    diagnosis)."""
    return text.isascii() and "_" not in text


def _first_bad_number(column: list[str]) -> int:
    for k, text in enumerate(column):
        if not _plain_number(text):
            return k
        try:
            float(text)
        except ValueError:
            return k
    return -1  # pragma: no cover - only called after numpy failed


def _parse_column(column: list[str]) -> tuple[np.ndarray | None, int]:
    """The column as floats, or ``(None, index of the first field that is no number)``."""
    joined = "".join(column)
    if not _plain_number(joined):
        return None, _first_bad_number(column)
    try:
        return np.array(column, dtype=str).astype(float), -1
    except (ValueError, OverflowError):
        return None, _first_bad_number(column)


def numbers_of_rows(path: Path, names, rows, numbers, need,
             allow_nan: bool = False) -> tuple[np.ndarray, dict]:
    """Required columns as a (K, len(need)) float array (checked); numeric extras (the
    kept columns ``names`` after ``need``). With ``allow_nan`` an empty field or ``nan``
    outside the time column is a missing sample (NaN)."""
    K = len(rows)
    columns = list(zip(*rows))
    rows.clear()                       # the text of the fields lives on in ``columns``
    index = {h: i for i, h in enumerate(names)}
    data = np.empty((K, len(need)))
    first = None  # (row index, column name, message) of the earliest problem
    for j, name in enumerate(need):
        text = columns[index[name]]
        if allow_nan and name != "t":
            text = tuple("nan" if not f.strip() else f for f in text)
        values, bad = _parse_column(text)
        if values is None:
            problem = (bad, name, f"not a number ({text[bad].strip()[:20]!r})")
        else:
            data[:, j] = values
            off = np.flatnonzero(~np.isfinite(values) & ~(
                np.isnan(values) if allow_nan and name != "t" else False))
            if not off.size:
                continue
            bad = int(off[0])
            problem = (bad, name, f"value is {text[bad].strip()[:20]} "
                                  + nonfinite_note(allow_nan and name != "t"))
        if first is None or problem[0] < first[0]:
            first = problem
    if first is not None:
        k, name, message = first
        raise LogError(f"{path}, row {numbers[k]}, column {name!r}: {message}")
    extra = {}
    for h, i in index.items():
        if h in need:
            continue
        values, _ = _parse_column(columns[i])
        if values is not None:
            extra[h] = values
    return data, extra

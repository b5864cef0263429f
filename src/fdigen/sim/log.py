"""Read and write logs in the rig format (CSV, header row, SI units, uniform sample time).

Columns are matched by name, in any order; the model says which columns it needs (its
inputs' and outputs' ``column``). Every problem is a :class:`~fdigen.errors.LogError`
naming the file, the row (1-based, the header is row 1) and the column.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fdigen.errors import LogError
from fdigen.model.model import Model

#: Relative deviation of a sample interval from the median that is still "uniform".
UNIFORM_TOL = 0.01


@dataclass(frozen=True)
class Log:
    """A measured log: time, inputs (K, m) and outputs (K, p) in the model's order."""

    path: str
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    extra: dict
    sample_time: float


def _expected_span(model: Model, output) -> tuple[float, float] | None:
    expr = model.expand(output.expr)
    for s in model.states:
        if expr == s.symbol and s.range:
            return s.range
    return None


def read_log(path: str | Path, model: Model) -> Log:
    """Read a log for ``model``.

    Raises
    ------
    LogError
        Missing column, text in a number field, NaN or Inf, empty file, time not strictly
        increasing or not uniform, or values whose magnitude shows a wrong unit (bar, kPa,
        mm instead of Pa and m).
    """
    path = Path(path)
    need = {"t": None}
    for s in model.inputs:
        need[s.column] = s
    for o in model.outputs:
        need[o.column] = o
    try:
        fh = open(path, newline="")
    except OSError as exc:
        raise LogError(f"{path}: cannot read log ({exc.strerror})")
    with fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration:
            raise LogError(f"{path}: empty file (expected a header row)")
        except csv.Error as exc:
            raise LogError(f"{path}, row 1: malformed CSV ({exc})")
        header = [h.strip() for h in header]
        missing = [c for c in need if c not in header]
        if missing:
            raise LogError(f"{path}, row 1: missing column '{missing[0]}' "
                           f"(header has {', '.join(header)})")
        dup = {h for h in header if header.count(h) > 1}
        if dup:
            raise LogError(f"{path}, row 1: duplicated column '{sorted(dup)[0]}'")
        rows = []
        try:
            for line, row in enumerate(reader, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != len(header):
                    raise LogError(f"{path}, row {line}: {len(row)} fields, header has "
                                   f"{len(header)}")
                values = []
                for col, text in zip(header, row):
                    try:
                        v = float(text)
                    except ValueError:
                        raise LogError(f"{path}, row {line}, column '{col}': not a number "
                                       f"({text.strip()[:20]!r})") from None
                    if not math.isfinite(v):
                        raise LogError(f"{path}, row {line}, column '{col}': value is {text.strip()} "
                                       "(NaN and Inf are not accepted in logs)")
                    values.append(v)
                rows.append(values)
        except csv.Error as exc:
            raise LogError(f"{path}, row {reader.line_num}: malformed CSV ({exc})")
    if len(rows) < 2:
        raise LogError(f"{path}: header only or a single sample; a log needs at least two rows")
    data = np.array(rows, dtype=float)
    col = {h: i for i, h in enumerate(header)}
    t = data[:, col["t"]]
    dts = np.diff(t)
    bad = np.flatnonzero(dts <= 0)
    if bad.size:
        raise LogError(f"{path}, row {bad[0] + 3}, column 't': time does not increase "
                       f"({t[bad[0]]} then {t[bad[0] + 1]})")
    dt = float(np.median(dts))
    off = np.flatnonzero(np.abs(dts - dt) > UNIFORM_TOL * dt)
    if off.size:
        k = off[0]
        raise LogError(f"{path}, row {k + 3}, column 't': non-uniform sample time "
                       f"(interval {dts[k]:.6g} s, median {dt:.6g} s)")
    u = np.stack([data[:, col[s.column]] for s in model.inputs], axis=1)
    y = np.stack([data[:, col[o.column]] for o in model.outputs], axis=1)
    for j, o in enumerate(model.outputs):
        span = _expected_span(model, o)
        if span is None:
            continue
        med = float(np.median(np.abs(y[:, j])))
        hi = max(abs(span[0]), abs(span[1]))
        if med > 0 and (med > 50 * hi or med < hi / 500):
            raise LogError(
                f"{path}, column '{o.column}': values look like the wrong unit (median "
                f"magnitude {med:.4g}, expected up to about {hi:.4g} {o.unit}); logs are in "
                "SI units: m, Pa (absolute), V")
    extra = {h: data[:, i] for h, i in col.items() if h not in need}
    return Log(str(path), t, u, y, extra, dt)


def write_log(path: str | Path, columns: dict, precision: int = 9) -> None:
    """Write a log (rig format) from a mapping column name -> 1-D array, ``t`` first."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    with open(path, "w", newline="") as fh:
        fh.write(",".join(names) + "\n")
        np.savetxt(fh, data, delimiter=",", fmt=f"%.{precision}g")

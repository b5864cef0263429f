"""Read and write logs in the rig format (CSV, header row, SI units, uniform sample time).

MAT (v5, v7.3), HDF5 and Parquet logs with the same columns are read too (by the file
suffix, :mod:`fdigen.sim.log_tables`) and checked the same way; in them a row is a sample.

Columns are matched by name, in any order; the model says which columns it needs (its
inputs' and outputs' ``column``, and the time ``t``). Every problem is a
:class:`~fdigen.errors.LogError` whose one-line message names the file, the row (1-based,
as an editor counts lines: the header is row 1) and the column.

What :func:`read_log` accepts and what it rejects
--------------------------------------------------

Accepted (and tested):

* columns in any order; extra columns are ignored by the FDI and not kept in memory
  (those named in ``extra_columns`` are kept in :attr:`Log.extra` when numeric, others
  are left out, and neither is checked);
* a UTF-8 byte-order mark, UTF-16 text with a byte-order mark, CRLF or CR line endings,
  blank lines (anywhere, including trailing ones), spaces around fields and names,
  quoted fields;
* anything Python's ``float`` reads as a finite number (``1e-3``, `` +2.5 ``).

Rejected with a :class:`~fdigen.errors.LogError`:

* an unreadable or empty file, text that is not UTF-8, malformed CSV;
* a missing required column, a required column named twice, a row whose number of
  fields differs from the header (a hint is given when the separator looks like ``;``
  or a tab);
* a header only, or a single sample;
* text, NaN or Inf in a required column (row and column named);
* a duplicated sample (a row equal to the one before it; with ``missing`` other than
  ``"refuse"`` it is dropped and counted instead), time not strictly increasing,
  a non-uniform sample time (:mod:`fdigen.sim.log_time`: a logger's jitter is accepted), a
  sample time other than the expected one when ``sample_time`` is given;
* values whose magnitude shows a unit other than SI (pressures in bar, kPa or MPa,
  positions in mm): checked for each output that measures a state with a
  ``range`` (see :func:`fdigen.sim.log_units.check_units`).
"""

from __future__ import annotations

import codecs
import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fdigen.errors import LogError
from fdigen.files.atomic import write_text
from fdigen.files.bounded import read_bytes
from fdigen.model.model import Model
from fdigen.sim.log_fields import numbers_of_rows as _numbers
from fdigen.sim.log_time import TIME_UNITS, check_time as _check_time, grid_step
from fdigen.sim.log_tables import (HDF5_SIGNATURE, MAX_VALUES, hdf5_units, read_columns,
                                   table_data, table_format)
from fdigen.sim.log_units import check_units, check_units_row, is_units_row

@dataclass(frozen=True)
class Log:
    """A measured log: time, inputs (K, m) and outputs (K, p) in the model's order.

    Attributes
    ----------
    path : str
    t : numpy.ndarray
        Time [s], shape (K,), strictly increasing, uniform.
    u : numpy.ndarray
        Inputs, shape (K, m), in the order of ``model.inputs``.
    y : numpy.ndarray
        Measured outputs, shape (K, p), in the order of ``model.outputs``.
    extra : dict of str to numpy.ndarray
        Numeric columns the model does not need (e.g. ``xref``), unchecked.
    sample_time : float
        The median sample interval [s].
    missing : dict of str to int
        Missing samples per column (``missing="keep"``: left NaN; ``"fill"``:
        interpolated), dropped rows put back counted under ``"rows"``, rows a logger
        wrote twice (dropped) under ``"duplicates"``.
    """

    path: str
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    extra: dict
    sample_time: float
    missing: dict = field(default_factory=dict)

    def missing_note(self) -> str | None:
        """One sentence on the missing samples, or ``None``."""
        if not self.missing:
            return None
        rows = self.missing.get("rows", 0)
        dup = self.missing.get("duplicates", 0)
        cols = {k: v for k, v in self.missing.items() if k not in ("rows", "duplicates")}
        parts = []
        if cols:
            parts.append("missing samples " + ", ".join(f"{k} {v}" for k, v in cols.items())
                         + (f" ({rows} dropped rows put back)" if rows else ""))
        if dup:
            parts.append(f"{dup} duplicated rows (a row written twice, stamp and values) "
                         "dropped")
        return f"{self.path}: " + "; ".join(parts) if parts else None


def _decode(path: Path, raw: bytes) -> str:
    """The file's text: UTF-8 (BOM optional) or UTF-16 with a BOM."""
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        encoding = "utf-16"
    else:
        encoding = "utf-8-sig"
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as exc:
        row = raw.count(b"\n", 0, exc.start) + 1
        raise LogError(f"{path}, row {row}: not UTF-8 text (byte {raw[exc.start]:#04x} "
                       f"at offset {exc.start}); logs are plain UTF-8 CSV") from None


def _blank(row: list[str]) -> bool:
    return all(not c.strip() for c in row)


def _lines(text: str):
    """The lines of ``text`` one at a time, each with its line break (CR, LF or CRLF):
    no copy of the whole text (``io.StringIO`` holds 4 bytes per character)."""
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    start = 0
    while start < len(text):
        end = text.find("\n", start)
        end = len(text) if end < 0 else end + 1
        yield text[start:end]
        start = end


def _rows(path: Path, text: str, need, extra_columns
          ) -> tuple[list[str], int, list[str], list[list[str]], list[int], dict]:
    """Header, its row number, the names of the columns kept (``need`` then the extras
    asked for), the data rows reduced to those columns (blank rows skipped) and their row
    numbers, and the row of units under the header if there is one (``{"row", "units"}``,
    else empty). The rows are read one at a time and only the kept fields stay in memory: a
    log with many unused columns costs what its used columns cost."""
    nul = text.find("\x00")
    if nul >= 0:
        row = len(io.StringIO(text[:nul], newline=None).read().split("\n"))
        raise LogError(f"{path}, row {row}: NUL character (a binary file?); logs are plain "
                       "UTF-8 CSV")
    reader = csv.reader(_lines(text))
    header, header_row, rows, numbers, keep, names = None, 0, [], [], [], []
    units = None
    try:
        for row in reader:
            if _blank(row):
                continue
            if header is not None and units is None and not rows:
                units = {}
                if is_units_row(row, len(header)):
                    # a logger's row of units under the header ('s,%,V,A'): checked
                    # against the model's (log_units.check_units_row), not data
                    units = {"row": reader.line_num,
                             "units": {h: f.strip() for h, f in zip(header, row)}}
                    continue
            if header is None:
                header, header_row = [h.strip() for h in row], reader.line_num
                _check_header(f"{path}, row {header_row}", header, need)
                names = list(need) + [h for h in dict.fromkeys(header) if h not in need
                                      and (extra_columns == "all" or h in extra_columns)]
                keep = [header.index(h) for h in names]
                continue
            if len(row) != len(header):
                raise LogError(f"{path}, row {reader.line_num}: {len(row)} fields, the header "
                               f"(row {header_row}) has {len(header)}")
            rows.append([row[i] for i in keep])
            numbers.append(reader.line_num)
    except csv.Error as exc:
        raise LogError(f"{path}, row {max(reader.line_num, 1)}: malformed CSV ({exc})") from None
    if header is None:
        raise LogError(f"{path}: empty file (expected a header row naming the columns)")
    return header, header_row, names, rows, numbers, units or {}


def _check_header(where: str, header: list[str], need) -> None:
    """Every required column once; ``where`` locates the header in messages."""
    missing = [c for c in need if c not in header]
    if missing:
        names = ", ".join(repr(h[:20]) for h in header[:12])
        hint = ""
        if len(header) == 1 and any(s in header[0] for s in ";\t"):
            hint = "; the separator looks like ';' or a tab: logs are comma separated"
        else:
            # a unit written into the header ('t [s]', 'L1 (cm)'): names only
            stem = {c: h for c in missing for h in header
                    if h.split("[")[0].split("(")[0].strip() == c and h != c}
            if stem:
                hint = ("; a header names the columns only, units are the model's: "
                        + ", ".join(f"{h!r} -> {c!r}" for c, h in stem.items()))
        raise LogError(f"{where}: missing column "
                       + ", ".join(repr(c) for c in missing)
                       + f" (header has {names}){hint}")
    for c in need:
        if header.count(c) > 1:
            raise LogError(f"{where}: column {c!r} appears twice in the header")


#: Largest log read into memory (bytes): about 4e6 rows of the rig format; a larger log is
#: refused with a clear message (split it, or run the C core's ``_run`` on chunks).
MAX_LOG_BYTES = 256 * 1024 * 1024


def read_log(path: str | Path, model: Model, sample_time: float | None = None,
             max_bytes: int | None = None, extra_columns=(), missing: str = "refuse",
             nominal_sample_time: float | None = None) -> Log:
    """Read a log for ``model``.

    Parameters
    ----------
    path : str or Path
        The CSV file (rig format, see the module docstring for what is accepted), or a
        MAT (v5, v7.3), HDF5 or Parquet file with the same columns
        (:mod:`fdigen.sim.log_tables`).
    model : Model
        Says which columns are needed: ``t``, each input's and each output's ``column``.
    sample_time : float, optional
        The sample time the caller needs (an FDI design's); ``None``: not checked.
    max_bytes : int, optional
        Size limit [default :data:`MAX_LOG_BYTES`].
    extra_columns : sequence of str or "all"
        Columns the model does not need to keep (when numeric) in :attr:`Log.extra`;
        ``"all"``: every one. Memory is proportional to the columns kept, not to the
        columns of the file.
    missing : {"refuse", "keep", "fill"}
        Missing samples (an empty field or ``nan`` outside the time column, a dropped
        row, put back as a row of NaN): refused; or gaps of at most
        :data:`~fdigen.sim.log_gaps.MAX_FILL` samples interpolated (a logger's dropped
        samples, which the controller saw) and longer ones kept as NaN (``"keep"``: the
        FDI core runs them as a dead sensor) or refused (``"fill"``; see
        :mod:`fdigen.sim.log_gaps`).
    nominal_sample_time : float, optional
        The model's sample time (its ``[fdi] sample_time``, anything else ignored) where
        the caller takes the log's own (``discover``, ``commission``): a log sampled a time
        unit's factor slower (1000x: the time column in ms) is refused with that advice.

    Returns
    -------
    Log

    Raises
    ------
    LogError
        Unreadable or empty file, malformed CSV, missing column, text in a number field,
        NaN or Inf, header only, duplicated sample, time not strictly increasing or not
        uniform, a sample time other than ``sample_time``, or values whose magnitude
        shows a wrong unit (bar, kPa, mm instead of Pa and m).
    """
    if missing not in ("refuse", "keep", "fill"):
        raise ValueError(f"missing={missing!r}")
    path = Path(path)
    need = ["t"] + [s.column for s in model.inputs] + [o.column for o in model.outputs]
    need = list(dict.fromkeys(need))
    limit = MAX_LOG_BYTES if max_bytes is None else int(max_bytes)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise LogError(f"{path}: cannot read log ({exc.strerror or exc})") from None
    if size > limit:
        raise LogError(f"{path}: log is {size / 2**20:.1f} MiB, more than the "
                       f"{limit / 2**20:.0f} MiB read into memory at once (about "
                       f"{limit // 64:.3g} rows); split it into parts")
    raw = read_bytes(path, limit, what="log", error=LogError)   # regular files only
    if table_format(path) is not None:       # MAT, HDF5, Parquet: rows are samples
        columns = read_columns(path, raw)
        units = hdf5_units(raw) if raw[512:520] == HDF5_SIGNATURE or table_format(
            path) == "hdf5" else {}
        del raw
        _check_header(str(path), [name for name, _ in columns], need)
        data, extra, numbers = table_data(path, columns, need, allow_nan=missing != "refuse")
        if units:       # a logger's units attributes, as a CSV log's row of units
            scale = check_units_row(path, model, "datasets", units, TIME_UNITS,
                                    source="a dataset's units attribute")
            data[:, need.index("t")] *= scale
        extra = {k: v for k, v in extra.items()
                 if extra_columns == "all" or k in extra_columns}
    else:
        text = _decode(path, raw)
        del raw
        lines = text.count("\n") + 1
        if lines * len(need) > MAX_VALUES:
            # 255 MiB of "0,0,0,0" rows (33 million) took 156 s and 7.9 GB before their
            # error (attack round 13): the same bound as a MAT, HDF5 or Parquet log's
            raise LogError(f"{path}: {lines} rows of the {len(need)} columns the model reads "
                           f"are more than the {MAX_VALUES} values read into memory at once "
                           f"(at most {MAX_VALUES // len(need)} rows); split it into parts")
        header, header_row, names, rows, numbers, units = _rows(path, text, need,
                                                                extra_columns)
        del text
        time_scale = 1.0
        if units:
            time_scale = check_units_row(path, model, units["row"], units["units"],
                                         TIME_UNITS)
        if not rows:
            raise LogError(f"{path}, row {header_row}: header only; a log needs at least "
                           "two samples")
        if len(rows) < 2:
            raise LogError(f"{path}, row {numbers[0]}: a single sample; a log needs at "
                           "least two")
        data, extra = _numbers(path, names, rows, numbers, need,
                               allow_nan=missing != "refuse")
        if time_scale != 1.0:           # a logger that stamps in ms (its row of units)
            k = need.index("t")
            with np.errstate(all="ignore"):
                scaled = data[:, k] * time_scale
            over = np.flatnonzero(np.isfinite(data[:, k]) & ~np.isfinite(scaled))
            if over.size:
                row = int(over[0])
                raise LogError(f"{path}, row {numbers[row]}, column 't': "
                               f"{float(data[row, k])!r} overflows in seconds (its row of "
                               "units converts the time column)")
            data[:, k] = scaled
    col = {name: j for j, name in enumerate(need)}
    counts = {}
    if missing != "refuse":
        # a logger that wrote a row twice (every column the same, its stamp too): the copy
        # is dropped and counted (a user's hot-water rig logger; a repeated stamp with
        # other values is still refused: which row is the sample?)
        same = np.flatnonzero(np.all((data[1:] == data[:-1])
                                     | (np.isnan(data[1:]) & np.isnan(data[:-1])), axis=1))
        if same.size:
            keep = np.ones(len(data), dtype=bool)
            keep[same + 1] = False
            data = data[keep]
            extra = {k: np.asarray(v)[keep] if len(v) == len(keep) else v
                     for k, v in extra.items()}
            numbers = [n for n, k in zip(numbers, keep) if k]
            counts["duplicates"] = int(same.size)
            if len(data) < 2:     # every row the same (attack round 9: "sample time nan")
                raise LogError(f"{path}: every row repeats the first ({same.size} "
                               "duplicated rows dropped): a single sample; a log needs at "
                               "least two")
        from fdigen.sim.log_gaps import insert_missing_rows

        dt0 = grid_step(data[:, col["t"]])        # (a median misreads alternating jitter)
        if math.isfinite(dt0) and dt0 > 0:
            # the kept extra columns (a reference) get the same NaN rows
            names = list(extra)
            both = np.column_stack([data, *(extra[n] for n in names)]) if names else data
            numbers = list(numbers)
            both, added = insert_missing_rows(data[:, col["t"]], both, dt0, col["t"],
                                              path, numbers=numbers)
            if added:
                data = both[:, :len(need)]
                extra = {n: both[:, len(need) + k] for k, n in enumerate(names)}
                counts["rows"] = added
    t = data[:, col["t"]]
    try:
        nominal = float(nominal_sample_time) if nominal_sample_time is not None else None
    except (TypeError, ValueError):     # the design says what is wrong with it
        nominal = None
    dt = _check_time(path, t, data, numbers, sample_time,
                     nominal if nominal and math.isfinite(nominal) and nominal > 0 else None)
    if missing != "refuse":
        nan = np.isnan(data).sum(axis=0)
        counts.update({name: int(nan[j]) for name, j in col.items() if nan[j]})
        if any(nan):
            from fdigen.sim.log_gaps import fill_short_gaps

            fill_short_gaps(path, t, data, need,
                            longer="refuse" if missing == "fill" else "keep")
    u = data[:, [col[s.column] for s in model.inputs]]
    y = data[:, [col[o.column] for o in model.outputs]]
    check_units(path, model, y)
    return Log(str(path), t, u, y, extra, dt, counts)


def write_log(path: str | Path, columns: dict, precision: int = 9) -> None:
    """Write a log (rig format) from a mapping column name -> 1-D array, ``t`` first."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    buf = io.StringIO(newline="")
    buf.write(",".join(names) + "\n")
    np.savetxt(buf, data, delimiter=",", fmt=f"%.{precision}g")
    write_text(path, buf.getvalue())   # atomic: an existing log is replaced whole or kept

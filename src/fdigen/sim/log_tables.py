"""Logs as binary tables: MAT files (v5 and v7.3) and Parquet, read into named columns.

:func:`fdigen.sim.log.read_log` reads a CSV log as text; a log whose name ends in
``.mat``, ``.parquet``/``.pq`` or ``.h5``/``.hdf5`` is read here into ``(name, values)``
pairs, then checked by the same code as a CSV (same column mapping, same errors for
missing columns, NaN, time that does not increase...). In these formats a *row* is a
sample, counted from 1.

* **MAT v5** (MATLAB ``save``, ``save -v7``; :func:`scipy.io.loadmat`) and
  **MAT v7.3** (HDF5 with a MATLAB header; :mod:`h5py`): one vector per column, either as
  separate variables (``t``, ``u``, ``x``...) or as the fields of one struct
  (``log.t``, ``log.u``...). Row or column vectors, ``double`` or any numeric class.
* **HDF5** (``.h5``/``.hdf5``): the same layout, datasets at the top or in one group.
* **Parquet** (:mod:`pyarrow`): one column per signal, numeric types.

Bounded reads: the file is read with the same size limit as a CSV log (the caller passes
the bytes), and the declared sizes (MAT variable shapes, HDF5 dataset shapes, Parquet
row counts) are checked against :data:`MAX_VALUES` before their data are read.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from fdigen.errors import LogError
from fdigen.sim.log_fields import nonfinite_note

#: Log formats by file suffix (anything else is read as CSV text).
TABLE_FORMATS = {".mat": "mat", ".parquet": "parquet", ".pq": "parquet",
                 ".h5": "hdf5", ".hdf5": "hdf5"}

#: Most values (all columns together) a table log may declare: 32 Mi doubles, the memory
#: of the largest CSV log :func:`fdigen.sim.log.read_log` reads.
MAX_VALUES = 32 * 1024 * 1024

#: The HDF5 signature, at offset 512 of a MAT v7.3 file (after MATLAB's user block).
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def table_format(path: str | Path) -> str | None:
    """``"mat"``, ``"parquet"``, ``"hdf5"`` by the file suffix, ``None`` for CSV."""
    return TABLE_FORMATS.get(Path(path).suffix.lower())


def _check_size(path, declared: int) -> None:
    if declared > MAX_VALUES:
        raise LogError(f"{path}: log declares {declared} values, more than the {MAX_VALUES} "
                       "read into memory at once; split it into parts")


def _vector(value) -> np.ndarray | None:
    """A numeric 1-D array from a MAT/HDF5 value (row or column vector), else ``None``."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf" or arr.ndim > 2 or (arr.ndim == 2 and min(arr.shape) > 1):
        return None
    return arr.reshape(-1).astype(float)


#: MAT classes whose variables can be a log column (whosmat's third field).
_MAT_NUMERIC = {"double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32",
                "int64", "uint64", "logical"}


def _is_vector(shape) -> bool:
    return len(shape) <= 2 and (len(shape) < 2 or min(shape) <= 1)


def mat_v5_expanded_bytes(path, raw: bytes, cap: int) -> int:
    """The bytes the top-level data elements of a MAT v5 file hold once decompressed,
    decompressing each ``miCOMPRESSED`` element at most up to ``cap`` bytes in all: a
    1.5 MB file of three compressed 8000x8000 zero matrices in a cell took 1.8 GB to read,
    and a struct log's unused field 0.9 GB, while the shapes ``whosmat`` declares (1x3,
    1x1) looked small (attack round 8). Refuses (:class:`LogError`) past ``cap``."""
    import struct
    import zlib

    end = "<" if raw[126:128] == b"IM" else ">"
    pos, total = 128, 0
    while pos + 8 <= len(raw):
        dtype, nbytes = struct.unpack(end + "II", raw[pos:pos + 8])
        if dtype >> 16:                      # a small data element: 4 bytes in the tag
            pos += 8
            continue
        if dtype == 15:                      # miCOMPRESSED
            d, pending = zlib.decompressobj(), raw[pos + 8:pos + 8 + nbytes]
            try:        # counted 1 MiB at a time: nothing of it is kept
                while pending and total <= cap:
                    total += len(d.decompress(pending, 1 << 20))
                    pending = d.unconsumed_tail
            except zlib.error as exc:
                raise LogError(f"{path}: not a readable MAT file (compressed variable: "
                               f"{exc})") from None
            pos += 8 + nbytes
        else:
            total += nbytes
            pos += 8 + nbytes + (-nbytes) % 8
        if total > cap:
            raise LogError(f"{path}: its variables hold more than {cap // 8} values once "
                           "decompressed, the most a log may read into memory at once (a "
                           "log holds its columns, nothing else); save only the columns, "
                           "or split it into parts")
    return total


def _mat_v5(path, raw: bytes) -> list[tuple[str, np.ndarray | None]]:
    import scipy.io

    if raw[126:128] not in (b"IM", b"MI"):
        # a MAT v4 file (no 128-byte header) was read by the v5 walker as "more than 33554432
        # values once decompressed"
        raise LogError(f"{path}: not a MAT v5/v7 or v7.3 file (a MAT v4 file, or another "
                       "format); save it with save -v7 or -v7.3")
    try:
        mat_v5_expanded_bytes(path, raw, 8 * MAX_VALUES)
        declared = scipy.io.whosmat(io.BytesIO(raw))
        names = [name for name, _, _ in declared]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:          # scipy keeps the last silently; CSV and Parquet refuse it
            raise LogError(f"{path}: variable {twice[0]!r} appears twice: which one is the "
                           "column is not knowable; save each column once")
        # a column is a numeric vector; a cell, a matrix, text are never read (one struct
        # is the documented layout of a log: its fields are the columns)
        wanted = [name for name, shape, cls in declared
                  if (cls in _MAT_NUMERIC and _is_vector(shape))
                  or (cls == "struct" and len(declared) == 1)]
        _check_size(path, sum(int(np.prod(shape)) for name, shape, _ in declared
                              if name in wanted))
        data = scipy.io.loadmat(io.BytesIO(raw), squeeze_me=False, struct_as_record=True,
                                chars_as_strings=True, variable_names=wanted) if wanted else {}
    except LogError:
        raise
    except Exception as exc:    # scipy raises ValueError, TypeError, OSError... on garbage
        raise LogError(f"{path}: not a readable MAT file ({type(exc).__name__}: "
                       f"{str(exc)[:200]})") from None
    variables = [(k, v) for k, v in data.items() if not k.startswith("__")]
    variables += [(name, None) for name, _, _ in declared if name not in data]
    structs = [(k, v) for k, v in variables if isinstance(v, np.ndarray)
               and v.dtype.names and v.size == 1]
    if len(structs) == 1 and len(variables) == 1:
        record = structs[0][1].reshape(-1)[0]
        return [(name, _vector(record[name])) for name in record.dtype.names]
    return [(k, _vector(v) if isinstance(v, np.ndarray) else None) for k, v in variables]


def _hdf5(path, raw: bytes) -> list[tuple[str, np.ndarray | None]]:
    import h5py

    try:
        with h5py.File(io.BytesIO(raw), "r") as f:
            _check_links(path, f, h5py)
            items = [(k, f[k]) for k in f.keys() if not k.startswith("#")]   # #refs#
            groups = [(k, v) for k, v in items if isinstance(v, h5py.Group)]
            if len(groups) == 1 and len(items) == 1:
                _check_links(path, groups[0][1], h5py)
                items = [(k, groups[0][1][k]) for k in groups[0][1].keys()]
            datasets = [(k, v) for k, v in items if isinstance(v, h5py.Dataset)]
            for k, v in datasets:
                # data stored outside the log (another file, a FIFO, /dev/zero) or mapped
                # from other files: never read (security.md: a log is one regular file)
                if v.external or v.is_virtual:
                    raise LogError(f"{path}: dataset {k!r} keeps its data outside the log "
                                   f"({'external storage' if v.external else 'a virtual dataset'}"
                                   "): fdigen reads a log's own bytes only; save the data "
                                   "into the file")
            # a column is a numeric vector of plain numbers: a dataset of strings, of
            # sub-arrays, a matrix is never read (10 strings of 200 MB declared 10
            # values, attack round 8)
            columns = {k for k, v in datasets
                       if v.dtype.kind in "biuf" and v.dtype.shape == () and
                       _is_vector(v.shape) and
                       v.attrs.get("MATLAB_class", b"double") not in (b"char", "char")}
            _check_size(path, sum(int(v.size) for k, v in datasets if k in columns))
            return [(k, _vector(v[()]) if k in columns else None) for k, v in items]
    except LogError:
        raise
    except Exception as exc:    # OSError for anything that is not HDF5
        raise LogError(f"{path}: not a readable HDF5/MAT v7.3 file ({type(exc).__name__}: "
                       f"{str(exc)[:200]})") from None


def hdf5_units(raw: bytes) -> dict:
    """Column -> the ``units`` (or ``unit``) attribute of an HDF5 log's datasets that have
    one (a logger's metadata): checked like a CSV log's row of units. A current logged in
    mA under ``units="mA"`` was read as A, and a healthy log ended in ``safety_stop``,
    where the same data as CSV with its units row was refused (attack round 13)."""
    import h5py

    out = {}
    with h5py.File(io.BytesIO(raw), "r") as f:
        items = [(k, f[k]) for k in f.keys() if not k.startswith("#")]
        groups = [v for _, v in items if isinstance(v, h5py.Group)]
        if len(groups) == 1 and len(items) == 1:
            items = [(k, groups[0][k]) for k in groups[0].keys()]
        for k, v in items:
            if not isinstance(v, h5py.Dataset):
                continue
            unit = v.attrs.get("units", v.attrs.get("unit"))
            if isinstance(unit, np.ndarray) and unit.size == 1:
                unit = unit.reshape(-1)[0]
            if isinstance(unit, bytes):
                unit = unit.decode("utf-8", "replace")
            if isinstance(unit, str) and unit.strip():
                out[k] = unit
    return out


def _check_links(path, group, h5py) -> None:
    """Refuse links of ``group`` that lead outside it (external and soft links)."""
    for k in group.keys():
        link = group.get(k, getlink=True)
        if isinstance(link, (h5py.ExternalLink, h5py.SoftLink)):
            kind = "an external link" if isinstance(link, h5py.ExternalLink) else "a soft link"
            raise LogError(f"{path}: {k!r} is {kind}: fdigen reads a log's own datasets "
                           "only; save the data into the file")


def _parquet(path, raw: bytes) -> list[tuple[str, np.ndarray | None]]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        pf = pq.ParquetFile(pa.BufferReader(raw))
        schema = pf.schema_arrow
        # only columns of plain numbers are read: a list column holding 1.5e8 values in
        # one row counted as one (attack round 8)
        numeric = [f.name for f in schema
                   if pa.types.is_integer(f.type) or pa.types.is_floating(f.type)]
        meta = pf.metadata
        _check_size(path, int(meta.num_rows) * len(numeric))
        groups = [meta.row_group(i).num_rows for i in range(meta.num_row_groups)]
        if sum(groups) != meta.num_rows:
            raise LogError(f"{path}: its footer declares {meta.num_rows} rows, its row "
                           f"groups {sum(groups)}: not a consistent Parquet file")
        table = _bounded_parquet(path, pf, numeric, int(meta.num_rows))
    except LogError:
        raise
    except Exception as exc:    # ArrowInvalid, OSError... on garbage
        raise LogError(f"{path}: not a readable Parquet file ({type(exc).__name__}: "
                       f"{str(exc)[:200]})") from None
    values = {name: column.to_numpy(zero_copy_only=False).astype(float)
              for name, column in zip(table.column_names, table.columns)}
    return [(f.name, values.get(f.name)) for f in schema]


#: Rows :func:`_bounded_parquet` decodes at a time.
PARQUET_BATCH = 1 << 16


def _bounded_parquet(path, pf, columns: list[str], declared: int):
    """The ``columns`` of a Parquet file, decoded a batch at a time and refused as soon
    as they hold more rows than the footer ``declared``: a footer rewritten to declare 1
    row over 4 x 4e7 constant doubles (697 kB) passed the size check and was read at
    6.4 GB (attack round 13)."""
    import pyarrow as pa

    batches, rows = [], 0
    for batch in pf.iter_batches(batch_size=PARQUET_BATCH, columns=columns):
        rows += batch.num_rows
        if rows > declared:
            raise LogError(f"{path}: holds more rows than its footer declares ({declared}): "
                           "not a consistent Parquet file")
        batches.append(batch)
    if rows != declared:
        raise LogError(f"{path}: holds {rows} rows, its footer declares {declared}: not a "
                       "consistent Parquet file")
    if not batches:
        return pa.table({c: pa.array([], pa.float64()) for c in columns})
    return pa.Table.from_batches(batches)


def read_columns(path: str | Path, raw: bytes) -> list[tuple[str, np.ndarray | None]]:
    """The named columns of a MAT, HDF5 or Parquet log, in file order.

    Parameters
    ----------
    path : str or Path
        The log's name (its suffix gives the format; used in messages).
    raw : bytes
        The file's content (read with the caller's size limit).

    Returns
    -------
    list of (str, numpy.ndarray or None)
        Each column's values as floats, ``None`` for a column that is not a numeric vector
        (text, a matrix, a nested struct).

    Raises
    ------
    LogError
        A file that is not of its suffix's format, or declares more than
        :data:`MAX_VALUES` values.
    """
    kind = table_format(path)
    if kind == "parquet":
        return _parquet(path, raw)
    if kind == "hdf5" or raw[512:520] == HDF5_SIGNATURE:     # HDF5 or MAT v7.3
        return _hdf5(path, raw)
    return _mat_v5(path, raw)


def table_data(path, columns: list[tuple[str, np.ndarray | None]], need: list[str],
               allow_nan: bool = False) -> tuple[np.ndarray, dict, list[int]]:
    """The required columns as a (K, len(need)) array (checked), numeric extras and the
    row (sample) numbers, with the messages of a CSV log's checks (``allow_nan``: NaN
    outside the time column is a missing sample).

    Raises
    ------
    LogError
        A required column that is not numeric, columns of different lengths, fewer than
        two samples, NaN or Inf in a required column (row and column named).
    """
    values = dict(columns)
    for name in need:
        if values[name] is None:
            raise LogError(f"{path}, column {name!r}: not a numeric vector (a log column "
                           "holds one number per sample)")
    lengths = {name: len(values[name]) for name in need}
    k = lengths["t"]
    for name, n in lengths.items():
        if n != k:
            raise LogError(f"{path}, column {name!r}: {n} samples, column 't' has {k}")
    if k == 0:
        raise LogError(f"{path}: no samples; a log needs at least two")
    if k == 1:
        raise LogError(f"{path}, row 1: a single sample; a log needs at least two")
    data = np.column_stack([values[name] for name in need])
    nan_ok = np.isnan(data) & np.array([allow_nan and n != "t" for n in need])[None, :]
    bad = np.argwhere(~np.isfinite(data) & ~nan_ok)
    if bad.size:
        row, j = (int(v) for v in bad[np.lexsort((bad[:, 1], bad[:, 0]))][0])
        raise LogError(f"{path}, row {row + 1}, column {need[j]!r}: value is "
                       f"{data[row, j]} " + nonfinite_note(allow_nan and need[j] != "t"))
    extra = {name: v for name, v in columns
             if name not in need and v is not None and len(v) == k}
    return data, extra, list(range(1, k + 1))

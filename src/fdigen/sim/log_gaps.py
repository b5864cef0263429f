"""Missing samples in a measured log: what a real logger produces and fdigen accepts.

A rig's logger drops samples (an empty field, ``nan``, or a whole row missing) and stamps
time with some jitter. The FDI core handles a missing measurement itself (it holds the
prediction and raises the sensor's validity flag ``nf_<y>``, latched: a dead sensor).
A few samples a logger dropped are not a dead sensor (the controller saw them), so every
reader fills short gaps; ``detect`` runs a longer outage as it is (the sensor's validity
flag rises), the data loop (``discover``, ``commission``), which needs numbers, refuses it.

* :func:`insert_missing_rows`: an interval that is a whole multiple ``m >= 2`` of the
  sample time (within :data:`GAP_TOL`) is ``m - 1`` dropped rows, put back as rows of
  NaN measurements at the missing times;
* :func:`fill_short_gaps`: runs of at most :data:`MAX_FILL` missing samples of a column
  are interpolated linearly between their neighbours; a longer run is refused, naming
  the column and the rows (a log with a long outage is two logs).
"""

from __future__ import annotations

import numpy as np

from fdigen.errors import LogError

#: Largest run of missing samples (per column) the data loop interpolates.
MAX_FILL = 5

#: Dropped rows put back in a log of few rows may reach this many (else ten times its
#: rows); never more than :data:`MAX_INSERTED` (``simulate``'s longest run is 1e7 samples).
MIN_INSERT_LIMIT = 100_000
MAX_INSERTED = 10_000_000

#: Largest distance of a timestamp from its point of the uniform grid, in sample times (a
#: logger's stamp jitter: a user's drive rig stamped its 2 ms samples within +-0.1 ms, and
#: a check of 5 % on each interval refused it, where two such stamps make an interval
#: 10 % off).
STAMP_TOL = 0.1

#: Relative distance of an interval from a whole multiple of the sample time that still
#: counts as dropped rows (two stamps, each up to :data:`STAMP_TOL` off its grid point).
GAP_TOL = 2 * STAMP_TOL


def max_inserted_rows(rows: int) -> int:
    """The most dropped rows a log of ``rows`` rows may have put back: ten times its own
    rows (at least :data:`MIN_INSERT_LIMIT`), never more than :data:`MAX_INSERTED`."""
    return min(max(10 * rows, MIN_INSERT_LIMIT), MAX_INSERTED)


def insert_missing_rows(t: np.ndarray, data: np.ndarray, dt: float,
                        time_column: int, path="the log",
                        numbers: list | None = None) -> tuple[np.ndarray, int]:
    """``data`` with a NaN row (its time filled in) for each dropped sample; returns the
    new array and the number of rows inserted. With ``numbers`` (the file's row number
    of each row) the list is extended in place the same way, a put-back row numbered as
    the file row before it: an error after the put-back names the file's row (a log with
    rows put back named row 11518 of a 5761-line file, attack round 9).

    Raises
    ------
    LogError
        When more rows would be put back than :func:`max_inserted_rows` allows: a 35 kB
        log whose time jumped by 3e6 s at 0.1 s made ``detect`` hold 3e7 samples (5.5 GB),
        and one of 1e8 s asked for 30 GiB.
    """
    dts = np.diff(t)
    with np.errstate(all="ignore"):
        ratio = dts / dt
    m = np.rint(np.where(np.isfinite(ratio) & (ratio < 2.0 ** 62), ratio, 0)).astype(np.int64)
    gaps = np.flatnonzero((m >= 2) & (np.abs(dts - m * dt) <= GAP_TOL * dt))
    if not gaps.size:
        return data, 0
    total = int(np.sum(m[gaps] - 1, dtype=np.float64))
    if total > max_inserted_rows(len(t)):
        k = int(gaps[np.argmax(m[gaps])])
        raise LogError(f"{path}, column 't': time jumps by {float(dts[k]):.6g} s after t = "
                       f"{float(t[k]):.6g} s; putting back the dropped rows would add "
                       f"{total:.3g} missing samples to a log of {len(t)} rows (at most "
                       f"{max_inserted_rows(len(t))}): an outage that long makes two "
                       "logs; cut it there")
    pieces, start, added = [], 0, 0
    renumbered = []
    for k in gaps:
        pieces.append(data[start:k + 1])
        rows = np.full((m[k] - 1, data.shape[1]), np.nan)
        rows[:, time_column] = t[k] + dt * np.arange(1, m[k]) * (dts[k] / (m[k] * dt))
        pieces.append(rows)
        if numbers is not None:
            renumbered += list(numbers[start:k + 1]) + [numbers[k]] * int(m[k] - 1)
        added += m[k] - 1
        start = k + 1
    pieces.append(data[start:])
    if numbers is not None:
        numbers[:] = renumbered + list(numbers[start:])
    return np.vstack(pieces), int(added)


def fill_short_gaps(path, t: np.ndarray, data: np.ndarray, names: list[str],
                    max_fill: int = MAX_FILL, longer: str = "refuse") -> dict:
    """Interpolate (in place) runs of at most ``max_fill`` NaN samples of each column;
    returns ``{column: samples filled}`` (a short run at either end of the log holds the
    nearest measured value). A longer run, or a column with no value at all, is refused,
    or with ``longer="keep"`` left NaN.

    Raises
    ------
    LogError
        A longer run (``longer="refuse"``), naming the column and the times.
    """
    filled = {}
    for j, name in enumerate(names):
        col = data[:, j]
        bad = np.isnan(col)
        if not bad.any():
            continue
        if bad.all():
            if longer == "keep":
                continue
            raise LogError(f"{path}, column {name!r}: holds no number (every sample is "
                           "missing)")
        edges = np.flatnonzero(np.diff(np.concatenate([[0], bad.view(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2]):
            # a short gap at either end holds the nearest measured value
            if b - a > max_fill and longer == "keep":
                bad[a:b] = False
            elif b - a > max_fill:
                raise LogError(f"{path}, column {name!r}: missing samples from t = "
                               f"{t[a]:.6g} s to {t[b - 1]:.6g} s ({b - a} samples in a "
                               f"row); the data loop interpolates gaps of at most "
                               f"{max_fill} samples: cut the log there (two logs), or "
                               "`fdigen detect`, which runs missing samples as they are")
        good = np.isfinite(col)
        if bad.any():
            col[bad] = np.interp(t[bad], t[good], col[good])
            filled[name] = int(bad.sum())
    return filled

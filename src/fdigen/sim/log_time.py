"""The time column of a measured log: strictly increasing, uniform within a logger's
jitter, in seconds.

* each interval within :data:`JITTER_TOL` of the median (two stamps, each up to
  :data:`~fdigen.sim.log_gaps.STAMP_TOL` of a sample time off its grid point), and every
  stamp within ``STAMP_TOL`` of a uniform grid fitted to all of them;
* a sample time other than the one the caller needs is refused, and one a time unit's
  factor off the model's (1000x: stamps in ms) with that advice;
* :data:`TIME_UNITS`: the units a log's row of units may give the time column in (it is
  converted to seconds).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fdigen.errors import LogError
from fdigen.sim.log_gaps import STAMP_TOL

#: Relative deviation of the median sample interval from the sample time a design needs.
UNIFORM_TOL = 0.01

#: Relative deviation of one sample interval from the median that is still "uniform": two
#: stamps, each up to :data:`~fdigen.sim.log_gaps.STAMP_TOL` of a sample time off its grid
#: point (a user's 2 Hz log with 1 ms of jitter was refused at 1 %, a drive rig's 2 ms
#: log stamped within +-0.1 ms at 5 %).
JITTER_TOL = 2 * STAMP_TOL

#: Time units a row of units may give the time column in, and their factor to seconds: the
#: time column is converted (a logger that stamps in ms), every other column is refused
#: in another scale than the model's.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "msec": 1e-3, "millisecond": 1e-3, "milliseconds": 1e-3,
              "us": 1e-6, "µs": 1e-6, "μs": 1e-6, "usec": 1e-6, "microseconds": 1e-6,
              "min": 60.0, "minutes": 60.0, "h": 3600.0, "hours": 3600.0}


def check_time(path: Path, t: np.ndarray, data: np.ndarray, numbers: list[int],
               sample_time: float | None, nominal_sample_time: float | None = None
               ) -> float:
    """Strictly increasing, uniform time; returns the median sample interval."""
    same = np.flatnonzero(np.all(data[1:] == data[:-1], axis=1))
    if same.size:
        k = int(same[0]) + 1
        raise LogError(f"{path}, row {numbers[k]}, column 't': duplicated sample (the row "
                       f"repeats row {numbers[k - 1]})")
    with np.errstate(all="ignore"):
        dts = np.diff(t)
    bad = np.flatnonzero(~(dts > 0))
    if bad.size:
        k = int(bad[0])
        raise LogError(f"{path}, row {numbers[k + 1]}, column 't': time does not increase "
                       f"({float(t[k])!r} then {float(t[k + 1])!r})")
    dt = float(np.median(dts))
    if not math.isfinite(dt) or dt <= 0.0:
        raise LogError(f"{path}, column 't': sample time {dt!r} s is not a positive number")
    grid = grid_step(t, dts)
    dt = grid if math.isfinite(grid) else dt
    off = np.flatnonzero(~(np.abs(dts - dt) <= JITTER_TOL * dt))
    if not off.size:
        _check_grid(path, t, dt, numbers)
    if off.size:
        k = int(off[0])
        ratio = float(dts[k] / dt)
        # never a 300-digit integer (a last time stamp of 1e300)
        count = f"{round(ratio) - 1}" if ratio < 1e12 else f"{ratio:.3g}"
        hint = (f": {count} dropped row{'s' if ratio >= 2.5 else ''}? `fdigen detect` runs "
                "a log with dropped rows and empty fields as missing samples, `discover` "
                "and `commission` interpolate gaps of a few samples" if ratio >= 1.5 else "")
        raise LogError(f"{path}, row {numbers[k + 1]}, column 't': non-uniform sample time "
                       f"(interval {dts[k]:.6g} s, sample time {dt:.6g} s){hint}")
    unit = _time_unit_off(dt, sample_time or nominal_sample_time,
                          Path(path).suffix.lower() in (".csv", ".txt", ""))
    if sample_time is not None and abs(dt - sample_time) > UNIFORM_TOL * sample_time:
        raise LogError(f"{path}, column 't': sample time {dt:.6g} s, the FDI design expects "
                       f"{sample_time:.6g} s" + (f"; {unit}" if unit else ""))
    if unit:
        # discover and commission take the log's own sample time: a log stamped in ms at
        # 2 ms read as 2 s samples of a plant whose design samples at 2 ms (a user's rig)
        raise LogError(f"{path}, column 't': sample time {dt:.6g} s, where the model's "
                       f"[fdi] sample_time is {nominal_sample_time:.6g} s; {unit}")
    return dt


def grid_step(t: np.ndarray, dts: np.ndarray | None = None) -> float:
    """The step of the uniform grid a log's stamps ``t`` lie on: the span over the whole
    steps it holds, each interval counted as the whole number of steps nearest to it
    (twice, from the median interval, then from that estimate; a dropped row is two).

    The median of the intervals is one of two lengths when a logger stamps every other
    sample late: a double-buffered logger at +-2 % read as 1.04 ms for 1 ms, and was
    refused. NaN when the stamps give none."""
    with np.errstate(all="ignore"):
        dts = np.diff(t) if dts is None else dts
        step = float(np.median(dts)) if len(dts) else math.nan
        for _ in range(2):
            if not (math.isfinite(step) and step > 0.0):
                return math.nan
            steps = np.rint(dts / step)
            steps = np.where(np.isfinite(steps) & (steps >= 1.0), steps, 1.0)
            step = float((t[-1] - t[0]) / np.sum(steps))
    return step if math.isfinite(step) and step > 0.0 else math.nan


def _time_unit_off(dt: float, expected: float | None, text: bool = True) -> str:
    """The advice when a log's sample time ``dt`` is a time unit's factor off the
    ``expected`` one (the time column in ms or us), else ``""``; a row of units is
    advised for a ``text`` (CSV) log only (a MAT or Parquet file has none)."""
    if not expected:
        return ""
    scale = {1e3: ("milliseconds", "ms"), 1e6: ("microseconds", "us")}
    unit = next((v for k, v in scale.items()
                 if abs(dt - k * expected) <= UNIFORM_TOL * k * expected), None)
    if unit is None:
        return ""
    if not text:
        return (f"the time column looks like {unit[0]}: time is in seconds (convert the "
                "variable 't')")
    return (f"the time column looks like {unit[0]}: time is in seconds, or a row of units "
            f"under the header gives it ({unit[1]!r} under 't') and fdigen converts it")


def _check_grid(path: Path, t: np.ndarray, dt: float, numbers: list[int]) -> None:
    """Every timestamp within :data:`~fdigen.sim.log_gaps.STAMP_TOL` sample times of a
    uniform grid :math:`t_k \\approx a + b k` fitted to the stamps by least squares: a
    logger's jitter, not a clock whose rate wanders (whose samples are not uniform)."""
    if len(t) < 3:
        return
    k = np.arange(len(t), dtype=float)
    b, a = np.polyfit(k, t - t[0], 1)
    off = np.abs(t - t[0] - (a + b * k))
    worst = int(np.argmax(off))
    if off[worst] > STAMP_TOL * dt:
        raise LogError(f"{path}, row {numbers[worst]}, column 't': non-uniform sample time "
                       f"(timestamp {float(t[worst]):.6g} s is {off[worst] / dt:.3g} sample "
                       f"times off the uniform grid of the log's stamps; a logger's jitter "
                       f"of up to {100 * STAMP_TOL:g} % of the sample time is accepted)")

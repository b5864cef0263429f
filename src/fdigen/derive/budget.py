"""Time budgets for symbolic steps: abort past the budget, never a silent long hang.

A symbolic derivation (an observable reduction with a leak term, a gcd of large
polynomials) can run for minutes on a model that is only a little bigger than the
built-in ones. A step run under :func:`time_budget` is interrupted when its budget of
*CPU time* is spent (``SIGVTALRM`` through ``setitimer(ITIMER_VIRTUAL)``: POSIX, main
thread; CPU time, so a machine shared with other jobs does not trip it early), and raises
:class:`BudgetExceeded`; the caller then falls back to a numeric construction and says
so. :class:`BudgetExceeded` derives from ``BaseException`` so that the broad
``except Exception`` of library code cannot swallow it. Where no alarm can be set (a
worker thread, another alarm already pending, no ``setitimer``), the step runs without a
budget.

The budget is ``FDIGEN_SYMBOLIC_BUDGET`` CPU seconds (default :data:`DEFAULT_BUDGET`; ``0``
or a negative value: no budget).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading

#: Default budget of one symbolic step [s].
DEFAULT_BUDGET = 60.0


class BudgetExceeded(BaseException):
    """A symbolic step ran past its time budget."""


def symbolic_budget() -> float | None:
    """The budget of one symbolic step [s] (``FDIGEN_SYMBOLIC_BUDGET``), None: unlimited."""
    raw = os.environ.get("FDIGEN_SYMBOLIC_BUDGET", "")
    try:
        value = float(raw) if raw.strip() else DEFAULT_BUDGET
    except ValueError:
        value = DEFAULT_BUDGET
    return value if value > 0 else None


def _can_alarm() -> bool:
    return (hasattr(signal, "setitimer")
            and threading.current_thread() is threading.main_thread()
            and signal.getitimer(signal.ITIMER_VIRTUAL)[0] == 0.0)


#: CPU seconds between repeated alarms once a budget has run out (see :func:`time_budget`).
REPEAT_S = 0.5


@contextlib.contextmanager
def time_budget(seconds: float | None, what: str = "symbolic step"):
    """Run the block with a time budget; raise :class:`BudgetExceeded` past it."""
    if seconds is None or not _can_alarm():
        yield
        return

    def _expired(signum, frame):
        raise BudgetExceeded(f"{what}: over its budget of {seconds:g} s")

    previous = signal.signal(signal.SIGVTALRM, _expired)
    # and again every REPEAT_S of CPU time after it: sympy catches exceptions inside
    # some of its algorithms (a fallback path), and an alarm raised there is swallowed;
    # a one-shot timer then never fired again and the step ran past its budget unbounded
    signal.setitimer(signal.ITIMER_VIRTUAL, float(seconds), min(float(seconds), REPEAT_S))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_VIRTUAL, 0.0)
        signal.signal(signal.SIGVTALRM, previous)


def _marks_dir():
    """``$FDIGEN_CACHE/over_budget`` (else ``~/.cache/fdigen/over_budget``), ours only."""
    from fdigen.files.cache_root import cache_root

    return cache_root() / "over_budget"


def known_over_budget(key: str) -> bool:
    """Whether the symbolic step ``key`` (a hex digest of everything it reads) ran past
    its budget before, in this or an earlier command: a user's ball screw spent its
    60 s budget again in every command (inspect, build, commission: two minutes each)
    for the numeric fallback it had already taken. A folder not ours is ignored."""
    folder = _marks_dir()
    try:
        return folder.stat().st_uid == os.getuid() and (folder / key).is_file()
    except OSError:
        return False


def mark_over_budget(key: str) -> None:
    """Remember that the step ``key`` ran past its budget (best effort: a cache that
    cannot be written only costs the budget again)."""
    from fdigen.files.atomic import write_text

    folder = _marks_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        if folder.stat().st_uid == os.getuid():
            write_text(folder / key, "")
    except OSError:
        pass


"""Pickles of sympy's ``Max`` and ``Min`` that load as they were stored.

Unpickling rebuilds ``Max(a, b, ...)`` through ``Max.__new__``, which compares every pair
of arguments (``_find_localzeros``: assumption queries on each difference). A design's
``Max`` terms are already reduced when it is pickled, so the rebuild repeats work whose
answer is known: 0.5-1.4 s per cached cylinder design after ``commission``, on every
command that reads it and on every Dask worker a campaign sends it to.

A stored ``Max`` is rebuilt with ``evaluate=False`` from its own arguments: the same
canonical, ordered argument set, hence the same expression (``srepr`` and hash equal; on
1062 cached designs of the test suite, 58.5 s of unpickling became 13.1 s).
"""

from __future__ import annotations

import copyreg

from sympy import Max, Min


def stored_max(*args):
    """``Max(*args)`` of arguments that were a ``Max``'s own (already reduced)."""
    return Max(*args, evaluate=False)


def stored_min(*args):
    """``Min(*args)`` of arguments that were a ``Min``'s own (already reduced)."""
    return Min(*args, evaluate=False)


def _reduce_max(expr):
    return stored_max, tuple(expr.args)


def _reduce_min(expr):
    return stored_min, tuple(expr.args)


def pickle_minmax_as_stored() -> None:
    """Register the reductions with :mod:`copyreg` (idempotent): called before a design is
    pickled (the design cache, a campaign's workers)."""
    copyreg.pickle(Max, _reduce_max)
    copyreg.pickle(Min, _reduce_min)

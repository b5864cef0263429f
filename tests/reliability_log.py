"""Shared by the reliability tests: one JSON line per check for docs/reliability.md."""

import functools
import json
import os


def record(area, test, kind, cases, result, details=""):
    """Append one JSON line to $FDIGEN_RELIABILITY_REPORT (no-op when unset)."""
    path = os.environ.get("FDIGEN_RELIABILITY_REPORT")
    if not path:
        return
    line = {"area": area, "test": test, "class": kind, "cases": cases,
            "result": result, "details": details}
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(line, sort_keys=True) + "\n")


def reporter(area):
    """``report(test, kind, cases, result, details="")`` for one area."""
    return functools.partial(record, area)

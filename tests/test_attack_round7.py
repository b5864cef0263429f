"""Attack round 7 (from the outside, on the newest inputs: rows of units, jitter,
``commission --validate``). The rows of units and the jitter are tested with the logs in
tests/test_log_gaps.py; the validation logs' refusals in tests/test_newuser35_data.py."""

from __future__ import annotations

import json
import shutil

import sympy as sp
from click.testing import CliRunner

from conftest import RIG
from fdigen.cli import main
from fdigen.model.expression import MAX_DEPTH, parse_expression


def test_a_flat_sum_is_one_level_and_real_nesting_is_still_refused():
    """A 70-term sum was refused as "nested deeper than 60 levels": the parser chains a
    sum to the left, and each link counted as a level."""
    h = sp.Symbol("h", real=True)
    total = " + ".join(f"{k}*h" for k in range(1, 2 * MAX_DEPTH))
    assert parse_expression(total, {"h": h}) == sum(range(1, 2 * MAX_DEPTH)) * h
    product = "*".join(["(h + 1)"] * (2 * MAX_DEPTH)) + " / 2 / 3"
    assert parse_expression(product, {"h": h}) == (h + 1) ** (2 * MAX_DEPTH) / 6
    nested = "h"
    for _ in range(MAX_DEPTH + 5):
        nested = f"({nested} + 1)*2"
    import pytest

    from fdigen.errors import ModelFileError

    with pytest.raises(ModelFileError, match=f"nested deeper than {MAX_DEPTH} levels"):
        parse_expression(nested, {"h": h})


def test_the_commissioning_log_is_no_validation_log(tmp_path):
    """`commission LOG --validate LOG` (the same file, a link to it, or a copy) reported
    the log "quiet": its thresholds clear it by construction."""
    base = RIG / "logs" / "fdi_healthy.csv"
    main_log = tmp_path / "main.csv"
    shutil.copy(base, main_log)
    (tmp_path / "link.csv").symlink_to(main_log)
    shutil.copy(base, tmp_path / "copy.csv")
    for other, says in (("main.csv", "the same data as the commissioning log"),
                        ("link.csv", "the same data as the commissioning log"),
                        ("copy.csv", "the same data as the commissioning log")):
        out = tmp_path / f"out_{other}"
        res = CliRunner().invoke(main, ["commission", str(main_log), "--validate",
                                        str(tmp_path / other), "--out", str(out), "--json"])
        assert res.exit_code == 2, res.output
        assert says in json.loads(res.stdout)["error"]["message"]
        assert not out.exists()
    other = RIG / "logs" / "commission_healthy2.csv"
    shutil.copy(other, tmp_path / "other.csv")
    twice = ["commission", str(base), "--validate", str(other), "--validate",
             str(tmp_path / "other.csv"), "--out", str(tmp_path / "o"), "--json"]
    res = CliRunner().invoke(main, twice)
    assert res.exit_code == 2
    assert f"the same data as --validate {other}" in json.loads(res.stdout)["error"][
        "message"]


def test_a_time_in_hours_that_overflows_in_seconds_is_named(tmp_path):
    """A time column in h whose values overflow when converted read "time does not
    increase (inf then inf)": the file holds finite numbers only."""
    import pytest

    from fdigen.errors import LogError
    from fdigen.model.model_file import load_model
    from fdigen.sim.log import read_log

    lines = (RIG / "logs" / "fdi_healthy.csv").read_text().splitlines()[:400]
    head = lines[0].split(",")
    units = ",".join("h" if c == "t" else "" for c in head)
    body = [",".join([repr(1e306 + k * 1e292)] + r.split(",")[1:])
            for k, r in enumerate(lines[1:])]
    path = tmp_path / "h.csv"
    path.write_text("\n".join([lines[0], units] + body) + "\n")
    with pytest.raises(LogError, match=r"row 3, column 't': 1e\+306 overflows in seconds"):
        read_log(path, load_model())


def test_a_temporary_file_a_killed_write_left_is_removed_by_the_next(tmp_path):
    """A discover killed (SIGKILL) while writing its figure left a 0-byte
    ``.discover.png.XXXXXXXX.png`` that no later run removed. The next write of the same
    file removes such leftovers when they are old; a younger one (a concurrent write's)
    and a user's file of a similar name stay."""
    import os
    import time

    from fdigen.files.atomic import STALE_SECONDS, atomic_path, write_text

    target = tmp_path / "discover.png"
    old = tmp_path / ".discover.png.a1b2c3d4.png"
    young = tmp_path / ".discover.png.zz99yy88.png"
    mine = tmp_path / ".discover.png.notes.png"
    other = tmp_path / ".report.json.a1b2c3d4.tmp"
    for p in (old, young, mine, other):
        p.write_bytes(b"")
    past = time.time() - 2 * STALE_SECONDS
    for p in (old, mine, other):
        os.utime(p, (past, past))
    with atomic_path(target) as tmp:
        tmp.write_bytes(b"png")
    assert target.read_bytes() == b"png"
    assert not old.exists() and young.exists() and mine.exists() and other.exists()
    text = tmp_path / "report.json"
    write_text(text, "{}")
    assert not other.exists() and text.read_text() == "{}"

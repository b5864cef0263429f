"""Every rig log through the default path of ``fdigen detect`` (text and ``--json``) and
``fdigen report -o x.html``: exit 0, valid output, the text and the JSON agree, and the
healthy logs of a rig that matches the datasheet (``fdi_healthy``, ``discrepancy_none``)
raise no flag.

The class of each ``fdi_*`` log is asserted by ``tests/test_design.py`` and
``tests/test_experiments.py``; discover and commission on every log by their own tests.
"""

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import RIG
from fdigen.cli import main

LOGS = sorted((RIG / "logs").glob("*.csv")) if (RIG / "logs").is_dir() else []
QUIET = {"fdi_healthy", "discrepancy_none"}


def cli(*args):
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exit_code == 0, (args, res.output, res.exception)
    assert "Traceback" not in res.output
    return res.output


@pytest.mark.skipif(not LOGS, reason="reference rig logs not available")
@pytest.mark.parametrize("log", LOGS, ids=[p.stem for p in LOGS])
def test_detect_and_report(log: Path, tmp_path):
    text = cli("detect", log)
    res = json.loads(cli("detect", log, "--json"))
    assert res["samples"] == 20000 and res["sample_time"] == pytest.approx(1e-3)
    d = res["diagnosis"]
    assert {"fault", "action", "t_isolated", "consistent_faults"} <= set(d)
    flags = [f["residual"] for f in res["flags"]]
    assert res["detected"] == bool(flags)
    # the text says what the JSON says
    last = text.strip().splitlines()
    diagnosis = next(line for line in last if line.startswith("diagnosis:"))
    if d["fault"] != "none":
        assert diagnosis.startswith(f"diagnosis: {d['fault']} at ") and d["action"] in diagnosis
    elif flags:
        assert "detected, not isolated" in diagnosis
        assert all(f in diagnosis for f in flags)
    else:
        assert "no flag raised" in diagnosis
    if log.stem in QUIET:
        assert flags == [] and d["fault"] == "none", res
    out = tmp_path / "x.html"
    msg = cli("report", log, "-o", out)
    assert out.is_file() and out.stat().st_size > 1000, msg
    page = out.read_text()
    assert page.lstrip().lower().startswith(("<!doctype html", "<html")) and "</html>" in page

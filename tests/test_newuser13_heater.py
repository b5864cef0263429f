"""A user's water heater (tests/data/newuser13, written from the README; logs from the
user's own simulator with a heat loss, a heater efficiency and a thermocouple lag the
model lacks): discover on a model whose declared residuals have no thresholds yet, and the
equation test's refusal of a log too short or too slowly sampled for it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser13"


def _copy(tmp_path, *names):
    for n in names:
        shutil.copy(DATA / n, tmp_path / n)


def test_discover_default_path_on_a_model_never_tuned(tmp_path, monkeypatch):
    """The model declares R1 and K1 and no [fdi.thresholds]: discover ended in exit 2
    ("missing thresholds for residuals R1, K1") after writing the augmented model, with or
    without --no-fdi. Now both designs read their thresholds from the log and the
    before/after residual comparison is reported."""
    _copy(tmp_path, "water_heater.toml", "heater_healthy.csv")
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, ["discover", "heater_healthy.csv", "--model",
                                    "water_heater.toml", "--out", "d", "--no-build",
                                    "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert info["effects"], info
    before, after = info["fdi_before"], info["fdi_after"]
    assert set(before) >= {"R1", "K1"} and set(after) >= {"R1", "K1"}
    # the augmented model explains more of the log: its parity residual shrinks
    assert after["R1"] < 0.5 * before["R1"]
    text = " ".join(info["warnings"])
    assert "no threshold for R1" in text and "without a threshold in the file" in text


def test_too_short_names_a_length_that_would_do(tmp_path, monkeypatch):
    """A 10-s log of 1190 s with 30-s windows (3 samples each): the message said it
    needed 'at least about 1155 s (this one is 1190 s)'. The length it names now follows
    from the windows this log could use, and it names the output-error loop."""
    _copy(tmp_path, "water_heater.toml", "heater_slow.csv")
    monkeypatch.chdir(tmp_path)
    for extra in (["--window", "30"], []):
        res = CliRunner().invoke(main, ["discover", "heater_slow.csv", "--model",
                                        "water_heater.toml", "--out", "d", *extra])
        assert res.exit_code == 2, res.output
        msg = " ".join(res.output.split())
        need = float(msg.split("at least about ")[1].split(" s")[0])
        have = float(msg.split("(this one is ")[1].split(" s")[0])
        assert need > 2 * have, msg
        assert "--method output-error" in msg
    assert "windows of at least 10 samples (`fdigen discover --window 100`)" in " ".join(
        CliRunner().invoke(main, ["discover", "heater_slow.csv", "--model",
                                  "water_heater.toml", "--out", "d", "--window", "30"]
                           ).output.split())

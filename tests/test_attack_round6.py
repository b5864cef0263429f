"""Attack round 6 (2026-11-28): an outside reviewer against the promises of bounded work,
clear errors and refusals before work. Each test reads the default path of a command.

* a 35 kB log whose time jumps by 3e6 s at 0.1 s: ``detect`` put back 3e7 dropped rows
  (5.5 GB), and 1e8 s asked for 30 GiB;
* a linear chain of 24 states with one sensor: ``inspect`` past 300 s enumerating 1.7e7
  subsets of states; a nonlinear chain of 12: 60-200 s and 1.5 GB in the output
  derivatives' expression graph;
* a balance ``yb/(c - ya)**2`` with ``c`` between the 41-point grid's points: a double
  pole inside the range passed the sign test;
* ``simulate --duration`` shorter than a sample: an internal error after a one-sample log
  was written;
* ``[fdi] refused = ""``: a refused design read as accepted;
* ``commission --out`` with the user's folder named like the model: refused after 37 s of
  work and written files.
"""

import json
import shutil
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "attack6"


def _healthy(tmp_path, name="healthy.csv", duration="60"):
    log = tmp_path / name
    res = CliRunner().invoke(main, ["simulate", "--model", str(DATA / "tank.toml"),
                                    "--duration", duration, "-o", str(log)])
    assert res.exit_code == 0, res.output
    return log


def test_a_time_jump_cannot_make_a_log_of_gigabytes(tmp_path, monkeypatch):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    log = _healthy(tmp_path)
    lines = log.read_text().splitlines()
    head, rows = lines[:1], lines[1:]
    jumped = tmp_path / "gap.csv"
    out = []
    for k, row in enumerate(rows):
        cells = row.split(",")
        if k >= len(rows) // 2:
            cells[0] = repr(float(cells[0]) + 3e6)
        out.append(",".join(cells))
    jumped.write_text("\n".join(head + out) + "\n")
    res = CliRunner().invoke(main, ["detect", "--model", str(DATA / "tank.toml"),
                                    str(jumped), "--json"])
    assert res.exit_code == 2, res.output
    err = json.loads(res.stdout)["error"]
    assert err["kind"] == "LogError" and "time jumps by 3e+06 s" in err["message"]
    assert "makes two logs" in err["message"]
    # a few dropped rows are still put back
    few = tmp_path / "few.csv"
    few.write_text("\n".join(head + rows[:100] + rows[103:]) + "\n")
    res = CliRunner().invoke(main, ["detect", "--model", str(DATA / "tank.toml"), str(few),
                                    "--json"])
    assert res.exit_code == 0, res.output


def test_long_chains_are_inspected_in_bounded_work(tmp_path, monkeypatch):
    """24 linear states with one sensor, 12 nonlinear ones: inspect ends (4-5 s each
    here) with its table; the subsets looked at and the series' size are bounded."""
    import fdigen.design.signatures as sig

    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    seen = []               # subsets looked at, per call of candidate_residuals
    real = sig.itertools.combinations

    def counted(items, size):
        if size == 1:       # each call starts with the single states
            seen.append(0)
        for c in real(items, size):
            seen[-1] += 1
            yield c

    monkeypatch.setattr(sig.itertools, "combinations", counted)
    for name in ("lin24", "trig12"):
        seen.clear()
        res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / f"{name}.toml"),
                                        "--json"])
        assert res.exit_code == 0, res.output
        assert "faults" in json.loads(res.stdout) or json.loads(res.stdout)
        assert seen and max(seen) <= sig.MAX_SUBSETS_EXAMINED + 30   # + one per size


def test_a_double_pole_between_grid_points_is_no_balance(monkeypatch, tmp_path):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model

    model = load_model(str(DATA / "balance_double_pole.toml"))
    design = cached_design(model)
    assert not any("blind to f" in str(e.get("description", "")) or
                   "(c - ya)" in str(e.get("expression", "")) for e in design.extra_residuals)
    assert all("c - ya" not in json.dumps(e, default=str) and "ya - c" not in
               json.dumps(e, default=str) for e in design.extra_residuals)


def test_a_run_shorter_than_ten_samples_is_a_usage_error_and_writes_nothing(tmp_path):
    out = tmp_path / "x.csv"
    for d in ("0.1", "1e-300"):
        res = CliRunner().invoke(main, ["simulate", "--model", str(DATA / "tank.toml"),
                                        "--duration", d, "-o", str(out)])
        assert res.exit_code == 2, res.output
        assert "--duration" in res.output and "10 samples" in res.output
    assert not out.exists() and not out.with_suffix(".json").exists()
    res = CliRunner().invoke(main, ["verify", "--model", str(DATA / "tank.toml"),
                                    "--duration", "0.05", "--json"])
    assert res.exit_code == 2
    assert json.loads(res.stdout)["error"]["kind"] == "BadParameter"


def test_an_empty_refusal_still_refuses(tmp_path, monkeypatch):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    model = tmp_path / "tank.toml"
    text = (DATA / "tank.toml").read_text().replace("[fdi]\n", '[fdi]\nrefused = ""\n', 1)
    model.write_text(text)
    log = _healthy(tmp_path, duration="10")
    res = CliRunner().invoke(main, ["detect", "--model", str(model), str(log), "--json"])
    assert res.exit_code == 0, res.output
    assert "(no reason given)" in json.loads(res.stdout)["design_refused"]


def test_commission_refuses_a_users_build_folder_before_any_work(tmp_path, monkeypatch):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    log = _healthy(tmp_path)
    mine = tmp_path / "out" / "tank"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("mine\n")
    res = CliRunner().invoke(main, ["commission", str(log), "--model",
                                    str(DATA / "tank.toml"), "--out", "out", "--json"])
    assert res.exit_code == 2, res.output
    assert "out/tank is not empty and has no .fdigen-stamp" in json.loads(res.stdout)[
        "error"]["message"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["tank"]
    assert (mine / "notes.txt").read_text() == "mine\n"

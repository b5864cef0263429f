"""Security and data safety, round 3 (issue 23): the files fdigen writes and the corners
between commands. Each numbered case of the issue is a test here (case 9, the generated
C's state validation, is in test_reliability_c.py); each records its class for
docs/reliability.md (scripts/reliability_report.py).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import tomllib
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main
from reliability_log import reporter

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "src" / "fdigen" / "models"
DATA = reporter("data safety")
CLI = reporter("command line")
MODEL = reporter("model files")
LOGS = reporter("logs")

#: Log file names that broke the model files fdigen wrote (cases 2 and 15).
EVIL_ORIGINS = ["h\n[faults.evil]\n#.csv", "run \U0001F600.csv",
                os.fsdecode(b"bad\xffbyte.csv"), "a\r\nb = 1\u2028[x].csv", 'q"uote\\.csv']


def _invoke(*args, **kw):
    return CliRunner().invoke(main, [str(a) for a in args], **kw)


def _env():
    return dict(os.environ, PYTHONPATH=str(ROOT / "src"))


# --- cases 1, 2, 15: model files fdigen writes parse back; names are escaped ------------


def test_commissioned_model_escapes_the_log_name(tmp_path):
    """A log's name enters the commissioned model's first-line comment escaped: newlines,
    emoji and non-UTF-8 bytes never add a table nor break the TOML."""
    from fdigen.commission.pipeline import commissioned_text
    from fdigen.files.model_write import write_model_text
    from fdigen.model.model_file import load_model

    text = (MODELS / "dc_motor.toml").read_text()
    for k, origin in enumerate(EVIL_ORIGINS):
        new = commissioned_text(text, ["Ra"], {"Rw": 3.5}, {"Rw": "3.5"}, origin, "note")
        doc = tomllib.loads(new)
        assert "evil" not in doc["faults"] and "x" not in doc
        assert new.split("\n", 1)[1].startswith(text.split("\n", 1)[0][:5])
        assert doc["parameters"]["Ra"]["uncertain"] is True
        path = write_model_text(tmp_path / f"m{k}.toml", new)
        assert load_model(path).name == "dc_motor"
    DATA("test_commissioned_model_escapes_the_log_name", "log name in a written model file",
         len(EVIL_ORIGINS), "pass", "newline/[table], emoji, non-UTF-8 byte, U+2028, quotes: "
         "one comment line, file parses back")


def test_augmented_model_escapes_the_log_name(cylinder):
    """discover's augmented model (descriptions carry the log's name) parses back for
    every hostile name (an emoji was written as a JSON surrogate pair: invalid TOML)."""
    from fdigen.discover import effects as fx
    from fdigen.discover.augment import augmented_text, check_augmented

    e = fx.get_effect("coulomb_friction", cylinder)
    text = (MODELS / "pneumatic_cylinder.toml").read_text()
    for origin in EVIL_ORIGINS:
        aug = augmented_text(text, cylinder, [e], {p.name: p.nominal for p in e.parameters},
                             {p.name: 0.1 * p.nominal for p in e.parameters}, origin=origin)
        doc = tomllib.loads(aug)
        assert "evil" not in doc["faults"] and "x" not in doc
        check_augmented(aug, cylinder, [e], "<test>")
    DATA("test_augmented_model_escapes_the_log_name", "log name in discover's model file",
         len(EVIL_ORIGINS), "pass", "descriptions and comment escaped, parses back")


def test_model_writes_are_atomic_and_checked(tmp_path, monkeypatch):
    """A model file fdigen writes: text that does not parse back is refused before the
    write; a full disk keeps the old file; commission uses the atomic writer only."""
    from fdigen.errors import FdigenError
    from fdigen.files import atomic
    from fdigen.files.model_write import write_model_text
    from fdigen.model.model_file import builtin_model_path

    path = tmp_path / "m.toml"
    path.write_text("old = 1\n")
    with pytest.raises(FdigenError, match="does not parse back"):
        write_model_text(path, "[a]\nx = \n")
    with pytest.raises(FdigenError, match="does not parse back"):
        write_model_text(path, "x = '\udcff'\n")
    assert path.read_text() == "old = 1\n"

    def full(*a, **k):
        raise OSError(28, "No space left on device")

    # a model that reads back but names an unknown table is refused too (attack round 3:
    # a commissioned file with tolerance = 3.55 was written and then refused everywhere)
    good = builtin_model_path("dc_motor").read_text()
    with pytest.raises(FdigenError, match="does not read back"):
        write_model_text(path, good + "\n[new]\nx = 2\n")
    assert path.read_text() == "old = 1\n"
    monkeypatch.setattr(atomic.os, "fsync", full)
    with pytest.raises(OSError):
        write_model_text(path, good)
    assert path.read_text() == "old = 1\n" and [p.name for p in tmp_path.iterdir()] == ["m.toml"]
    source = (ROOT / "src" / "fdigen" / "commission" / "pipeline.py").read_text()
    assert ".write_text(" not in source      # every write through fdigen.files
    DATA("test_model_writes_are_atomic_and_checked", "commission/model file on a full disk",
         3, "pass", "unparsable text refused, old file intact, no temporary left")


# --- case 3: sidecar files ----------------------------------------------------------------


def test_simulate_refuses_sidecars_it_did_not_write(tmp_path):
    truth = tmp_path / "run.json"
    truth.write_text('{"mine": 1}')
    t0 = time.perf_counter()
    res = _invoke("simulate", "--model", "dc_motor", "-o", tmp_path / "run.csv",
                  "--duration", "0.1")
    assert res.exit_code == 2 and "run.json" in res.output and "--force" in res.output
    assert truth.read_text() == '{"mine": 1}' and not (tmp_path / "run.csv").exists()
    run = tmp_path / "p"
    run.mkdir()
    (run / "leg1.csv").write_text("mine\n")
    res = _invoke("platform", "simulate", "-o", run, "--duration", "0.1", "--bank", "none")
    assert res.exit_code == 2 and "leg1.csv" in res.output
    assert (run / "leg1.csv").read_text() == "mine\n" and not (run / "truth.json").exists()
    assert time.perf_counter() - t0 < 20          # refused before simulating
    # fdigen's own earlier output is replaced; --force replaces the user's
    res = _invoke("simulate", "--model", "dc_motor", "-o", tmp_path / "run.csv",
                  "--duration", "0.1", "--force")
    assert res.exit_code == 0 and "truth" in json.loads(truth.read_text())
    res = _invoke("simulate", "--model", "dc_motor", "-o", tmp_path / "run.csv",
                  "--duration", "0.1")
    assert res.exit_code == 0, res.output
    DATA("test_simulate_refuses_sidecars_it_did_not_write", "sidecar files (truth, legs)", 4,
         "pass", "user's run.json / leg1.csv: exit 2 naming them; fdigen's own or --force: "
         "replaced")


# --- case 4: build replacement survives SIGKILL -------------------------------------------

_KILL = """
import os, signal, sys
from pathlib import Path
from fdigen.files import folder_swap
out, mode = Path(sys.argv[1]), sys.argv[2]
from fdigen.stamp import stamp_text
tmp = out / ".m-newbuild"                     # the shape of mkdtemp's names
tmp.mkdir()
(tmp / folder_swap.TMP_MARK).write_text("1")
(tmp / "f.txt").write_text("new")
(tmp / ".fdigen-stamp").write_text(stamp_text("1" * 64, "m", {"f.txt": "new"}))
if mode == "exchange":
    folder_swap.exchange_paths = lambda a, b: os.kill(os.getpid(), signal.SIGKILL)
else:
    folder_swap.exchange_paths = lambda a, b: False
    real = os.replace
    def replace(a, b):
        real(a, b)
        if "-old-" in str(b):
            os.kill(os.getpid(), signal.SIGKILL)
    folder_swap.os.replace = replace
folder_swap.replace_folder(tmp, out / "m")
"""


def test_build_replacement_survives_sigkill(tmp_path):
    """SIGKILL in the middle of replacing a build's folder: the exchange is atomic (the
    old folder stays); without it (two renames) the next build restores the old folder;
    stale hidden folders of fdigen's are removed, a user's are kept."""
    from fdigen.files.folder_swap import exchange_paths, recover_folder
    from fdigen.stamp import is_complete_build, stamp_text

    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    (a / "A").touch()
    swapped = exchange_paths(a, b)
    assert not swapped or (b / "A").exists()
    cases = 0
    for mode in ("exchange", "two renames"):
        out = tmp_path / mode.replace(" ", "_")
        (out / "m").mkdir(parents=True)
        (out / "m" / "f.txt").write_text("old")
        (out / "m" / ".fdigen-stamp").write_text(stamp_text("0" * 64, "m", {"f.txt": "old"}))
        res = subprocess.run([sys.executable, "-c", _KILL, str(out), mode.split()[0]],
                             env=_env(), capture_output=True, text=True)
        assert res.returncode == -signal.SIGKILL, res.stderr
        if mode == "exchange":
            assert (out / "m" / "f.txt").read_text() == "old"
        else:
            assert not (out / "m").exists()          # the window two renames leave
        (out / ".m-notes").mkdir()                   # a user's folder, same prefix
        (out / ".m-notes" / "keep").write_text("mine")
        done = recover_folder(out, "m", lambda f: is_complete_build(f, "m"))
        assert (out / "m" / "f.txt").read_text() == "old", done
        assert sorted(p.name for p in out.iterdir()) == [".m-notes", "m"], done
        cases += 1
    DATA("test_build_replacement_survives_sigkill", "SIGKILL while replacing a build", cases,
         "pass", f"renameat2 exchange {'available' if swapped else 'missing'}: old folder "
         "kept; two renames: restored on the next build; stale .m-xxxx removed, user's kept")


def test_recovery_keeps_a_users_copies_of_a_generated_folder(tmp_path):
    """Only folders fdigen made, by name and content, are removed: a user's backup copy of
    a generated folder (stamp and all, plus a note), a folder holding only an empty file
    named like the stamp, a set-aside name with a file added are kept; a stale temporary
    build folder (mkdtemp name, marked) and a complete old build under the set-aside name
    are removed (attack round 2, F0: `cp -a` backups were deleted by the next build)."""
    from fdigen.files.folder_swap import TMP_MARK, recover_folder
    from fdigen.stamp import is_complete_build, stamp_text

    out = tmp_path / "out"
    good = stamp_text("0" * 64, "m", {"c/m.c": "int x;"})

    def folder(name, files):
        (out / name).mkdir(parents=True)
        for rel, text in files.items():
            (out / name / rel).parent.mkdir(parents=True, exist_ok=True)
            (out / name / rel).write_text(text)

    folder("m", {"c/m.c": "int x;", ".fdigen-stamp": good})
    folder(".m-backup-2026", {"c/m.c": "int x;", ".fdigen-stamp": good, "NOTES.txt": "mine"})
    folder(".m-mine", {".fdigen-stamp": "", "thesis.tex": "data"})
    folder(".m-old-123", {"c/m.c": "int x;", ".fdigen-stamp": good, "extra.txt": "mine"})
    # a mkdtemp-shaped name holding exactly a build: the old folder an exchange left
    folder(".m-copyofit", {"c/m.c": "int x;", ".fdigen-stamp": good})
    folder(".m-abcd1234", {TMP_MARK: "1", "c/m.c": "int"})
    folder(".m-old-77", {"c/m.c": "int x;", ".fdigen-stamp": good})
    done = recover_folder(out, "m", lambda f: is_complete_build(f, "m"))
    assert sorted(p.name for p in out.iterdir()) == [
        ".m-backup-2026", ".m-mine", ".m-old-123", "m"], done
    assert (out / ".m-backup-2026" / "NOTES.txt").read_text() == "mine"


# --- case 6: model files edited as TOML documents ------------------------------------------


def test_calibration_edits_values_not_text(cylinder):
    """A description reading 'datasheet value = 100' keeps its text; the parameter gets
    the calibrated value (the line edit replaced the first 'value =' on the line)."""
    from fdigen.discover.augment import augmented_text, check_augmented

    text = (MODELS / "pneumatic_cylinder.toml").read_text().replace(
        'description = "viscous friction coefficient"',
        'description = "datasheet value = 100"', 1)
    assert "datasheet value = 100" in text
    aug = augmented_text(text, cylinder, [], {}, {}, calibrated={"Ff": 94.262, "K": 1.02e-3})
    new = check_augmented(aug, cylinder, [], "<test>")
    ff = {q.name: q for q in new.parameters}["Ff"]
    assert ff.value == 94.262 and ff.description == "datasheet value = 100"
    assert {q.name: q for q in new.parameters}["K"].value == 1.02e-3
    DATA("test_calibration_edits_values_not_text", "calibration: value = in a description", 1,
         "pass", "parameter 100 -> 94.262, description unchanged")


def test_tune_write_places_new_tables_beside_their_kin():
    """[fdi.frozen_horizon] created by tune --write goes after [fdi.thresholds], not
    between the comment above [simulation] and its table."""
    from fdigen.tune.model_update import updated_model_text

    text = (MODELS / "dc_motor.toml").read_text()
    new = updated_model_text(text, {}, None, {"Rw": 1.5})
    lines = new.splitlines()
    i = lines.index("[fdi.frozen_horizon]")
    assert lines[i - 1] == "" and lines[i - 2].startswith("R2 = ")
    j = lines.index("[simulation]")
    assert lines[j - 1].startswith("# reverses")          # the comment still above it
    assert tomllib.loads(new)["fdi"]["frozen_horizon"] == {"Rw": 1.5}
    DATA("test_tune_write_places_new_tables_beside_their_kin", "layout of tables tune adds",
         1, "pass", "after [fdi.thresholds]; comments stay with their table")


# --- case 7: hash and lock ------------------------------------------------------------------


def test_tune_write_checks_hash_and_lock(tmp_path):
    """The model edited during a campaign: the write is refused; two writers: the second
    is told, never both 'wrote'; a writer holding the lock makes the other fail at once."""
    from fdigen.files.model_write import ModelChangedError, file_digest, locked
    from fdigen.tune.model_update import write_thresholds

    path = tmp_path / "m.toml"
    path.write_text((MODELS / "dc_motor.toml").read_text())
    read = file_digest(path)
    path.write_text(path.read_text().replace("window = 100", "window = 400"))
    edited = path.read_text()
    with pytest.raises(ModelChangedError, match="changed since"):
        write_thresholds(path, {"Rw": 9.5}, {"Rw": "9.5"}, expected_digest=read)
    assert path.read_text() == edited
    read = file_digest(path)
    outcomes = []

    def writer(value):
        try:
            write_thresholds(path, {"Rw": value}, {"Rw": str(value)}, expected_digest=read)
            outcomes.append("wrote")
        except ModelChangedError:
            outcomes.append("told")

    threads = [threading.Thread(target=writer, args=(v,)) for v in (7.5, 8.5)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(outcomes) == ["told", "wrote"]
    with locked(path):
        with pytest.raises(ModelChangedError, match="another fdigen"):
            write_thresholds(path, {"Rw": 1.5}, {"Rw": "1.5"},
                             expected_digest=file_digest(path))
    DATA("test_tune_write_checks_hash_and_lock", "model changed during tune / concurrent "
         "writers", 3, "pass", "edited: refused, file kept; two writers: 1 wrote, 1 told; "
         "locked: refused at once")


# --- case 8: cached designs check their model ------------------------------------------------


def test_design_cache_entry_checks_its_model(tmp_path, monkeypatch, motor):
    """A design planted under this model's key whose recorded model hash differs (another
    variant's design) is ignored; the entry fdigen stored serves."""
    import pickle

    from fdigen.design import cache

    design = cache.cached_design(motor)          # the session's cache: derived once
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "c"))
    cache.store_design(motor, design)
    path = cache.design_path(motor)
    tag, model_hash, text_digest, stored = pickle.loads(cache._read_framed(path))
    assert (tag, model_hash) == (cache._TAG, cache._identity(motor)[0])
    assert stored.config.window == design.config.window
    path.write_bytes(cache._framed(pickle.dumps((tag, "0" * 64, text_digest, stored))))
    assert cache.load_design(motor) is None
    path.unlink()
    cache.store_design(motor, design)
    assert cache.load_design(motor).model.name == "dc_motor"
    DATA("test_design_cache_entry_checks_its_model", "another model's design under the key",
         1, "pass", "hash differs: ignored with a warning, derived again")


# --- case 10: a log shorter than the window ---------------------------------------------------


def test_short_log_gives_no_verdict(tmp_path):
    log = tmp_path / "short.csv"
    log.write_text("t,u,w,i\n0,0,0,0\n0.001,0,0,0\n")
    res = _invoke("detect", log, "--model", "dc_motor")
    assert res.exit_code == 0 and "no verdict: the log has 2 samples, the window needs 100" \
        in res.output
    out = json.loads(_invoke("detect", log, "--model", "dc_motor", "--json").output)
    assert out["enough_data"] is False and out["verdict"].startswith("no verdict")
    CLI("test_short_log_gives_no_verdict", "log shorter than the RMS window", 2, "pass",
        "text and --json: 'no verdict: the log has 2 samples, the window needs 100'")


# --- case 11: model size after substitution --------------------------------------------------


def test_models_past_the_expanded_size_are_refused_fast(tmp_path):
    from fdigen.errors import ModelFileError
    from fdigen.model.model_file import load_model

    sys.path.insert(0, str(Path(__file__).parent))
    from hostile_models import hostile_models

    for name, text in hostile_models().items():
        path = tmp_path / f"{name}.toml"
        path.write_text(text)
        t0 = time.perf_counter()
        with pytest.raises(ModelFileError) as err:
            load_model(path)
        elapsed = time.perf_counter() - t0
        assert elapsed < 10 and ("limit" in str(err.value)), (name, str(err.value))
        MODEL("test_models_past_the_expanded_size_are_refused_fast", f"model size: {name}", 1,
              "pass", f"refused in {elapsed:.2f} s: "
              f"{str(err.value).split(': ', 1)[1].split(' (')[0]}")


# --- case 12: scheduler addresses and worker counts --------------------------------------------


def _listener(mode: str) -> int:
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(4)

    def serve():
        held = []
        while True:
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            if mode == "garbage":
                conn.sendall(b"HTTP/1.1 200 OK\r\n\r\n" + b"x" * 64)
                conn.close()
            else:
                held.append(conn)       # accepts, never answers

    threading.Thread(target=serve, daemon=True).start()
    return srv.getsockname()[1]


def test_bad_scheduler_and_workers_are_usage_errors(monkeypatch):
    monkeypatch.setenv("FDIGEN_CONNECT_TIMEOUT", "1")
    closed = socket.socket()
    closed.bind(("127.0.0.1", 0))
    port = closed.getsockname()[1]
    closed.close()
    cases = [("closed port", f"tcp://127.0.0.1:{port}"),
             ("silent listener", f"tcp://127.0.0.1:{_listener('silent')}"),
             ("non-Dask listener", f"tcp://127.0.0.1:{_listener('garbage')}"),
             ("host:port without scheme", "127.0.0.1:8786"),
             ("unknown scheme", "nonsense://x:1")]
    for kind, address in cases:
        t0 = time.perf_counter()
        res = _invoke("tune", "--model", "dc_motor", "--runs", "2", "--scheduler", address)
        elapsed = time.perf_counter() - t0
        assert res.exit_code == 2, (kind, res.output)
        assert "--scheduler" in res.output and "internal error" not in res.output, res.output
        assert elapsed < 30, kind
        CLI("test_bad_scheduler_and_workers_are_usage_errors", f"--scheduler: {kind}", 1,
            "pass", f"exit 2 in {elapsed:.1f} s naming the address")
    res = _invoke("tune", "--model", "dc_motor", "--workers", "100000")
    assert res.exit_code == 2 and "--workers" in res.output
    CLI("test_bad_scheduler_and_workers_are_usage_errors", "--workers 100000", 1, "pass",
        "exit 2 at once (at most 4 per core)")


# --- case 13: log memory ------------------------------------------------------------------------


def test_log_memory_is_proportional_to_used_columns(tmp_path, motor):
    """A log with 300 unused columns: reading it costs about its size (the bytes and the
    text), not 30 times it (every field of every row as a Python string)."""
    from fdigen.sim.log import read_log

    K, extra = 1500, 300
    t = np.arange(K) * 1e-3
    path = tmp_path / "wide.csv"
    with open(path, "w") as fh:
        fh.write("t,u,w,i," + ",".join(f"c{j}" for j in range(extra)) + "\n")
        pad = ",1.5" * extra
        for k in range(K):
            fh.write(f"{t[k]:.6f},{np.sin(k):.6f},{np.cos(k):.6f},0.5{pad}\n")
    size = path.stat().st_size
    tracemalloc.start()
    t0 = time.perf_counter()
    log = read_log(path, motor)
    elapsed = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert len(log.t) == K and log.extra == {}
    assert peak < 3 * size, (peak, size)
    LOGS("test_log_memory_is_proportional_to_used_columns", "log with 300 unused columns", 1,
         "pass", f"{size / 1e6:.1f} MB file: peak {peak / 1e6:.1f} MB ({peak / size:.1f} x "
         f"the file), {elapsed:.2f} s")


# --- case 14: nesting and output paths -----------------------------------------------------------


def test_deep_nesting_and_bad_out_are_clean_errors(tmp_path):
    deep = tmp_path / "deep.toml"
    deep.write_text('[model]\nname = "x"\n[parameters]\na = ' + "[" * 5000 + "]" * 5000 + "\n")
    res = _invoke("inspect", "--model", deep)
    assert res.exit_code == 2 and "nested too deeply" in res.output, res.output
    (tmp_path / "file").write_text("a file")
    log = tmp_path / "h.csv"
    log.write_text("t,u,xref,x,pp,pn\n0,0,0,0,1,1\n0.001,0,0,0,1,1\n")
    t0 = time.perf_counter()
    res = _invoke("commission", log, "--out", tmp_path / "file" / "out", "--no-build")
    assert res.exit_code == 2 and "--out" in res.output and "internal" not in res.output
    assert time.perf_counter() - t0 < 10
    CLI("test_deep_nesting_and_bad_out_are_clean_errors", "deep TOML / commission --out "
        "under a file", 2, "pass", "exit 2 naming the problem, before any work")


# --- case 16: built-in models are never written by default ---------------------------------------


def test_tune_write_never_writes_builtin_models():
    before = {p.name: p.read_bytes() for p in MODELS.glob("*.toml")}
    for args in (("tune", "--write"), ("tune", "--write", "--model", "dc_motor")):
        t0 = time.perf_counter()
        res = _invoke(*args, "--runs", "2")
        assert res.exit_code == 2 and "built-in" in res.output, res.output
        assert time.perf_counter() - t0 < 10
    assert {p.name: p.read_bytes() for p in MODELS.glob("*.toml")} == before
    DATA("test_tune_write_never_writes_builtin_models", "tune --write into a built-in model",
         2, "pass", "no --model / a built-in name: exit 2 before the campaign (any install)")


def test_platform_report_never_overwrites_a_leg_figure_it_did_not_write(tmp_path):
    """`report --platform -o r.png` writes r_leg1..6.png beside r.png: an existing file of
    those names that fdigen did not write is refused before any work (exit 2, named,
    untouched); fdigen's own figures (PNG text chunk `Software: fdigen report`) are not."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from click.testing import CliRunner

    from fdigen.cli import main
    from fdigen.files.outputs import is_fdigen_png
    from fdigen.report import png_bytes

    mine = tmp_path / "r_leg3.png"
    mine.write_bytes(b"\x89PNG\r\n\x1a\n my own figure")
    res = CliRunner().invoke(main, ["report", "--platform", str(tmp_path / "run"),
                                    "-o", str(tmp_path / "r.png")])
    assert res.exit_code == 2, res.output
    assert "r_leg3.png" in res.output and "did not write" in res.output
    assert mine.read_bytes() == b"\x89PNG\r\n\x1a\n my own figure"
    assert not (tmp_path / "r.png").exists()

    fig = plt.figure()
    data = png_bytes(fig)
    plt.close(fig)
    mine.write_bytes(data)
    assert is_fdigen_png(mine) and not is_fdigen_png(tmp_path / "nothing.png")
    res = CliRunner().invoke(main, ["report", "--platform", str(tmp_path / "run"),
                                    "-o", str(tmp_path / "r.png")])
    assert "did not write" not in res.output      # past the check: the folder is missing
    assert mine.read_bytes() == data


def test_tuned_tables_never_change_the_meaning_of_a_dotted_key_model():
    """A first-time user's model written with dotted keys (`fdi.window = 20`,
    `simulation.input = ...`): `tune --write` once inserted [fdi.thresholds] mid-file and
    every later dotted key moved into [fdi.frozen_horizon] (the file parsed, and meant
    something else). The tables now go where no key can fall into them, and an edit that
    changes anything else is refused."""
    import tomllib
    from pathlib import Path

    from fdigen.errors import FdigenError
    from fdigen.tune.model_update import _check_edit, updated_model_text

    old = (Path(__file__).parent / "data" / "newuser" / "servo_motor_dotted.toml").read_text()
    new = updated_model_text(old, {"R1": 0.5, "R2": 0.25}, None, {"R1": 3.0},
                             {"R3": "Kalman filter: equations [w] driven by [], checked on enc"})
    a, b = tomllib.loads(old), tomllib.loads(new)
    assert b["fdi"].pop("thresholds") == {"R1": 0.5, "R2": 0.25}
    assert b["fdi"].pop("frozen_horizon") == {"R1": 3.0}
    assert set(b["fdi"].pop("residual_keys")) == {"R3"}
    assert a == b                                    # nothing else moved
    with pytest.raises(FdigenError, match="without changing its meaning"):
        _check_edit(old, old.replace("fdi.window = 20", "fdi.window = 21"), ("thresholds",))

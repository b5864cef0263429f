"""Security and data safety (issue 13): a model file never runs code, fdigen never
destroys what it did not write, every bad command-line value is a clean usage error.

Each test records its class of attack or bad input for docs/reliability.md
(scripts/reliability_report.py).
"""

from __future__ import annotations

import json
import os
import pickle
import re
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from click.testing import CliRunner

from fdigen.cli import main
from reliability_log import reporter

ROOT = Path(__file__).resolve().parents[1]
DC_MOTOR = ROOT / "src" / "fdigen" / "models" / "dc_motor.toml"
CODE = reporter("code execution")
DATA = reporter("data safety")
CLI = reporter("command line")


def _payloads(canary: Path) -> list[str]:
    """Text that would run code or break a generated file if pasted unescaped."""
    touch = f"touch {canary}"
    return [f"\n__attribute__((constructor)) static void pwn(void) {{ system(\"{touch}\"); }}\n",
            "*/ int pwn = 1; /*", f"$(shell {touch})", "\\\nint pwn_splice = 1;",
            "??/\nint pwn_trigraph = 1;", "\" ' ` quotes", "[bold red]markup[/]",
            "\u202e bidi \u2028 line sep \u00b5m \U0001d40a", f"`{touch}`",
            f"__import__('os').system('{touch}')"]


def _run(*args, **kw):
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    return subprocess.run([sys.executable, "-m", "fdigen.cli", *map(str, args)],
                          capture_output=True, text=True, env=env, **kw)


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


# --- code execution -------------------------------------------------------------------


def test_reference_never_execs_model_names(tmp_path):
    """Every symbol of the step program renamed to an injection payload: the reference
    backend's numbers are unchanged and nothing ran (safe_lambdify prints only generated
    names, whatever the model's names are)."""
    from fdigen.backends.reference import lambdify_program
    from fdigen.design.cache import cached_design
    from fdigen.design.program import Program
    from fdigen.model.model_file import load_model

    canary = tmp_path / "CANARY"
    design = cached_design(load_model("dc_motor"))
    prog = design.step
    syms = prog.free_inputs() + [s for s, _ in prog.assignments]
    payloads = _payloads(canary)
    ren = {s: sp.Symbol(f"{payloads[i % len(payloads)]}[{i}]", **s.assumptions0)
           for i, s in enumerate(syms)}
    evil = Program({k: tuple(ren[s] for s in v) for k, v in prog.inputs.items()},
                   tuple((ren[s], e.xreplace(ren)) for s, e in prog.assignments),
                   {k: tuple(sp.sympify(e).xreplace(ren) for e in v)
                    for k, v in prog.outputs.items()})
    rng = np.random.default_rng(0)
    args = [list(rng.uniform(0.5, 1.5, len(v))) for v in prog.inputs.values()]
    names = ["z_next", "r", "aux"]
    good = lambdify_program(prog, names)(*args)
    bad = lambdify_program(evil, names)(*args)
    for g, b in zip(good, bad):
        np.testing.assert_allclose(np.array(b, float), np.array(g, float), rtol=1e-12)
    assert not canary.exists()
    CODE("test_reference_never_execs_model_names", "names pasted into exec'd Python",
         len(syms), "pass", f"{len(syms)} symbols renamed to {len(payloads)} payloads: "
         "same numbers, nothing ran")


def test_safe_lambdify_refuses_unbound_names():
    from fdigen.safe_lambdify import safe_lambdify

    x, e = sp.Symbol("x"), sp.Symbol("e")      # 'e' would be numpy's e in lambdify
    with pytest.raises(ValueError, match="'e' is not an argument"):
        safe_lambdify([x], x + e)
    f = sp.Function("system")
    with pytest.raises(ValueError, match="undefined function"):
        safe_lambdify([x], f(x))(1.0)
    a0, v2 = sp.Symbol("_a0"), sp.Symbol("_v2")   # names like the generated ones
    assert safe_lambdify([x, a0, v2], [x + 10 * a0 + 100 * v2])(1.0, 2.0, 3.0) == [321.0]
    CODE("test_safe_lambdify_refuses_unbound_names", "free symbol / undefined function", 2,
         "pass", "ValueError before any code is run")


def _evil_model(folder: Path, canary: Path) -> Path:
    """dc_motor with payloads in its file name, descriptions and units."""
    text = DC_MOTOR.read_text()
    payloads = _payloads(canary)
    k = iter(range(10 ** 6))

    def desc(m):
        value = payloads[next(k) % len(payloads)] + m.group(2)
        return f"{m.group(1)} = {json.dumps(value, ensure_ascii=False)}"

    text = re.sub(r'\b(description|unit) = "([^"]*)"', desc, text)
    name = "m\n$(shell touch CANARY)\n__attribute__((constructor)) ??\\\n[bold]x`id`.toml"
    path = folder / name
    path.write_text(text)
    return path


def test_injection_corpus_through_generated_files(tmp_path):
    """The model FILE NAME and every description and unit carry the payloads: build,
    make (library and example), the example on a log, verify and detect on every backend
    run without executing any of them."""
    canary = tmp_path / "CANARY"
    model = _evil_model(tmp_path, canary)
    out = tmp_path / "out"
    res = _run("build", "--model", model, "--out", out, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    cdir = out / "dc_motor" / "c"
    for path in sorted((out / "dc_motor").rglob("*")):
        if path.is_file() and path.suffix in (".c", ".h", ""):
            for line in path.read_text().splitlines():   # payloads only inside comments
                if "pwn" in line or "$(shell" in line:
                    head = line.lstrip()
                    assert head.startswith(("//", "#", "*")) or "/**<" in line, line
    make = subprocess.run(["make", "-s"], cwd=cdir, capture_output=True, text=True)
    assert make.returncode == 0, make.stderr
    log = tmp_path / "run [bold]$x^_$.csv"
    assert _run("simulate", "--model", model, "-o", log, "--duration", "0.4",
                cwd=tmp_path).returncode == 0
    with open(log) as fh:
        ex = subprocess.run([str(cdir / "dc_motor_fdi_example")], stdin=fh,
                            capture_output=True, text=True, cwd=tmp_path)
    assert ex.returncode == 0, ex.stderr
    res = _run("verify", "--model", model, "--points", "20", "--duration", "0.3",
               cwd=tmp_path)
    assert res.returncode == 0, res.stdout + res.stderr
    for backend in ("reference", "casadi", "c"):
        res = _run("detect", log, "--model", model, "--backend", backend, cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        assert "[bold]" in res.stdout       # shown as text, not as rich markup
    assert not canary.exists() and not (tmp_path / "CANARY").exists()
    assert not (cdir / "CANARY").exists()
    CODE("test_injection_corpus_through_generated_files",
         "payloads in file name, descriptions, units", len(_payloads(canary)) + 5, "pass",
         "build, make, example, verify, detect x3 backends: no payload ran")


def test_design_cache_refuses_foreign_or_open_folders(tmp_path, monkeypatch):
    """A pickle planted in a cache folder others can write is never loaded."""
    from fdigen.design import cache
    from fdigen.model.model_file import load_model

    canary = tmp_path / "CANARY"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {canary}",))

    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "c"))
    model = load_model("dc_motor")
    path = cache.design_path(model)
    path.parent.mkdir(parents=True)
    path.write_bytes(pickle.dumps(Evil()))
    cases = 0
    os.chmod(path.parent, 0o777)
    assert cache.load_design(model) is None and not canary.exists()
    cases += 1
    os.chmod(path.parent, 0o700)
    os.chmod(path, 0o666)
    assert cache.load_design(model) is None and not canary.exists()
    cases += 1
    if os.getuid() == 0:
        os.chmod(path, 0o600)
        os.chown(path, 12345, 12345)
        assert cache.load_design(model) is None and not canary.exists()
        os.chown(path, 0, 0)
        os.chown(path.parent, 12345, 12345)
        assert cache.load_design(model) is None and not canary.exists()
        cases += 2
    DATA("test_design_cache_refuses_foreign_or_open_folders", "planted pickle", cases,
         "pass", "world-writable folder/file, other owner: ignored with a warning")


def test_design_cache_key_covers_printed_text():
    import dataclasses

    from fdigen.design.cache import design_path
    from fdigen.model.model_file import load_model

    m = load_model("dc_motor")
    q = dataclasses.replace(m.parameters[0], description="other", unit="mOhm")
    m2 = dataclasses.replace(m, parameters=(q,) + m.parameters[1:])
    assert design_path(m2) != design_path(m)
    DATA("test_design_cache_key_covers_printed_text", "units/descriptions in cache key", 1,
         "pass", "a changed description is a different cache entry")


# --- data safety ----------------------------------------------------------------------


def test_build_refuses_folders_it_did_not_write(tmp_path):
    out = tmp_path / "out"
    user = out / "dc_motor"
    (user / "notes").mkdir(parents=True)
    (user / ".git").mkdir()
    (user / "controller.c").write_text("int main(void) { return 0; }\n")
    res = _invoke("build", "--model", "dc_motor", "--out", out)
    assert res.exit_code == 2 and str(user) in res.output
    assert (user / "controller.c").read_text().startswith("int main")
    # a model named like a package folder, --out its parent: refused, sources intact
    src = tmp_path / "src"
    (src / "fdigen").mkdir(parents=True)
    (src / "fdigen" / "__init__.py").write_text("x = 1\n")
    named = tmp_path / "fdigen.toml"
    named.write_text(DC_MOTOR.read_text().replace('name = "dc_motor"', 'name = "fdigen"'))
    res = _invoke("build", "--model", named, "--out", src)
    assert res.exit_code == 2 and "refusing" in res.output
    assert (src / "fdigen" / "__init__.py").read_text() == "x = 1\n"
    DATA("test_build_refuses_folders_it_did_not_write", "build over a user's folder", 2,
         "pass", "exit 2 naming the folder; user files intact")


def test_stamp_notices_deleted_files_and_copies(tmp_path):
    out = tmp_path / "out"
    assert _invoke("build", "--model", "dc_motor", "--out", out).exit_code == 0
    res = _invoke("build", "--model", "dc_motor", "--out", out)
    assert "up to date" in res.output
    (out / "dc_motor" / "c" / "main.c").unlink()
    res = _invoke("build", "--model", "dc_motor", "--out", out)
    assert "up to date" not in res.output and (out / "dc_motor" / "c" / "main.c").is_file()
    (out / "dc_motor" / "design.json").write_text("{}")
    assert "up to date" not in _invoke("build", "--model", "dc_motor", "--out", out).output
    shutil.move(out / "dc_motor", out / "copy")
    res = _invoke("build", "--model", "dc_motor", "--out", out)
    assert "up to date" not in res.output and (out / "dc_motor").is_dir()
    (out / "dc_motor" / "mine.txt").write_text("keep")
    res = _invoke("build", "--model", "dc_motor", "--out", out, "--force")
    assert res.exit_code == 2 and "mine.txt" in res.output
    DATA("test_stamp_notices_deleted_files_and_copies", "stale stamp", 4, "pass",
         "deleted, edited, copied folder: rebuilt; foreign file: refused")


def test_atomic_write_keeps_symlink_and_mode(tmp_path):
    from fdigen.files.atomic import write_text
    from fdigen.tune.model_update import write_thresholds

    real = tmp_path / "real" / "model.toml"
    real.parent.mkdir()
    real.write_text(DC_MOTOR.read_text())
    os.chmod(real, 0o640)
    link = tmp_path / "link.toml"
    link.symlink_to(real)
    write_text(link, "x = 1\n")
    assert link.is_symlink() and real.read_text() == "x = 1\n"
    assert stat.S_IMODE(real.stat().st_mode) == 0o640
    real.write_text(DC_MOTOR.read_text())
    write_thresholds(link, {"Rw": 3.5}, {"Rw": "3.5"})
    assert link.is_symlink() and "3.5" in real.read_text()
    assert stat.S_IMODE(real.stat().st_mode) == 0o640
    assert sorted(p.name for p in real.parent.iterdir()) == ["model.toml"]   # no temp left
    DATA("test_atomic_write_keeps_symlink_and_mode", "symlinked/moded output", 2, "pass",
         "target replaced, link and mode 0640 kept")


def test_atomic_write_failure_keeps_old_file(tmp_path, monkeypatch):
    from fdigen.files import atomic

    path = tmp_path / "log.csv"
    path.write_text("old\n")

    def full(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(atomic.os, "fsync", full)
    with pytest.raises(OSError):
        atomic.write_text(path, "new\n")
    assert path.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["log.csv"]
    DATA("test_atomic_write_failure_keeps_old_file", "disk full while writing", 1, "pass",
         "old file intact, no temporary left")


def test_simulate_never_clobbers_its_log(tmp_path):
    log = tmp_path / "run.json"
    log.write_text("precious")
    res = _invoke("simulate", "--model", "dc_motor", "-o", log, "--duration", "0.1")
    assert res.exit_code == 2 and "-o" in res.output and log.read_text() == "precious"
    DATA("test_simulate_never_clobbers_its_log", "log named like its truth file", 1, "pass",
         "refused before simulating")


# --- command line ---------------------------------------------------------------------

BAD_VALUES = [
    (("verify", "--points", "-5"), "--points"),
    (("verify", "--duration", "0"), "--duration"),
    (("verify", "--duration", "-1"), "--duration"),
    (("verify", "--duration", "nan"), "--duration"),
    (("verify", "--duration", "inf"), "--duration"),
    (("simulate", "-o", "{tmp}/x.csv", "--duration", "nan"), "--duration"),
    (("simulate", "-o", "{tmp}/x.csv", "--duration", "0"), "--duration"),
    (("simulate", "-o", "{tmp}/x.csv", "--fault", "load@1=nan"), "--fault"),
    (("simulate", "-o", "{tmp}/x.csv", "--fault", "load@inf=1"), "--fault"),
    (("simulate", "-o", "{tmp}/missing/x.csv"), "-o"),
    (("simulate", "-o", "{tmp}/file/x.csv"), "-o"),
    (("simulate", "--platform", "-o", "{tmp}/file/p"), "-o"),
    (("tune", "--workers", "0"), "--workers"),
    (("tune", "--runs", "0"), "--runs"),
    (("tune", "--report", "{tmp}/missing/r.json"), "--report"),
    (("build", "--out", "{tmp}/file/out"), "--out"),
    (("platform", "build", "-o", "{tmp}/file/b"), "-o"),
    (("report", "{tmp}/x.csv", "-o", "{tmp}/missing/r.png"), "-o"),
    (("discover", "{tmp}/x.csv", "--out", "{tmp}/file/d"), "--out"),
]


def test_bad_values_are_usage_errors(tmp_path):
    (tmp_path / "file").write_text("a file, not a folder")
    (tmp_path / "x.csv").write_text("t,u,w,i\n0,0,0,0\n0.001,0,0,0\n")
    for args, option in BAD_VALUES:
        argv = [a.format(tmp=tmp_path) for a in args]
        t0 = time.perf_counter()
        res = _invoke(*argv)
        assert res.exit_code == 2, (argv, res.output)
        assert option in res.output and "Traceback" not in res.output, (argv, res.output)
        assert time.perf_counter() - t0 < 20, argv
        value = args[args.index(option) + 1].replace("{tmp}", "<tmp>")
        CLI("test_bad_values_are_usage_errors", f"{argv[0]} {option}", 1, "pass",
            f"{value}: exit 2 naming the option")


def test_device_files_are_refused_fast():
    for args in (("detect", "/dev/zero"), ("inspect", "--model", "/dev/zero")):
        t0 = time.perf_counter()
        res = _invoke(*args)
        assert res.exit_code == 2 and "not a regular file" in res.output, res.output
        assert time.perf_counter() - t0 < 10
    CLI("test_device_files_are_refused_fast", "unbounded input (/dev/zero)", 2, "pass",
        "refused: not a regular file")


def test_json_failures_print_an_error_object(tmp_path):
    cases = [("inspect", "--model", "/dev/zero", "--json"),
             ("detect", tmp_path / "missing.csv", "--json"),
             ("verify", "--points", "0", "--json"),
             ("platform", "ik", "--pose", "0,0,9,0,0,0", "--json")]
    for args in cases:
        res = CliRunner().invoke(main, [str(a) for a in args])
        assert res.exit_code == 2
        err = json.loads(res.stdout)["error"]
        assert err["exit_code"] == 2 and err["message"] and err["kind"]
    CLI("test_json_failures_print_an_error_object", "--json failure", len(cases), "pass",
        '{"error": {"message", "kind", "exit_code"}} on stdout')


def test_stdout_write_error_is_clean():
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    with open("/dev/full", "w") as full:
        res = subprocess.run([sys.executable, "-m", "fdigen.cli", "inspect", "--model",
                              "dc_motor"], stdout=full, stderr=subprocess.PIPE, text=True,
                             env=dict(os.environ, PYTHONPATH=str(ROOT / "src")))
    assert res.returncode == 2 and "standard output" in res.stderr
    assert "Traceback" not in res.stderr
    CLI("test_stdout_write_error_is_clean", "stdout on a full disk", 1, "pass",
        "one error line, exit 2")


@pytest.mark.parametrize("moment", ["cluster start", "campaign"])
def test_ctrl_c_in_tune_is_a_clean_interruption(tmp_path, moment):
    """Ctrl-C to the whole process group of `tune --write`, while the Dask cluster starts
    (it was ignored then: the campaign ran on and wrote the model, exit 0) or during the
    campaign: exit 130 within seconds, no traceback, the model file untouched."""
    model = tmp_path / "m.toml"
    model.write_text(DC_MOTOR.read_text())
    before = model.read_bytes()
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    proc = subprocess.Popen([sys.executable, "-m", "fdigen.cli", "tune", "--model", model,
                             "--runs", "400", "--duration", "2", "--workers", "1",
                             "--write"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env, start_new_session=True)
    try:
        deadline = time.time() + 120
        # wait until the worker processes exist (children of the command)
        while time.time() < deadline and not _has_grandchildren(proc.pid):
            time.sleep(0.05)
        time.sleep(0.0 if moment == "cluster start" else 2.0)
        os.killpg(proc.pid, signal.SIGINT)       # what the terminal does: the whole group
        t0 = time.time()
        _, err = proc.communicate(timeout=60)
        took = time.time() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, (proc.returncode, err[:1000], err[-1000:])
    assert "Traceback" not in err and "interrupted" in err, err[-2000:]
    assert model.read_bytes() == before
    CLI("test_ctrl_c_in_tune_is_a_clean_interruption", f"Ctrl-C in tune --write ({moment})",
        1, "pass", f"'fdigen: interrupted', exit 130 {took:.1f} s after, no worker "
        "traceback, model file untouched")


def _has_grandchildren(pid: int) -> bool:
    """Whether the process group ``pid`` holds a Dask worker process (a process started
    by multiprocessing: ``spawn_main`` or ``forkserver`` in its command line)."""
    for stat_file in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat_file.read_text().rsplit(")", 1)[1].split()
            if fields[2] != str(pid):          # field 5 of stat: the process group
                continue
            cmd = (stat_file.parent / "cmdline").read_bytes()
        except (OSError, IndexError):
            continue
        if b"spawn_main" in cmd or b"forkserver" in cmd:
            return True
    return False

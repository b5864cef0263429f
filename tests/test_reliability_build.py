"""Reliability of `fdigen build`: atomic on failure, safe under concurrency, reproducible.

* A build failing at any stage (model parsing, design, C rendering, strict compile check,
  CasADi compile, writing a file) leaves the output folder and the CasADi compiled cache
  byte-for-byte as they were (no stray temporary folder either).
* Two builds started at the same time in two processes into the same folder both succeed
  and leave exactly a single build's bytes (fcntl lock).
* The same model gives byte-identical output whatever the working directory, the locale
  (LC_ALL=C vs C.UTF-8) or the time zone.

One real baseline build is shared by the module. Stages after rendering reuse the
baseline's rendered files (``render_all`` is a pure function of its inputs) so that each
failure case costs no new derivation. With ``FDIGEN_RELIABILITY_REPORT`` set, every test
appends a JSON line to that file.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from reliability_log import reporter

from fdigen import pipeline
from fdigen.errors import DesignError, FdigenError

ROOT = Path(__file__).resolve().parents[1]
NAME = "pneumatic_cylinder"


report = reporter("build pipeline")


def snapshot(folder: Path) -> dict:
    """Every path under folder (files with their bytes, folders as None)."""
    if not folder.exists():
        return {}
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    """One real build into a fresh folder with a private CasADi cache."""
    root = tmp_path_factory.mktemp("reliability_build")
    cache = root / "cache"
    out = root / "baseline"
    captured = {}
    real_render_all = pipeline.render_all

    def capture(*args, **kwargs):
        captured["render"] = real_render_all(*args, **kwargs)
        return captured["render"]

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FDIGEN_CACHE", str(cache))
        mp.setattr(pipeline, "render_all", capture)
        result = pipeline.build(out_dir=out, force=True)
    assert not result.up_to_date and "render" in captured
    return {"root": root, "cache": cache, "out": out, "render": captured["render"],
            "bytes": snapshot(out / NAME)}


@pytest.fixture
def work(baseline, tmp_path, monkeypatch):
    """A copy of the baseline output folder, FDIGEN_CACHE pointing at the shared cache."""
    out = tmp_path / "out"
    shutil.copytree(baseline["out"], out)
    monkeypatch.setenv("FDIGEN_CACHE", str(baseline["cache"]))
    return out


def _reuse_render(monkeypatch, baseline, mutate=None):
    name, files, design = baseline["render"]
    files = dict(files)
    if mutate:
        mutate(files)
    monkeypatch.setattr(pipeline, "render_all", lambda *a, **k: (name, files, design))


def _fail_and_compare(test, kind, out, cache, action, expected=FdigenError):
    before_out, before_cache = snapshot(out), snapshot(cache)
    with pytest.raises(BaseException) as info:
        action()
    unchanged_out = snapshot(out) == before_out
    unchanged_cache = snapshot(cache) == before_cache
    exc = info.value
    clean = isinstance(exc, expected)
    ok = unchanged_out and unchanged_cache
    details = (f"raised {type(exc).__name__}; output folder "
               f"{'unchanged' if unchanged_out else 'CHANGED'} ({len(before_out)} paths), "
               f"cache {'unchanged' if unchanged_cache else 'CHANGED'} "
               f"({len(before_cache)} paths)")
    result = "pass" if ok and clean else "FAIL" if not ok else "FAIL (xfail)"
    report(test, kind, 1, result, details)
    assert unchanged_out, f"{kind}: output folder changed"
    assert unchanged_cache, f"{kind}: cache changed"
    return exc, clean


# ------------------------------------------------------------------- failing stages
def test_model_parse_error_leaves_everything(work, baseline, tmp_path):
    bad = tmp_path / "bad.toml"
    text = (pipeline.SRC_DIR / "models" / f"{NAME}.toml").read_text()
    bad.write_text(text.replace('x    = "xdot"', 'x    = "__import__(\'os\')"'))
    exc, clean = _fail_and_compare(
        "test_model_parse_error_leaves_everything", "build: model file parse error",
        work, baseline["cache"], lambda: pipeline.build(model=bad, out_dir=work, force=True))
    assert clean, repr(exc)


def test_design_error_leaves_everything(work, baseline, monkeypatch):
    import fdigen.design.cache as design_cache
    import fdigen.design.fdi_design as fd

    def boom(model, *a, **k):
        raise DesignError("injected: pair (A, C) not detectable")

    monkeypatch.setattr(fd, "fdi_design", boom)
    # the baseline stored its design in the shared cache: make this build derive it
    monkeypatch.setattr(design_cache, "load_design", lambda model: None)
    exc, clean = _fail_and_compare(
        "test_design_error_leaves_everything", "build: FDI design error", work,
        baseline["cache"], lambda: pipeline.build(out_dir=work, force=True))
    assert clean and "injected" in str(exc)


def test_c_render_error_leaves_everything(work, baseline, monkeypatch):
    import fdigen.backends.c.emit as emit
    import fdigen.design.fdi_design as fd

    design = baseline["render"][2]
    monkeypatch.setattr(fd, "fdi_design", lambda model, *a, **k: design)  # skip derivation

    def boom(*a, **k):
        raise RuntimeError("injected: template error in c/fdi.c.j2")

    monkeypatch.setattr(emit, "render_c_sources", boom)
    exc, clean = _fail_and_compare(
        "test_c_render_error_leaves_everything", "build: C template rendering error",
        work, baseline["cache"], lambda: pipeline.build(out_dir=work, force=True))
    assert "injected" in str(exc)


def test_compile_check_failure_leaves_everything(work, baseline, monkeypatch):
    def corrupt(files):
        files["c/pneumatic_cylinder_fdi.c"] += "\nint this is not C;\n"

    _reuse_render(monkeypatch, baseline, corrupt)
    exc, clean = _fail_and_compare(
        "test_compile_check_failure_leaves_everything",
        "build: generated C fails the strict compile check", work, baseline["cache"],
        lambda: pipeline.build(out_dir=work, force=True))
    assert clean and "does not compile" in str(exc)


def test_casadi_compile_failure_leaves_everything(work, baseline, monkeypatch):
    import fdigen.backends.casadi_backend.compiled as compiled
    from fdigen.errors import BuildError

    def boom(*a, **k):
        raise BuildError("injected: CasADi library does not compile")

    _reuse_render(monkeypatch, baseline)
    monkeypatch.setattr(compiled, "compile_library", boom)
    exc, clean = _fail_and_compare(
        "test_casadi_compile_failure_leaves_everything",
        "build: CasADi compile failure (compile_library raises)", work, baseline["cache"],
        lambda: pipeline.build(out_dir=work, force=True))
    assert clean


def test_real_casadi_compiler_failure_leaves_cold_cache_empty(work, baseline, monkeypatch,
                                                              tmp_path):
    """The real compile_library with a compiler that fails (CC=false), cold cache."""
    cold = tmp_path / "cold-cache"
    cold.mkdir()
    monkeypatch.setenv("FDIGEN_CACHE", str(cold))
    monkeypatch.setenv("CC", shutil.which("false") or "false")
    _reuse_render(monkeypatch, baseline)
    exc, clean = _fail_and_compare(
        "test_real_casadi_compiler_failure_leaves_cold_cache_empty",
        "build: real CasADi compile with a failing compiler (CC=false), cold cache",
        work, cold, lambda: pipeline.build(out_dir=work, force=True))
    assert clean, repr(exc)


def test_write_failure_leaves_everything(work, baseline, monkeypatch):
    _reuse_render(monkeypatch, baseline)
    real_write_text = Path.write_text

    def write_text(self, *a, **k):
        if self.name == "pneumatic_cylinder_fdi.h" and self.parent.name == "c_float":
            raise OSError(errno.ENOSPC, "No space left on device (injected)", str(self))
        return real_write_text(self, *a, **k)

    monkeypatch.setattr(Path, "write_text", write_text)
    exc, clean = _fail_and_compare(
        "test_write_failure_leaves_everything", "build: disk full while writing one file",
        work, baseline["cache"], lambda: pipeline.build(out_dir=work, force=True))
    if not clean:
        pytest.xfail(f"output unchanged, but build() raised {type(exc).__name__} "
                     "instead of the FdigenError (BuildError) its docstring promises "
                     "'On any failure'")


def test_first_build_failure_leaves_no_output(baseline, tmp_path, monkeypatch):
    """A failing build into a folder that has no previous output creates no model folder."""
    out = tmp_path / "fresh"
    monkeypatch.setenv("FDIGEN_CACHE", str(baseline["cache"]))
    _reuse_render(monkeypatch, baseline,
                  lambda files: files.__setitem__("c_float/pneumatic_cylinder_fdi.c", "#error x\n"))
    with pytest.raises(FdigenError):
        pipeline.build(out_dir=out, force=True)
    left = sorted(p.name for p in out.iterdir()) if out.exists() else []
    ok = left in ([], [".fdigen.lock"])
    report("test_first_build_failure_leaves_no_output",
           "build: failure with no previous output", 1, "pass" if ok else "FAIL",
           f"left in the folder: {left}")
    assert ok, left


# -------------------------------------------------------------------- concurrency
def _build_cmd(out):
    code = textwrap.dedent(f"""
        from fdigen import pipeline
        r = pipeline.build(out_dir={str(out)!r}, force=True)
        print(r.up_to_date, len(r.files))
    """)
    return [sys.executable, "-c", code]


def _compare(a: dict, b: dict):
    return sorted(k for k in set(a) | set(b) if a.get(k, 0) != b.get(k, 0))


def test_two_concurrent_builds_same_folder(baseline, tmp_path):
    """Both processes also run in another cwd, locale (C.UTF-8) and time zone than the
    baseline: equality with the baseline bytes is a reproducibility check too."""
    out = tmp_path / "shared"
    cwd = tmp_path / "elsewhere" / "deeper"
    cwd.mkdir(parents=True)
    env = dict(os.environ, FDIGEN_CACHE=str(baseline["cache"]), LC_ALL="C.UTF-8",
               LANG="C.UTF-8", TZ="America/St_Johns", PYTHONHASHSEED="99")
    procs = [subprocess.Popen(_build_cmd(out), cwd=cwd, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [p.communicate(timeout=300) for p in procs]
    codes = [p.returncode for p in procs]
    mine = snapshot(out / NAME)
    diff = _compare(mine, baseline["bytes"])
    stray = sorted(p.name for p in out.iterdir() if p.name not in (NAME, ".fdigen.lock"))
    ok = codes == [0, 0] and not diff and not stray
    report("test_two_concurrent_builds_same_folder",
           "two builds started together, two processes, same output folder "
           "(cwd elsewhere, LC_ALL=C.UTF-8, TZ=America/St_Johns)", 2,
           "pass" if ok else "FAIL",
           f"exit codes {codes}; differing files {diff}; stray entries {stray}")
    assert codes == [0, 0], [r[1][-2000:] for r in results]
    assert not diff, diff
    assert not stray, stray


# ---------------------------------------------------------------- reproducibility
def test_reproducible_across_cwd_locale_tz(baseline, tmp_path):
    """One rebuild in another cwd with LC_ALL=C and a +14 h time zone (the C.UTF-8 /
    America/St_Johns variant runs in test_two_concurrent_builds_same_folder, which also
    compares against the baseline bytes); one build costs ~20 s, so they are not repeated."""
    variants = {"LC_ALL=C, TZ=Pacific/Kiritimati": {"LC_ALL": "C", "LANG": "C",
                                                    "TZ": "Pacific/Kiritimati"}}
    procs = {}
    for i, (label, extra) in enumerate(variants.items()):
        cwd = tmp_path / f"cwd{i}" / "deeper"
        cwd.mkdir(parents=True)
        env = dict(os.environ, FDIGEN_CACHE=str(baseline["cache"]), PYTHONHASHSEED=str(7 + i),
                   **extra)
        out = tmp_path / f"out{i}"
        procs[label] = (out, subprocess.Popen(_build_cmd(out), cwd=cwd, env=env,
                                              stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                              text=True))
    failures = {}
    for label, (out, proc) in procs.items():
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err[-2000:]
        diff = _compare(snapshot(out / NAME), baseline["bytes"])
        if diff:
            failures[label] = diff
    report("test_reproducible_across_cwd_locale_tz",
           "rebuild in another cwd / locale / time zone / hash seed", len(variants),
           "pass" if not failures else "FAIL",
           f"byte-identical to the baseline ({len(baseline['bytes'])} paths, stamp included) "
           f"for {', '.join(variants)}" if not failures else f"differences: {failures}")
    assert not failures, failures

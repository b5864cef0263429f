"""An installable package: the wheel, installed into a fresh venv, works from any folder.

The wheel is built from a copy of the source tree (``pip wheel --no-deps
--no-build-isolation``: no network), installed with ``--no-deps`` into a new virtual
environment whose dependencies come from this environment's site-packages (a ``.pth``
file), and ``fdigen build`` and ``fdigen verify`` run from an empty temporary folder.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("src", "templates", "pyproject.toml", "setup.py", "MANIFEST.in", "README.md",
           "LICENSE")


def _can_build_wheels() -> bool:
    import setuptools

    major, minor = (int(v) for v in setuptools.__version__.split(".")[:2])
    return importlib.util.find_spec("wheel") is not None or (major, minor) >= (70, 1)


def _run(cmd, cwd, env, timeout=300):
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)
    assert proc.returncode == 0, f"{' '.join(map(str, cmd))}:\n{proc.stdout[-2000:]}\n" \
                                 f"{proc.stderr[-3000:]}"
    return proc.stdout


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    if not _can_build_wheels():
        pytest.skip("building a wheel without isolation needs the 'wheel' package "
                    "(pip install -e '.[test]')")
    tmp = tmp_path_factory.mktemp("package")
    tree = tmp / "tree"
    for name in SOURCES:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, tree / name, ignore=shutil.ignore_patterns(
                "__pycache__", "*.egg-info", "*.so", "*.o", "_templates"))
        else:
            tree.mkdir(exist_ok=True)
            shutil.copy2(src, tree / name)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    dist = tmp / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
          "--no-cache-dir", "-q", str(tree), "-w", str(dist)], cwd=tmp, env=env)
    wheel = next(dist.glob("fdigen-*.whl"))
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=tmp, env=env)
    purelib = next((venv / "lib").glob("python3*/site-packages"))
    (purelib / "_fdigen_test_deps.pth").write_text(
        "\n".join(site.getsitepackages()) + "\n")     # the dependencies, not fdigen
    python = venv / "bin" / "python"
    _run([python, "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)],
         cwd=tmp, env=env)
    user = tmp / "project"
    user.mkdir()
    env = dict(env, FDIGEN_CACHE=str(tmp / "cache"), VIRTUAL_ENV=str(venv),
               PATH=f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}")
    return wheel, venv, user, env


def test_wheel_ships_templates_models_and_metadata(installed):
    wheel, *_ = installed
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        meta = next(zf.read(n).decode() for n in names if n.endswith(".dist-info/METADATA"))
    templates = {str(p.relative_to(ROOT / "templates")) for p in
                 (ROOT / "templates").rglob("*.j2")}
    assert templates and {f"fdigen/_templates/{t}" for t in templates} <= names
    assert {"fdigen/models/pneumatic_cylinder.toml", "fdigen/models/dc_motor.toml"} <= names
    from fdigen import __version__

    assert f"Version: {__version__}" in meta
    assert "License: MIT" in meta and "License :: OSI Approved :: MIT License" in meta
    assert "Summary: Symbolic model-to-code generator" in meta
    assert any(n.endswith(".dist-info/LICENSE") or "licenses/LICENSE" in n for n in names)


def test_installed_fdigen_builds_and_verifies_from_any_folder(installed):
    wheel, venv, user, env = installed
    fdigen = str(venv / "bin" / "fdigen")
    where = _run([venv / "bin" / "python", "-c",
                  "import fdigen, fdigen.resources as r; print(fdigen.__file__); "
                  "print(r.TEMPLATES_DIR)"], cwd=user, env=env).split()
    assert all(str(venv) in w for w in where), where   # the installed copy, not the sources
    out = _run([fdigen, "build"], cwd=user, env=env)
    folder = user / "generated" / "pneumatic_cylinder"
    assert str(folder) in out
    committed = ROOT / "generated" / "pneumatic_cylinder"
    for path in sorted(committed.rglob("*")):
        if path.is_file() and path.name != ".fdigen-stamp":
            rel = path.relative_to(committed)
            assert (folder / rel).read_bytes() == path.read_bytes(), rel
    out = _run([fdigen, "verify", "--points", "20", "--duration", "0.5"], cwd=user, env=env)
    assert out.count("OK") == 3 and "FAIL" not in out, out


def test_default_output_is_the_current_folder(tmp_path, monkeypatch):
    """Without ``out_dir`` a build writes ``./generated/<model>/`` of the current folder,
    in a source checkout too (the repository's generated/ is untouched)."""
    from fdigen import pipeline

    repo = ROOT / "generated" / "dc_motor"
    before = {p: p.stat().st_mtime_ns for p in repo.rglob("*") if p.is_file()}
    monkeypatch.chdir(tmp_path)
    result = pipeline.build("dc_motor", force=True)
    assert result.folder == tmp_path / "generated" / "dc_motor"
    assert (result.folder / "c" / "dc_motor_fdi.c").is_file()
    assert {p: p.stat().st_mtime_ns for p in repo.rglob("*") if p.is_file()} == before

"""The build pipeline: model file -> design -> every backend's sources -> ``generated/``.

Nothing is half-written: all files are rendered into a temporary folder beside the output
and moved into place only when every stage succeeded. A lock serialises concurrent builds.
An unchanged build is decided from a stamp (a hash of the model file, the templates and
fdigen's own sources) before any heavy library is imported.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

STAMP = ".fdigen-stamp"
SRC_DIR = Path(__file__).resolve().parent
TEMPLATES_DIR = SRC_DIR.parents[1] / "templates"
DEFAULT_OUT = SRC_DIR.parents[1] / "generated"


@dataclass(frozen=True)
class BuildResult:
    """What a build did: the model, its folder, the files written and whether it was cached."""

    model: str
    folder: Path
    files: tuple[str, ...]
    up_to_date: bool
    changed: tuple[str, ...] = ()


def _tree_digest(h, root: Path, suffixes):
    for path in sorted(root.rglob("*")):
        if path.is_file() and path.suffix in suffixes and "__pycache__" not in path.parts:
            h.update(str(path.relative_to(root)).encode())
            h.update(path.read_bytes())


def input_stamp(model_path: Path, options: dict) -> str:
    """Hash of everything a build depends on, computed without importing sympy/casadi."""
    h = hashlib.sha256()
    h.update(Path(model_path).read_bytes())
    h.update(json.dumps(options, sort_keys=True).encode())
    _tree_digest(h, TEMPLATES_DIR, {".j2"})
    _tree_digest(h, SRC_DIR, {".py", ".toml"})
    return h.hexdigest()


def resolve_model_path(model: str | Path | None) -> Path:
    """A model file path, or a built-in model's path by name (default: pneumatic cylinder).

    Imports nothing heavy: the unchanged-build check must stay fast.
    """
    BUILTIN_MODELS = {p.stem for p in (SRC_DIR / "models").glob("*.toml")}
    name = "pneumatic_cylinder" if model is None else str(model)
    if name in BUILTIN_MODELS:
        return SRC_DIR / "models" / f"{name}.toml"
    return Path(model)


@contextlib.contextmanager
def build_lock(out_dir: Path):
    """An exclusive lock on ``out_dir`` (blocks while another build writes there)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".fdigen.lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def render_all(model_path: Path, options: dict) -> tuple[str, dict[str, str]]:
    """Load, derive and render every backend; returns the model name and files by path."""
    from fdigen.backends.c.emit import render_c_sources
    from fdigen.backends.casadi_backend.compiled import casadi_sources
    from fdigen.design.describe import describe_design
    from fdigen.design.fdi_design import fdi_design
    from fdigen.model.model_file import load_model, model_hash

    model = load_model(model_path)
    design = fdi_design(model)
    digest = model_hash(model)
    source = Path(model_path).name
    files = {}
    for name, text in render_c_sources(design, float_type="double", model_source=source,
                                       model_hash=digest).items():
        files[f"c/{name}"] = text
    for name, text in render_c_sources(design, float_type="float", model_source=source,
                                       model_hash=digest).items():
        if name.endswith((".c", ".h")) and name != "main.c":
            files[f"c_float/{name}"] = text
    for name, text in casadi_sources(design, model_source=source, model_hash=digest).items():
        files[f"casadi/{name}"] = text
    description = describe_design(design)
    description["model_hash"] = digest
    files["design.json"] = json.dumps(description, indent=1, sort_keys=True) + "\n"
    return model.name, files, design


STRICT_CFLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2")


def compile_check(folder: Path, cc: str = "cc") -> None:
    """Compile every generated C core with the strict flags; raise BuildError on failure."""
    import subprocess

    from fdigen.errors import BuildError

    for sub in ("c", "c_float"):
        for src in sorted((folder / sub).glob("*_fdi.c")):
            cmd = [cc, *STRICT_CFLAGS, "-c", str(src), "-o", str(src.with_suffix(".o"))]
            try:
                proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
            except OSError as exc:
                raise BuildError(f"cannot run the C compiler '{cc}': {exc}")
            src.with_suffix(".o").unlink(missing_ok=True)
            if proc.returncode != 0:
                raise BuildError(f"generated C does not compile ({' '.join(cmd)}):\n"
                                 f"{proc.stderr.strip()[:4000]}")


def build(model: str | Path | None = None, out_dir: str | Path | None = None,
          check: bool = False, force: bool = False) -> BuildResult:
    """Build a model into ``out_dir/<model name>/``.

    Parameters
    ----------
    model : str or Path, optional
        A model file or a built-in model name; default the pneumatic cylinder.
    out_dir : str or Path, optional
        Default: the repository's ``generated/``.
    check : bool
        Write nothing; report the files that differ from a fresh build.
    force : bool
        Rebuild even when the stamp says the folder is up to date.

    Raises
    ------
    FdigenError
        On any failure; the output folder is then exactly as it was.
    """
    model_path = resolve_model_path(model)
    out = Path(out_dir) if out_dir is not None else DEFAULT_OUT
    options = {"float_variant": True}
    if not model_path.is_file():
        from fdigen.errors import ModelFileError

        raise ModelFileError("model file not found", source=str(model_path))
    stamp = input_stamp(model_path, options)
    if not check and not force:
        for folder in out.glob("*/" + STAMP) if out.is_dir() else ():
            if folder.read_text().strip() == stamp:
                return BuildResult(folder.parent.name, folder.parent, (), True)

    from fdigen.errors import BuildError, FdigenError

    try:
        name, files, design = render_all(model_path, options)
    except FdigenError:
        raise
    except Exception as exc:
        raise BuildError(f"build of {model_path.name} failed while deriving or rendering "
                         f"({type(exc).__name__}: {exc})") from exc
    target = out / name
    if check:
        changed = []
        for rel, text in sorted(files.items()):
            path = target / rel
            if not path.is_file() or path.read_text() != text:
                changed.append(rel)
        if target.is_dir():
            for path in sorted(target.rglob("*")):
                rel = str(path.relative_to(target))
                if path.is_file() and rel not in files and rel != STAMP:
                    changed.append(rel)
        return BuildResult(name, target, tuple(sorted(files)), not changed, tuple(changed))

    with build_lock(out):
        tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=out))
        try:
            for rel, text in files.items():
                path = tmp / rel
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(text)
            compile_check(tmp)
            from fdigen.backends.casadi_backend.compiled import compile_library
            compile_library(design)   # cached by the hash of its source: compiles once
            (tmp / STAMP).write_text(stamp + "\n")
            backup = None
            if target.exists():
                backup = out / f".{name}-old-{os.getpid()}"
                os.replace(target, backup)
            os.replace(tmp, target)
            if backup is not None:
                shutil.rmtree(backup, ignore_errors=True)
        except FdigenError:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        except Exception as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            raise BuildError(f"build of {name} failed while writing {out} "
                             f"({type(exc).__name__}: {exc}); {out / name} is unchanged") from exc
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return BuildResult(name, target, tuple(sorted(files)), False)

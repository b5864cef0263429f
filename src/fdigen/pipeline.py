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

from fdigen.design.design_warnings import (detection_warnings,  # noqa: F401 (re-exported)
                                           open_loop_warnings, operating_point_warnings,
                                           refusal_warning, unkeyed_warning)
from fdigen.resources import TEMPLATES_DIR
from fdigen.stamp import (STAMP, is_complete_build, is_up_to_date, replace_refusal,
                          stamp_text)

SRC_DIR = Path(__file__).resolve().parent
#: Default output folder, relative to the current folder: ``fdigen build`` run from the
#: repository root writes the repository's ``generated/``, run from a user's project its
#: own ``generated/`` (never the installation).
DEFAULT_OUT = Path("generated")


@dataclass(frozen=True)
class BuildResult:
    """What a build did: the model, its folder, the files written and whether it was cached."""

    model: str
    folder: Path
    files: tuple[str, ...]
    up_to_date: bool
    changed: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()


def _tree_digest(h, root: Path, suffixes):
    for path in sorted(root.rglob("*")):
        if path.is_file() and path.suffix in suffixes and "__pycache__" not in path.parts:
            h.update(str(path.relative_to(root)).encode())
            h.update(path.read_bytes())


def input_stamp(model_path: Path, options: dict) -> str:
    """Hash of everything a build depends on, computed without importing sympy/casadi."""
    h = hashlib.sha256()
    from fdigen.errors import ModelFileError
    from fdigen.files.bounded import read_bytes

    h.update(read_bytes(model_path, 1 << 20, what="model file",     # regular files only
                        error=lambda msg: ModelFileError(msg)))
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
    """An exclusive lock on ``out_dir`` (blocks while another build writes there). The
    lock file is opened without following a link and without blocking on a FIFO, and must
    be a regular file (a FIFO there hung the build; a dangling link created its target)."""
    import stat

    from fdigen.errors import BuildError

    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / ".fdigen.lock"
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW
                     | os.O_NONBLOCK, 0o666)
    except OSError as exc:
        kind = ("a symbolic link" if path.is_symlink() else "not a regular file"
                if path.exists() else exc.strerror or str(exc))
        raise BuildError(f"{path} cannot be the build lock ({kind}): remove it") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise BuildError(f"{path} is not a regular file: remove it (fdigen's build lock)")
    with os.fdopen(fd, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def render_all(model_path: Path, options: dict,
               on_casadi=None) -> tuple[str, dict[str, str], object]:
    """Load, derive and render every backend; returns the model name, files by path, design.

    The design comes from the design cache (:func:`fdigen.design.cache.load_design`) when
    the same model was derived by the same fdigen before, else from
    :func:`fdigen.design.fdi_design.fdi_design` (:func:`build` stores it once the build
    succeeded). The CasADi functions are built once, for the sources written here; the
    build compiles the library from these same sources.

    Parameters
    ----------
    model_path : Path
    options : dict
        Build options (part of the stamp).
    on_casadi : callable, optional
        Called as ``on_casadi(design, sources)`` as soon as the CasADi sources exist
        (before the C is rendered and the design described), so that the build can start
        compiling them in the background.
    """
    from fdigen.backends.c.emit import render_c_sources
    from fdigen.backends.casadi_backend.compiled import build_functions, casadi_sources
    from fdigen.design import fdi_design as derivation
    from fdigen.design.cache import load_description, load_design
    from fdigen.design.describe import describe_design
    from fdigen.model.model_file import load_model, model_hash

    model = load_model(model_path)
    design = load_design(model)
    cached = design is not None
    if not cached:
        design = derivation.fdi_design(model)
    digest = model_hash(model)
    source = Path(model_path).name
    casadi = casadi_sources(design, build_functions(design), model_source=source,
                            model_hash=digest)
    if on_casadi is not None:
        on_casadi(design, casadi)
    files = {}
    for name, text in render_c_sources(design, float_type="double", model_source=source,
                                       model_hash=digest).items():
        files[f"c/{name}"] = text
    for name, text in render_c_sources(design, float_type="float", model_source=source,
                                       model_hash=digest).items():
        if name.endswith((".c", ".h")) and name != "main.c":
            files[f"c_float/{name}"] = text
    for name, text in casadi.items():
        files[f"casadi/{name}"] = text
    description = load_description(model) if cached else None
    if description is None:
        description = describe_design(design)
    description = dict(description, model_hash=digest)
    files["design.json"] = json.dumps(description, indent=1, sort_keys=True) + "\n"
    if options.get("fmu"):
        files.update(_fmu_files(design, files, source, digest))
    return model.name, files, design


def _fmu_files(design, files: dict, source: str, digest: str) -> dict:
    """``fmu/``: the FMI 2.0 co-simulation FMU of the double-precision C core (bytes),
    its ``modelDescription.xml`` and wrapper (text, for review)."""
    from fdigen.backends.fmu import fmu_archive, render_fmu_sources

    core = {rel.split("/", 1)[1]: text for rel, text in files.items()
            if rel.startswith("c/") and rel.endswith((".c", ".h")) and rel != "c/main.c"}
    texts = render_fmu_sources(design, model_source=source, model_hash=digest,
                               core_files=core)
    wrapper = next(name for name in texts if name.endswith(".c"))
    identifier = wrapper[:-len("_fmi2.c")]
    archive = fmu_archive(identifier, texts["modelDescription.xml"],
                          {**core, wrapper: texts[wrapper]}, wrapper)
    out = {f"fmu/{name}": text for name, text in texts.items()}
    out[f"fmu/{identifier}.fmu"] = archive
    return out


STRICT_CFLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2")
#: also checked by the build: every implicit conversion in the generated C is explicit
CONVERSION_CFLAGS = ("-Wshadow", "-Wconversion")


def compile_check(folder: Path, cc: str = "cc") -> None:
    """Compile every generated C core with the strict flags, all at once; raise BuildError
    on the first failure (in file order)."""
    import subprocess

    from fdigen.errors import BuildError

    jobs = []
    try:
        for sub in ("c", "c_float"):
            for src in sorted((folder / sub).glob("*_fdi.c")):
                cmd = [cc, *STRICT_CFLAGS, *CONVERSION_CFLAGS, "-c", str(src), "-o",
                       str(src.with_suffix(".o"))]
                try:
                    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL,
                                            stderr=subprocess.PIPE, text=True)
                except OSError as exc:
                    raise BuildError(f"cannot run the C compiler '{cc}': {exc}")
                jobs.append((src, cmd, proc))
        for src, cmd, proc in jobs:
            try:
                _, err = proc.communicate(timeout=300)
            except subprocess.TimeoutExpired:
                raise BuildError(f"the C compiler timed out ({' '.join(cmd)})")
            if proc.returncode != 0:
                raise BuildError(f"generated C does not compile ({' '.join(cmd)}):\n"
                                 f"{err.strip()[:4000]}")
    finally:
        for src, _, proc in jobs:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
            src.with_suffix(".o").unlink(missing_ok=True)


def _peek_name(model_path: Path) -> str | None:
    """The ``[model] name`` of a model file, read without sympy (None if unreadable)."""
    import tomllib

    try:
        with open(model_path, "rb") as fh:
            doc = tomllib.loads(fh.read(1 << 20).decode("utf-8", errors="replace"))
        name = doc["model"]["name"]
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return None
    return name if isinstance(name, str) and name.isidentifier() else None


def check_build_target(out: Path, name: str | None) -> None:
    """Before any derivation: ``out`` must be a writable folder (or creatable) and
    ``out/<name>`` replaceable (:func:`fdigen.stamp.replace_refusal`)."""
    from fdigen.errors import BuildError
    from fdigen.files.outputs import check_output_folder

    check_output_folder(out, "--out")
    if name is not None:
        refusal = replace_refusal(out / name)
        if refusal is not None:
            raise BuildError(f"refusing to replace {out / name}: {refusal}")


def _abandon(tmp: Path, job) -> None:
    """Remove the temporary output folder and stop/remove a pending library compile."""
    shutil.rmtree(tmp, ignore_errors=True)
    if job is not None:
        job.discard()


def build(model: str | Path | None = None, out_dir: str | Path | None = None,
          check: bool = False, force: bool = False, fmu: bool = False) -> BuildResult:
    """Build a model into ``out_dir/<model name>/``.

    Parameters
    ----------
    model : str or Path, optional
        A model file or a built-in model name; default the pneumatic cylinder.
    out_dir : str or Path, optional
        Default: ``generated/`` in the current folder (:data:`DEFAULT_OUT`).
    check : bool
        Write nothing; report the files that differ from a fresh build.
    force : bool
        Rebuild even when the stamp says the folder is up to date.
    fmu : bool
        Also write ``fmu/<model>_fdi.fmu``, an FMI 2.0 co-simulation FMU of the C core
        (:mod:`fdigen.backends.fmu`; needs fmpy's FMI headers and gcc).

    Raises
    ------
    FdigenError
        On any failure; the output folder is then exactly as it was.
    """
    model_path = resolve_model_path(model)
    out = Path(out_dir) if out_dir is not None else Path.cwd() / DEFAULT_OUT
    options = {"float_variant": True}
    if fmu:
        options["fmu"] = True
    if not model_path.is_file():
        from fdigen.errors import ModelFileError

        raise ModelFileError("model file not found", source=str(model_path))
    stamp = input_stamp(model_path, options)
    if not check and not force:
        for folder in out.glob("*/" + STAMP) if out.is_dir() else ():
            if folder.parent.name.startswith("."):   # an interrupted build's folder
                continue
            if is_up_to_date(folder.parent, stamp):
                return BuildResult(folder.parent.name, folder.parent, (), True)

    from fdigen.errors import BuildError, FdigenError

    if not check:
        check_build_target(out, _peek_name(model_path))

    started = []

    def start_casadi(design, sources):
        # the CasADi library (cached by the hash of its source: compiled once) compiles in
        # the background while the C is rendered and checked; it enters the cache only
        # when the whole build succeeded
        from fdigen.backends.casadi_backend import compiled

        started.append((sources, compiled.start_library_compile(design, sources=sources)))

    try:
        name, files, design = render_all(model_path, options,
                                         on_casadi=None if check else start_casadi)
    except FdigenError:
        for _, job in started:
            job.discard()
        raise
    except Exception as exc:
        for _, job in started:
            job.discard()
        err = BuildError(f"build of {model_path.name} failed while deriving or rendering "
                         f"({type(exc).__name__}: {exc})")
        err.internal = True         # an fdigen bug, not the model's fault: exit 3
        raise err from exc
    except BaseException:
        for _, job in started:
            job.discard()
        raise
    target = out / name
    if check:
        changed = []
        for rel, text in sorted(files.items()):
            path = target / rel
            data = text if isinstance(text, bytes) else text.encode("utf-8")
            if not path.is_file() or path.read_bytes() != data:
                changed.append(rel)
        if target.is_dir():
            for path in sorted(target.rglob("*")):
                rel = str(path.relative_to(target))
                if path.is_file() and rel not in files and rel != STAMP:
                    changed.append(rel)
        return BuildResult(name, target, tuple(sorted(files)), not changed, tuple(changed))

    sources, job = started[0] if started else (None, None)
    refusal = replace_refusal(target, files)
    if refusal is not None:
        if job is not None:
            job.discard()
        raise BuildError(f"refusing to replace {target}: {refusal}")
    from fdigen.files.folder_swap import TMP_MARK, recover_folder, replace_folder

    with build_lock(out):
        try:
            recover_folder(out, name,   # an earlier build killed midway
                           lambda folder: is_complete_build(folder, name))
            tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=out))
            (tmp / TMP_MARK).write_text(f"{os.getpid()}\n")   # fdigen's: removable
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o777 & ~umask)   # mkdtemp's 0700 is for the build, not the result
        except BaseException:
            if job is not None:
                job.discard()
            raise
        try:
            for rel, text in files.items():
                path = tmp / rel
                path.parent.mkdir(parents=True, exist_ok=True)
                if isinstance(text, bytes):     # the FMU archive
                    path.write_bytes(text)
                else:
                    path.write_text(text, encoding="utf-8")
            from fdigen.backends.casadi_backend import compiled

            casadi = {rel.split("/", 1)[1]: text for rel, text in files.items()
                      if rel.startswith("casadi/")}
            if job is None or sources != casadi:   # render_all did not start this one
                if job is not None:
                    job.discard()
                job = None
                job = compiled.start_library_compile(design, sources=casadi)
            compile_check(tmp)
            compiled.compile_library(design, sources=casadi, started=job)
            (tmp / STAMP).write_text(stamp_text(stamp, name, files), encoding="utf-8")
            refusal = replace_refusal(target, files)   # again, under the lock
            if refusal is not None:
                raise BuildError(f"refusing to replace {target}: {refusal}")
            replace_folder(tmp, target)   # one atomic exchange where the system can
        except FdigenError:
            _abandon(tmp, job)
            raise
        except Exception as exc:
            _abandon(tmp, job)
            raise BuildError(f"build of {name} failed while writing {out} "
                             f"({type(exc).__name__}: {exc}); {out / name} is unchanged") from exc
        except BaseException:
            _abandon(tmp, job)
            raise
    from fdigen.design.cache import store_design

    description = json.loads(files["design.json"]) if "design.json" in files else None
    if description is not None:
        description.pop("model_hash", None)
    store_design(design.model, design, description)   # a no-op when already cached
    return BuildResult(name, target, tuple(sorted(files)), False,
                       warnings=refusal_warning(design) + detection_warnings(design)
                       + unkeyed_warning(design))


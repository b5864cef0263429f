"""C code of the CasADi functions, compiled once into a cached shared library.

:func:`casadi_sources` generates the C of the model functions, the core, the full step
and the fixed-length log chunk with :class:`casadi.CodeGenerator`, behind the fdigen
preamble (template ``casadi/source.c.j2``). :func:`compile_library` compiles it with the
system C compiler into a cache folder, keyed by a SHA-256 of the source, the compiler and
its flags: a second build with nothing changed finds the library and compiles nothing.
:func:`compiled_functions` loads the functions back with :func:`casadi.external`.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import shutil
import signal
import subprocess
import tempfile
from functools import lru_cache
from pathlib import Path

import casadi as ca

from fdigen.backends.casadi_backend.functions import core_function, model_functions
from fdigen.backends.casadi_backend.log_functions import (block_function, chunk_function,
                                                          step_function)
from fdigen.backends.casadi_backend.step_kernel import step_kernel_function
from fdigen.backends.render import render
from fdigen.design.fdi_design import FdiDesign
from fdigen.errors import BuildError
from fdigen.files.trust import untrusted_reason
from fdigen.model.model_file import model_hash as _model_hash

#: Compiler flags. ``-ffp-contract=off``: no fused multiply-add, so the compiled code rounds
#: exactly as the interpreted one on every target.
CFLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off")
#: Libraries linked after the source.
LDLIBS = ("-lm",)
#: Seconds the compiler may take to print its ``--version`` banner.
VERSION_TIMEOUT = 10.0
#: Environment variable naming the cache folder (default ``~/.cache/fdigen``).
CACHE_ENV = "FDIGEN_CACHE"


def function_names(design: FdiDesign) -> dict:
    """The C names of the functions in the generated library.

    Parameters
    ----------
    design : FdiDesign

    Returns
    -------
    dict of str to str
        ``core``, ``step``, ``kernel`` (:func:`~fdigen.backends.casadi_backend.functions.
        step_kernel_function`), ``block`` (:func:`~fdigen.backends.casadi_backend.functions.
        block_function`), ``chunk`` (:func:`~fdigen.backends.casadi_backend.functions.
        chunk_function`) and the model functions ``f A B h C``
        to their exported names (``<m>_core``...).
    """
    m = design.name
    names = {"core": f"{m}_core", "step": f"{m}_step", "kernel": f"{m}_step_kernel",
             "block": f"{m}_block", "chunk": f"{m}_chunk"}
    names.update({k: f"{m}_{k}" for k in ("f", "A", "B", "h", "C")})
    return names


def build_functions(design: FdiDesign) -> dict:
    """Every CasADi function of the library, built symbolically (not compiled).

    Parameters
    ----------
    design : FdiDesign

    Returns
    -------
    dict of str to casadi.Function
        Keys as :func:`function_names`.
    """
    core = core_function(design)
    kernel = step_kernel_function(design, core)
    step = step_function(design, kernel=kernel)
    block = block_function(design, kernel=kernel)
    chunk = chunk_function(design, block=block)
    fns = {"core": core, "step": step, "kernel": kernel, "block": block, "chunk": chunk}
    fns.update(model_functions(design.model))
    return fns


def _source_basename(design: FdiDesign) -> str:
    return f"{design.name}_casadi"


def casadi_sources(design: FdiDesign, functions: dict | None = None, *,
                   model_source: str | None = None, model_hash: str | None = None) -> dict:
    """The CasADi-generated C of a design, ready to be written into ``generated/``.

    Parameters
    ----------
    design : FdiDesign
    functions : dict of str to casadi.Function, optional
        The result of :func:`build_functions` (built if not given).
    model_source, model_hash : str, optional
        For the preamble: the model file's name (default: the name of
        ``design.model.source``) and hash (default: :func:`fdigen.model.model_file.
        model_hash` of the model).

    Returns
    -------
    dict of str to str
        ``{"<m>_casadi.c": source, "<m>_casadi.h": header}``, each starting with the fdigen
        preamble. The text depends only on the design, fdigen and CasADi versions
        (byte-deterministic).
    """
    fns = build_functions(design) if functions is None else functions
    base = _source_basename(design)
    cg = ca.CodeGenerator(base, {"with_header": True})
    for key in function_names(design):
        cg.add(fns[key])
    with tempfile.TemporaryDirectory(prefix="fdigen-casadi-") as tmp:
        cg.generate(tmp + os.sep)
        texts = {f"{base}.c": Path(tmp, f"{base}.c").read_text(encoding="utf-8"),
                 f"{base}.h": Path(tmp, f"{base}.h").read_text(encoding="utf-8")}
    context = dict(comment="//", model_name=design.name,
                   model_source=model_source or Path(str(design.model.source)).name,
                   model_hash=model_hash or _model_hash(design.model))
    return {name: render("casadi/source.c.j2", body=text, **context)
            for name, text in texts.items()}


def default_cache_dir() -> Path:
    """``$FDIGEN_CACHE`` if set, else ``~/.cache/fdigen``."""
    from fdigen.files.cache_root import cache_root

    return cache_root()


@lru_cache(maxsize=None)
def _compiler_identity(compiler: str) -> str:
    """Resolved path and ``--version`` banner of the compiler (part of the cache key)."""
    path = shutil.which(compiler)
    if path is None:
        raise BuildError(f"C compiler '{compiler}' not found on PATH")
    try:
        done = run_bounded([path, "--version"], VERSION_TIMEOUT)
    except OSError:
        done = None
    banner = done[1].splitlines()[0] if done and done[1] else ""
    return f"{os.path.realpath(path)}\n{banner}"


def run_bounded(cmd: list, timeout: float) -> tuple[int, str, str] | None:
    """``(returncode, stdout, stderr)`` of ``cmd`` run in its own process group, or
    ``None`` when it ran past ``timeout`` seconds: the whole group is then killed (a $CC
    that hung held a campaign and left its children running; gcc's cc1 ran on as an
    orphan after a compile was given up)."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(OSError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        return None
    return (proc.returncode, out.decode("utf-8", "replace"),
            err.decode("utf-8", "replace"))


def _start_compiler(cmd: list) -> subprocess.Popen:
    """Start one compiler command (argument list, no shell); stderr is captured."""
    try:
        return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True)
    except OSError as exc:
        raise BuildError(f"cannot run the C compiler {cmd[0]!r}: {exc}") from None


def library_key(sources: dict, compiler: str, flags=CFLAGS) -> str:
    """SHA-256 (hex) of the sources, the compiler identity and the flags."""
    h = hashlib.sha256()
    for name in sorted(sources):
        h.update(name.encode() + b"\0" + sources[name].encode("utf-8") + b"\0")
    h.update(_compiler_identity(compiler).encode() + b"\0")
    h.update("\0".join(list(flags) + list(LDLIBS)).encode())
    return h.hexdigest()


class LibraryCompile:
    """A compile of a design's CasADi C running in the background (see :func:`compile_library`).

    Started by :func:`start_library_compile`: when the library is already in the cache
    nothing runs; otherwise the compiler runs in a temporary folder of the cache while the
    caller does other work. :meth:`finish` waits, checks and moves the library into place;
    :meth:`discard` stops the compiler and removes the temporary folder, leaving the cache
    as it was.

    Attributes
    ----------
    library : Path
        Where the library is (or will be once finished).
    """

    def __init__(self, design_name: str, library: Path, cmd: list | None, tmp: Path | None,
                 proc: subprocess.Popen | None, source: Path | None):
        self.design_name = design_name
        self.library = library
        self._cmd, self._tmp, self._proc, self._source = cmd, tmp, proc, source

    def finish(self) -> Path:
        """Wait for the compiler, then move the library (and its source) into the cache.

        Raises
        ------
        BuildError
            If the compiler failed (its stderr in the message); the cache is then as it
            was.
        """
        if self._proc is None:
            return self.library
        try:
            _, err = self._proc.communicate()
            out = self._tmp / self.library.name
            if self._proc.returncode != 0:
                raise BuildError(f"compiling the CasADi C of '{self.design_name}' failed "
                                 f"({' '.join(self._cmd)}, exit code {self._proc.returncode}):"
                                 f"\n{err.strip()}")
            if not out.is_file():
                raise BuildError(f"the C compiler produced no library ({' '.join(self._cmd)})")
            cache = self.library.parent
            os.replace(self._source, cache / (self.library.stem + ".c"))
            digest = self._tmp / (self.library.name + ".sha256")
            digest.write_text(_file_digest(out) + "\n", encoding="ascii")
            os.replace(out, self.library)
            os.replace(digest, _digest_path(self.library))
        except OSError as exc:
            raise BuildError(f"cannot build the CasADi library in {self.library.parent}: "
                             f"{exc}") from None
        finally:
            self.discard()
        return self.library

    def discard(self) -> None:
        """Stop the compiler if it still runs and remove the temporary folder."""
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.communicate()
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None


def _file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _digest_path(lib: Path) -> Path:
    """Where the SHA-256 of a cached library is kept: ``<lib>.sha256`` beside it."""
    return lib.with_name(lib.name + ".sha256")


def _library_intact(lib: Path) -> bool:
    """Whether the cached library is the one this cache compiled under its key: its bytes
    match the SHA-256 written beside it when it was compiled. Another design's library
    copied over it (one residual fewer) was loaded and sized from the design: "double
    free or corruption" and exit 134; one of the same sizes would have run other numbers.
    A library without its digest, or not matching it, is compiled again (said when it
    does not match)."""
    try:
        want = _digest_path(lib).read_text(encoding="ascii").strip()
        got = _file_digest(lib)
    except OSError:
        return False
    if want != got:
        import sys

        print(f"fdigen: warning: cached CasADi library {lib} does not match the digest "
              "written when it was compiled: compiled again", file=sys.stderr)
        return False
    return True


def _private_cache(cache: Path) -> Path:
    """``cache``, or a new private temporary folder when ``cache`` exists and another user
    could write it (a library planted there would run when loaded), with a warning."""
    if not cache.exists():
        return cache
    reason = untrusted_reason(cache)
    if reason is None:
        return cache
    import sys

    print(f"fdigen: warning: CasADi library cache not used: {reason}", file=sys.stderr)
    return Path(tempfile.mkdtemp(prefix="fdigen-casadi-"))


def start_library_compile(design: FdiDesign, cache_dir: str | Path | None = None, *,
                          compiler: str | None = None, functions: dict | None = None,
                          sources: dict | None = None) -> LibraryCompile:
    """Start compiling the design's CasADi C in the background (see :func:`compile_library`).

    Parameters
    ----------
    design : FdiDesign
    cache_dir, compiler, functions
        As :func:`compile_library`.
    sources : dict of str to str, optional
        The result of :func:`casadi_sources` (generated if not given): the build passes
        the text it writes into ``generated/``, so the CasADi C is generated once.

    Returns
    -------
    LibraryCompile
        Call :meth:`~LibraryCompile.finish` (or :meth:`~LibraryCompile.discard`).

    Raises
    ------
    BuildError
        If the compiler cannot be started or the cache folder cannot be written.
    """
    compiler = compiler or os.environ.get("CC") or "gcc"
    sources = casadi_sources(design, functions) if sources is None else sources
    key = library_key(sources, compiler)
    cache = _private_cache(Path(cache_dir).expanduser() if cache_dir is not None
                           else default_cache_dir())
    base = _source_basename(design)
    lib = cache / f"{base}_{key[:24]}.so"
    if lib.is_file() and untrusted_reason(lib) is None and _library_intact(lib):
        return LibraryCompile(design.name, lib, None, None, None, None)
    tmp = None
    try:
        cache.mkdir(mode=0o700, parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".build-", dir=cache))
        for name, text in sources.items():
            Path(tmp, name).write_text(text, encoding="utf-8")
        cmd = [compiler, *CFLAGS, str(Path(tmp, f"{base}.c")), "-o", str(tmp / lib.name),
               *LDLIBS]
        proc = _start_compiler(cmd)
    except (OSError, BuildError) as exc:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, BuildError):
            raise
        raise BuildError(f"cannot build the CasADi library in {cache}: {exc}") from None
    return LibraryCompile(design.name, lib, cmd, tmp, proc, Path(tmp, f"{base}.c"))


def compile_library(design: FdiDesign, cache_dir: str | Path | None = None, *,
                    compiler: str | None = None, functions: dict | None = None,
                    sources: dict | None = None,
                    started: LibraryCompile | None = None) -> Path:
    """Compile the design's CasADi C into a shared library, or find it in the cache.

    Parameters
    ----------
    design : FdiDesign
    cache_dir : str or Path, optional
        Default :func:`default_cache_dir`. Created if missing.
    compiler : str, optional
        The C compiler; default ``$CC`` or ``gcc``.
    functions : dict, optional
        The result of :func:`build_functions` (built if not given).
    sources : dict, optional
        The result of :func:`casadi_sources` (generated if not given).
    started : LibraryCompile, optional
        A compile already started by :func:`start_library_compile`: only finished here.

    Returns
    -------
    Path
        ``<cache>/<m>_casadi_<key>.so``; the key is :func:`library_key`. When the file
        exists, nothing is compiled. Otherwise the source is compiled in a temporary
        folder of the cache and moved into place atomically (``os.replace``), next to a
        copy of the source.

    Raises
    ------
    BuildError
        If the compiler is missing or fails (the message holds its stderr).
    """
    job = started or start_library_compile(design, cache_dir, compiler=compiler,
                                           functions=functions, sources=sources)
    return job.finish()


def compiled_functions(design: FdiDesign, cache_dir: str | Path | None = None, *,
                       compiler: str | None = None, functions: dict | None = None) -> dict:
    """The library's functions, compiled (or found in the cache) and loaded.

    Parameters
    ----------
    design : FdiDesign
    cache_dir, compiler, functions
        As :func:`compile_library`.

    Returns
    -------
    dict of str to casadi.Function
        Keys as :func:`function_names`; each an :func:`casadi.external` function.
    """
    lib = compile_library(design, cache_dir, compiler=compiler, functions=functions)
    return load_functions(design, lib)


def load_functions(design: FdiDesign, lib: str | Path) -> dict:
    """The functions of a compiled library, loaded with :func:`casadi.external`.

    Parameters
    ----------
    design : FdiDesign
    lib : str or Path
        The library (:func:`compile_library`).

    Returns
    -------
    dict of str to casadi.Function
        Keys as :func:`function_names`.
    """
    try:
        return {key: ca.external(name, str(lib))
                for key, name in function_names(design).items()}
    except RuntimeError as exc:
        raise BuildError(f"cannot load the compiled library {lib}: {exc}") from None


class NativeFunction:
    """One function of the compiled library called through :mod:`ctypes`, in place.

    CasADi's Python call converts every input to a ``DM`` and every output back (per
    element, through Python lists): for the chunk function that costs several times the
    evaluation itself. Here the caller passes pointers to contiguous float64 buffers
    (column-major nonzeros, as the generated C reads them) and the outputs are written
    where the caller wants them. Work vectors are allocated once.

    Parameters
    ----------
    lib : Path
        The shared library (:func:`compile_library`).
    name : str
        The exported function name (:func:`function_names`).
    function : casadi.Function
        The symbolic function it was generated from (sizes, dense inputs and outputs).
    basename : str
        The library's source name (``<m>_casadi``), prefix of its ``casadi_int_size``.
    """

    def __init__(self, lib: Path, name: str, function: ca.Function, basename: str):
        self._lib = ctypes.CDLL(str(lib))
        self.name = name
        self.function = function
        self._f = getattr(self._lib, name)
        self._f.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_int]
        self._f.restype = ctypes.c_int
        if self._lib[f"{basename}_casadi_int_size"]() != 8:
            raise BuildError(f"{lib}: casadi_int is not 64 bits")
        sizes = [ctypes.c_longlong() for _ in range(4)]
        work = getattr(self._lib, f"{name}_work")
        if work(*[ctypes.byref(v) for v in sizes]) != 0:
            raise BuildError(f"{lib}: {name}_work failed")
        n_arg, n_res, n_iw, n_w = (max(1, v.value) for v in sizes)
        self._arg = (ctypes.c_void_p * n_arg)()
        self._res = (ctypes.c_void_p * n_res)()
        self._iw = (ctypes.c_longlong * n_iw)()
        self._w = (ctypes.c_double * n_w)()
        self._check_shapes(lib, function)
        for i in range(function.n_in()):
            if not function.sparsity_in(i).is_dense():
                raise BuildError(f"{name}: input {i} is not dense")
        for i in range(function.n_out()):
            if not function.sparsity_out(i).is_dense():
                raise BuildError(f"{name}: output {i} is not dense")
        getattr(self._lib, f"{name}_incref")()

    def _check_shapes(self, lib, function: ca.Function) -> None:
        """The library's own inputs and outputs (``<name>_n_in``, ``_sparsity_in``...) are
        those of ``function``: the caller's buffers are sized from the design, and a
        library of another design would read and write past them."""
        lib_fn = self._lib
        for kind, count, size in (("in", function.n_in(), function.size_in),
                                  ("out", function.n_out(), function.size_out)):
            n = getattr(lib_fn, f"{self.name}_n_{kind}")
            n.restype = ctypes.c_longlong
            sp_fn = getattr(lib_fn, f"{self.name}_sparsity_{kind}")
            sp_fn.restype = ctypes.POINTER(ctypes.c_longlong)
            sp_fn.argtypes = [ctypes.c_longlong]
            shapes = []
            for i in range(int(n())):
                ptr = sp_fn(i)
                shapes.append((int(ptr[0]), int(ptr[1])) if ptr else None)
            want = [tuple(size(i)) for i in range(count)]
            if shapes != want:
                raise BuildError(f"{lib}: {self.name}'s {kind}puts are {shapes}, the "
                                 f"design's {want}: the library is another design's")

    def __call__(self, args, results) -> None:
        """Evaluate with ``args`` and ``results`` given as buffer addresses (ints).

        Every address must point to ``nnz`` contiguous float64 values of that input or
        output (column-major); 0 for an output means "not wanted".
        """
        for i, a in enumerate(args):
            self._arg[i] = a
        for i, r in enumerate(results):
            self._res[i] = r
        if self._f(self._arg, self._res, self._iw, self._w, 0) != 0:
            raise RuntimeError(f"{self.name} failed")


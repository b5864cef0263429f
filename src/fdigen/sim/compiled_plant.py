"""The plant's chunk function compiled to C, for processes that simulate it many times.

A campaign simulates the same plant tens of times per worker. CasADi's virtual machine
evaluates the chunk function (``mapaccum`` of one sample: controllers, RK4 sub-steps,
clamps) at about 15 us per sample for the cylinder at 10 sub-steps; the same function
generated as C by :class:`casadi.CodeGenerator` and compiled with the flags of the CasADi
backend (``-ffp-contract=off``: no fused multiply-add) runs it at about 2.3 us.

The numbers must not depend on which one ran: the first chunk a compiled function
evaluates is evaluated by the virtual machine too, and the compiled function is used only
when both agree bit for bit (states, outputs, commands and the not-a-number counts);
otherwise the process keeps the virtual machine for that plant (said in the log). Without
a C compiler, or when it fails, the virtual machine runs, as before.

The library is kept in the cache folder under the SHA-256 of its source, the compiler and
the flags, beside a digest of its bytes (another library copied over it is compiled
again): a second campaign of the same plant compiles nothing. It is read through a
descriptor of the cache folder checked as the user's own (a folder another user swaps in
after the check is never read: attack round 14 had a planted library run in the
victim's process) and loaded from a private copy; a compile runs in a private folder,
within a size and a time limit (the compiler's process group killed past it), and a
source that failed is not compiled again in the process.
"""

from __future__ import annotations

import hashlib
import logging
import os
import secrets
import shutil
import stat
import sys
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

#: Optimisation level of the plant library: -O1 runs within 5 % of -O2 here and compiles
#: in 70 % of its time (0.31 against 0.43 s for the cylinder at 10 sub-steps).
PLANT_CFLAGS = ("-O1", "-fPIC", "-shared", "-ffp-contract=off")
#: A plant is compiled at its third simulation in a process (a campaign's worker), never
#: for a single ``fdigen simulate``.
COMPILE_AT_USE = 3
#: ``FDIGEN_COMPILE_PLANT=0`` (or ``false``, ``no``, ``off``) keeps every plant on CasADi's
#: virtual machine.
ENV_SWITCH = "FDIGEN_COMPILE_PLANT"
#: Largest C source compiled (bytes): the source grows with the sub-steps (83 kB for the
#: cylinder at 10, 7.1 MB at 1000, where gcc ran past 10 minutes); above it the virtual
#: machine runs.
MAX_PLANT_SOURCE = 1_000_000
#: Seconds a compile may take; the compiler's whole process group is killed past it.
COMPILE_TIMEOUT = 120.0
#: Largest library read back from the cache (bytes).
MAX_LIBRARY_BYTES = 64_000_000

_LOG = logging.getLogger("casadi")
#: Sources whose compile or load failed in this process: not tried again.
_FAILED: set = set()


def compiling_enabled() -> bool:
    """Whether :data:`ENV_SWITCH` allows compiling (anything but 0, false, no, off)."""
    return os.environ.get(ENV_SWITCH, "1").strip().lower() not in ("0", "false", "no", "off")


def plant_source(run: ca.Function) -> str:
    """The C of ``run`` (deterministic: same function, same text)."""
    with tempfile.TemporaryDirectory(prefix="fdigen-plant-") as tmp:
        name = "plant_chunk"
        cg = ca.CodeGenerator(f"{name}.c", {"with_header": False})
        cg.add(run)
        cg.generate(tmp + os.sep)
        return Path(tmp, f"{name}.c").read_text(encoding="utf-8")


def compile_plant(run: ca.Function, cache_dir: str | Path | None = None) -> ca.Function | None:
    """``run`` compiled and loaded with :func:`casadi.external`, from the cache when the
    same source was compiled before; ``None`` whenever it cannot be (no compiler, a failed
    or too long compile, a source too large, a cache that cannot be read or written, a
    library that does not load): the caller keeps the virtual machine.

    The library is read from the cache through a descriptor of the cache folder checked as
    the user's own and not writable by others (a folder swapped in by another user after
    the check is never read), verified against its digest, and loaded from a private copy;
    a compile runs in a private temporary folder, and its bytes are what is loaded.
    """
    try:
        return _compile_plant(run, cache_dir)
    except Exception as exc:  # noqa: BLE001 - never breaks a simulation: the VM runs
        _LOG.info("plant %s not compiled: %s: %s", run.name(), type(exc).__name__, exc)
        return None


def _compile_plant(run, cache_dir):
    from fdigen.backends.casadi_backend import compiled as cc

    compiler = os.environ.get("CC") or "gcc"
    source = plant_source(run)
    if len(source) > MAX_PLANT_SOURCE:
        _LOG.info("plant %s not compiled: %d bytes of C (at most %d)", run.name(),
                  len(source), MAX_PLANT_SOURCE)
        return None
    key = cc.library_key({"plant_chunk.c": source}, compiler, PLANT_CFLAGS)
    if key in _FAILED:
        return None
    cache = Path(cache_dir).expanduser().absolute() if cache_dir is not None \
        else cc.default_cache_dir()
    name = f"plant_{key[:24]}.so"
    data = _read_trusted(cache, name)
    if data is None:
        data = _compile_private(source, compiler)
        if data is None:
            _FAILED.add(key)
            return None
        _store_trusted(cache, name, data)
    fn = _load_private(data, run.name())
    if fn is None:
        _FAILED.add(key)
    return fn


def _private_folder(cache: Path, create: bool) -> int | None:
    """A descriptor of ``cache`` when it is a folder (not a link) of the user's own that no
    one else can write, else None; created first with ``create``."""
    from fdigen.files.trust import reason_for_stat

    if create:
        try:
            cache.mkdir(mode=0o700, parents=True, exist_ok=True)
        except OSError:
            return None
    try:
        dfd = os.open(cache, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    except OSError:
        return None
    if reason_for_stat(os.fstat(dfd), cache) is not None:
        os.close(dfd)
        return None
    return dfd


def _read_at(dfd: int, name: str) -> bytes | None:
    from fdigen.files.trust import reason_for_stat

    try:
        fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW, dir_fd=dfd)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode) or reason_for_stat(st, name) is not None \
                or st.st_size > MAX_LIBRARY_BYTES:
            return None
        return fh.read(MAX_LIBRARY_BYTES + 1)


def _read_trusted(cache: Path, name: str) -> bytes | None:
    """The cached library ``name``, when the cache is private and its bytes match the
    digest written beside it (a replaced library is said and compiled again)."""
    dfd = _private_folder(cache, create=False)
    if dfd is None:
        return None
    try:
        data, digest = _read_at(dfd, name), _read_at(dfd, name + ".sha256")
    finally:
        os.close(dfd)
    if data is None or digest is None:
        return None
    if hashlib.sha256(data).hexdigest() != digest.decode("ascii", "replace").strip():
        print(f"fdigen: warning: cached plant library {cache / name} does not match the "
              "digest written when it was compiled: compiled again", file=sys.stderr)
        return None
    return data


def _store_trusted(cache: Path, name: str, data: bytes) -> None:
    """Write the library and its digest into the cache, each atomically (best effort:
    nothing when the cache is not private or cannot be written)."""
    dfd = _private_folder(cache, create=True)
    if dfd is None:
        return
    try:
        for fname, blob in ((name, data),
                            (name + ".sha256", (hashlib.sha256(data).hexdigest() + "\n")
                             .encode("ascii"))):
            tmp = f".{fname}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600,
                         dir_fd=dfd)
            with os.fdopen(fd, "wb") as fh:
                fh.write(blob)
            os.replace(tmp, fname, src_dir_fd=dfd, dst_dir_fd=dfd)
    except OSError as exc:
        _LOG.info("plant library not stored in %s: %s", cache, exc)
    finally:
        os.close(dfd)


def _compile_private(source: str, compiler: str) -> bytes | None:
    """The shared library of ``source``, compiled in a private temporary folder (its
    compiler killed with its whole process group past :data:`COMPILE_TIMEOUT`)."""
    from fdigen.backends.casadi_backend import compiled as cc

    tmp = Path(tempfile.mkdtemp(prefix="fdigen-plant-"))
    try:
        src, out = tmp / "plant_chunk.c", tmp / "plant_chunk.so"
        src.write_text(source, encoding="utf-8")
        exe = shutil.which(compiler)
        if exe is None:
            _LOG.info("plant library not compiled: no compiler %r on PATH", compiler)
            return None
        done = cc.run_bounded([exe, *PLANT_CFLAGS, str(src), "-o", str(out), *cc.LDLIBS],
                              COMPILE_TIMEOUT)
        if done is None:
            _LOG.info("plant library not compiled: %s ran past %g s", exe, COMPILE_TIMEOUT)
            return None
        if done[0] != 0 or not out.is_file():
            _LOG.info("plant library not compiled (exit %s): %s", done[0],
                      done[2].strip()[-2000:])
            return None
        return out.read_bytes()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _load_private(data: bytes, name: str) -> ca.Function | None:
    """:func:`casadi.external` of the library ``data``, loaded from a private copy (the
    copy is removed once loaded: the loader keeps its mapping)."""
    tmp = Path(tempfile.mkdtemp(prefix="fdigen-plant-"))
    try:
        lib = tmp / "plant_chunk.so"
        fd = os.open(lib, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o700)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        return ca.external(name, str(lib))
    except (OSError, RuntimeError) as exc:
        _LOG.info("plant library not loaded: %s", exc)
        return None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _same(a, b) -> bool:
    """Bit for bit: the same bytes (a -0.0 is not a 0.0, a NaN's payload counts)."""
    def raw(v):
        return np.ascontiguousarray(np.asarray(v, dtype=float)).tobytes()

    return len(a) == len(b) and all(raw(x) == raw(y) for x, y in zip(a, b))


class PlantChunks:
    """The chunk function of one plant: CasADi's virtual machine, and from its
    :data:`COMPILE_AT_USE`-th simulation the compiled library once it has agreed with the
    virtual machine bit for bit on a real chunk (module docstring).

    Parameters
    ----------
    vm : casadi.Function
        ``mapaccum(plant_step, CHUNK_SAMPLES)``.
    """

    def __init__(self, vm: ca.Function):
        self.vm = vm
        self.uses = 0
        self._native = None        # None: not tried; False: not used; else the function
        self._agreed = False

    def start_run(self) -> None:
        """Count one simulation; compile when the count reaches :data:`COMPILE_AT_USE`."""
        self.uses += 1
        if self._native is None and self.uses >= COMPILE_AT_USE and compiling_enabled():
            self._native = compile_plant(self.vm) or False

    @property
    def compiled(self) -> bool:
        """Whether chunks now run compiled (after agreeing with the virtual machine)."""
        return bool(self._native) and self._agreed

    def __call__(self, *args):
        native = self._native
        if not native:
            return self.vm(*args)
        if self._agreed:
            return native(*args)
        ref, got = self.vm(*args), native(*args)
        if _same(ref, got):
            self._agreed = True
        else:
            _LOG.warning("compiled plant %s differs from CasADi's virtual machine on a "
                         "chunk: the virtual machine is kept", self.vm.name())
            self._native = False
        return ref

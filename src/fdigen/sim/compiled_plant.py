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
again): a second campaign of the same plant compiles nothing.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
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
#: ``FDIGEN_COMPILE_PLANT=0`` keeps every plant on CasADi's virtual machine.
ENV_SWITCH = "FDIGEN_COMPILE_PLANT"

_LOG = logging.getLogger("casadi")


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
    same source was compiled before; ``None`` when it cannot be (no compiler, a failed
    compile, a cache folder that cannot be written)."""
    from fdigen.backends.casadi_backend import compiled as cc
    from fdigen.files.trust import untrusted_reason

    compiler = os.environ.get("CC") or "gcc"
    try:
        source = plant_source(run)
        key = cc.library_key({"plant_chunk.c": source}, compiler, PLANT_CFLAGS)
    except Exception as exc:          # no compiler on PATH (BuildError), codegen refused
        _LOG.info("plant %s not compiled: %s", run.name(), exc)
        return None
    cache = cc._private_cache(Path(cache_dir).expanduser() if cache_dir is not None
                              else cc.default_cache_dir())
    lib = cache / f"plant_{key[:24]}.so"
    if not (lib.is_file() and untrusted_reason(lib) is None and cc._library_intact(lib)):
        if not _compile(source, lib, compiler):
            return None
    try:
        return ca.external(run.name(), str(lib))
    except RuntimeError as exc:
        _LOG.info("plant library %s not loaded: %s", lib, exc)
        return None


def _compile(source: str, lib: Path, compiler: str) -> bool:
    """Compile ``source`` into ``lib`` (atomically, with its digest beside it)."""
    from fdigen.backends.casadi_backend import compiled as cc

    tmp = None
    try:
        lib.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".plant-", dir=lib.parent))
        src = tmp / "plant_chunk.c"
        src.write_text(source, encoding="utf-8")
        out = tmp / lib.name
        proc = subprocess.run([shutil.which(compiler) or compiler, *PLANT_CFLAGS, str(src),
                               "-o", str(out), *cc.LDLIBS], capture_output=True, text=True,
                              timeout=600, check=False)
        if proc.returncode != 0 or not out.is_file():
            _LOG.info("plant library not compiled (exit %s): %s", proc.returncode,
                      proc.stderr.strip()[-2000:])
            return False
        digest = tmp / (lib.name + ".sha256")
        digest.write_text(cc._file_digest(out) + "\n", encoding="ascii")
        os.replace(out, lib)
        os.replace(digest, cc._digest_path(lib))
        return True
    except (OSError, subprocess.SubprocessError) as exc:
        _LOG.info("plant library not compiled: %s", exc)
        return False
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def _same(a, b) -> bool:
    return len(a) == len(b) and all(
        np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True) for x, y in zip(a, b))


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
        if (self._native is None and self.uses >= COMPILE_AT_USE
                and os.environ.get(ENV_SWITCH, "1") != "0"):
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

"""Processor-in-the-loop: the float core on an emulated Cortex-M4F against the host.

:func:`pil_sources` renders the test binary (``templates/pil/``): the generated float core,
a replay ``main`` that steps the core over logs read through Arm semihosting and writes
every output, the startup code (vector table, ``.data``/``.bss`` set-up, FPU enable) and
the linker script of the MPS2 AN386 board (Cortex-M4 with FPU). :func:`run_pil` builds it
with ``arm-none-eabi-gcc`` (``-mcpu=cortex-m4 -mfpu=fpv4-sp-d16 -mfloat-abi=hard -Os``),
runs it under ``qemu-system-arm -M mps2-an386 -semihosting -icount shift=0`` and the same
``main`` built for the host (stdio in place of semihosting) on the same samples, and
compares the outputs byte for byte.

Instructions per step: under ``-icount`` the emulated clock follows the executed
instructions; SysTick (CPU clock) ticks are counted around every ``_step`` call and
converted with a calibration of ``PIL_NOPS`` ``nop`` instructions in the same binary.
Stack: the free stack is painted before each log and the high-water mark read after it
(the deepest call of the replay loop: ``_step`` and its callees); beside it the static
worst path of ``-fstack-usage``. Code size: ``arm-none-eabi-size`` of the core's object.
"""

from __future__ import annotations

import re
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from fdigen.backends.c.emit import c_context, render_c_sources
from fdigen.backends.render import render
from fdigen.design.fdi_design import FdiDesign
from fdigen.model.model_file import model_hash
from fdigen.verify.tools import require_tool

#: Target flags: the Cortex-M4F build of README's "Generated code" section.
M4_FLAGS = ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]
#: Flags of the core on both sides: no FMA contraction (the host has none either), sqrtf
#: as the IEEE instruction (no errno).
CORE_FLAGS = ["-std=c99", "-Os", "-ffp-contract=off", "-fno-math-errno"]
#: nops of the instructions-per-tick calibration.
NOPS = 16384
#: Stack reserved for the target program [bytes].
STACK_BYTES = 16384
_TRAILER = 0x50494C30


def pil_sources(design: FdiDesign) -> dict[str, str]:
    """Every file of the PIL test binary (target and host), file name -> text."""
    src, digest = Path(str(design.model.source or design.name)).name, model_hash(design.model)
    core = render_c_sources(design, float_type="float", model_source=src, model_hash=digest)
    ctx = c_context(design, "float")
    files = {n: core[n] for n in (f"{design.name}_fdi.c", f"{design.name}_fdi.h")}
    for name, template, comment in (("pil_main.c", "pil/pil_main.c.j2", "//"),
                                    ("pil_io.h", "pil/pil_io.h.j2", "//"),
                                    ("semihost.c", "pil/semihost.c.j2", "//"),
                                    ("host_io.c", "pil/host_io.c.j2", "//"),
                                    ("startup.c", "pil/startup.c.j2", "//"),
                                    ("link.ld", "pil/link.ld.j2", None)):
        text = render(template, comment=comment or "//", model_name=design.name,
                      model_source=src, model_hash=digest, prefix=ctx["prefix"],
                      macro=ctx["macro"], real=ctx["real"], real_type="float",
                      header=ctx["header"], nops=NOPS, stack_bytes=STACK_BYTES)
        if comment is None:   # a linker script takes /* */ comments only
            text = "\n".join(f"/* {line[2:].strip()} */" if line.startswith("//") else line
                             for line in text.splitlines()) + "\n"
        files[name] = text
    return files


def record_dtype(n_res: int) -> np.dtype:
    """One output record of the replay (``pil_record`` of ``pil_main.c``)."""
    return np.dtype([("r", "<f4", (n_res,)), ("rms", "<f4", (n_res,)), ("flags", "<u4"),
                     ("fault_class", "<i4"), ("action", "<i4"), ("faults", "<u4"),
                     ("status", "<i4")])


def encode_logs(logs: list[tuple[np.ndarray, np.ndarray]]) -> bytes:
    """``pil_in.bin``: the log count, then per log its sample count and (u, y) rows as
    float32."""
    parts = [np.uint32(len(logs)).tobytes()]
    for u, y in logs:
        parts.append(np.uint32(len(u)).tobytes())
        parts.append(np.hstack([u, y]).astype("<f4").tobytes())
    return b"".join(parts)


def _run(cmd, cwd, timeout, what):
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"{what} failed (exit {proc.returncode}): "
                           + (proc.stderr or proc.stdout)[-2000:])
    return proc


def _sections(size_tool, obj) -> dict:
    out = _run([size_tool, "-A", obj], obj.parent, 60, "arm-none-eabi-size").stdout
    sec = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[1].isdigit():
            key = next((k for k in (".text", ".rodata", ".data", ".bss")
                        if parts[0].startswith(k)), None)
            if key:
                sec[key] = sec.get(key, 0) + int(parts[1])
    return sec


def _static_stack(su_file: Path, prefix: str) -> int:
    """Worst static stack of ``_step``: its frame plus its deepest callee's (the generated
    step calls the residual generator and leaf helpers only)."""
    stack = {}
    for line in su_file.read_text().splitlines():
        fn = line.split("\t")[0].rsplit(":", 1)[-1].split(".")[0]
        stack[fn] = max(stack.get(fn, 0), int(line.split("\t")[1]))
    callees = [v for k, v in stack.items() if k.startswith(prefix) and k != f"{prefix}_step"
               and k not in (f"{prefix}_run", f"{prefix}_init", f"{prefix}_core")]
    return stack[f"{prefix}_step"] + max(callees, default=0)


def _parse_output(data: bytes, n_res: int) -> tuple[np.ndarray, np.ndarray]:
    trailer = np.frombuffer(data[-28:], dtype="<u4")
    if len(data) < 28 or trailer[0] != _TRAILER:
        raise RuntimeError("the PIL binary wrote no trailer (it stopped early)")
    return np.frombuffer(data[:-28], dtype=record_dtype(n_res)), trailer


def run_pil(design: FdiDesign, logs: list[tuple[np.ndarray, np.ndarray]], *,
            timeout: float = 600.0, keep_records: bool = False) -> dict:
    """Replay ``logs`` ((u, y) arrays) on the emulated Cortex-M4F and on the host.

    Returns
    -------
    dict
        ``equal`` (every output byte identical), ``max_abs_difference`` (residuals and
        RMS, target vs host), ``mismatched_samples``, ``samples``,
        ``instructions_per_step``, ``stack_bytes`` (measured high-water mark),
        ``stack_bytes_static`` (``-fstack-usage``), ``code_bytes`` (sections of the core),
        ``state_bytes``, ``seconds`` (build, target, host); with ``keep_records``,
        ``records``: ``{"target": ..., "host": ...}`` (arrays of :func:`record_dtype`).
    """
    gcc, size = require_tool("arm-none-eabi-gcc"), require_tool("arm-none-eabi-size")
    qemu, host_cc = require_tool("qemu-system-arm"), require_tool("gcc")
    ctx = c_context(design, "float")
    prefix, n_res = ctx["prefix"], ctx["sizes"]["r"]
    core = f"{design.name}_fdi.c"
    seconds = {}
    with tempfile.TemporaryDirectory(prefix="fdigen-pil-") as tmp:
        d = Path(tmp)
        for name, text in pil_sources(design).items():
            (d / name).write_text(text)
        (d / "pil_in.bin").write_bytes(encode_logs(logs))
        t0 = time.perf_counter()
        _run([gcc, *M4_FLAGS, *CORE_FLAGS, "-fstack-usage", "-c", core, "-o", "core.o"],
             d, timeout, "arm-none-eabi-gcc (core)")
        code = _sections(size, d / "core.o")
        _run([gcc, *M4_FLAGS, *CORE_FLAGS, "-nostartfiles", "-Wl,--gc-sections",
              "-ffunction-sections", "-fdata-sections", "-T", "link.ld", "startup.c",
              "semihost.c", "pil_main.c", core, "-lm", "-lc", "-lgcc", "-o", "pil.elf"],
             d, timeout, "arm-none-eabi-gcc (PIL binary)")
        _run([host_cc, *CORE_FLAGS, "host_io.c", "pil_main.c", core, "-lm", "-o", "pil_host"],
             d, timeout, "gcc (host PIL binary)")
        nm = _run([gcc.replace("gcc", "nm"), "-S", "pil.elf"], d, 60, "arm-none-eabi-nm").stdout
        m = re.search(r"^\w+ (\w+) [bBdD] pil_state$", nm, re.M)
        state_bytes = int(m.group(1), 16) if m else None
        seconds["build"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        _run([qemu, "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "none",
              "-semihosting-config", "enable=on,target=native", "-icount", "shift=0",
              "-kernel", "pil.elf"], d, timeout, "qemu-system-arm")
        target = (d / "pil_out.bin").read_bytes()
        seconds["target"] = time.perf_counter() - t0
        (d / "pil_out.bin").unlink()
        t0 = time.perf_counter()
        _run([d / "pil_host"], d, timeout, "host PIL binary")
        host = (d / "pil_out.bin").read_bytes()
        seconds["host"] = time.perf_counter() - t0
        static_stack = _static_stack(d / "core.su", prefix)
    rec_t, trailer = _parse_output(target, n_res)
    rec_h, _ = _parse_output(host, n_res)
    if len(rec_t) != len(rec_h):
        raise RuntimeError(f"target wrote {len(rec_t)} samples, host {len(rec_h)}")
    same = rec_t.tobytes() == rec_h.tobytes()
    mismatched = int(np.count_nonzero(rec_t != rec_h)) if not same else 0
    diff = 0.0
    for key in ("r", "rms"):
        a, b = rec_t[key].astype(float), rec_h[key].astype(float)
        both = (a == b) | (np.isnan(a) & np.isnan(b))
        delta = np.where(both, 0.0, np.abs(a - b))
        diff = max(diff, float(np.nanmax(delta, initial=0.0)) if delta.size else 0.0)
    steps, ticks = int(trailer[1]), int(trailer[2]) + (int(trailer[3]) << 32)
    nop_ticks, nops, stack = int(trailer[4]), int(trailer[5]), int(trailer[6])
    rep = {"model": design.name, "samples": steps, "equal": bool(same),
            "max_abs_difference": diff, "mismatched_samples": mismatched,
            "instructions_per_step": round(ticks / steps * nops / nop_ticks, 1)
            if steps and nop_ticks else None,
            "stack_bytes": stack, "stack_bytes_static": static_stack,
            "code_bytes": code, "state_bytes": state_bytes,
            "flags": " ".join(M4_FLAGS + CORE_FLAGS),
            "seconds": {k: round(v, 2) for k, v in seconds.items()}}
    if keep_records:
        rep["records"] = {"target": rec_t, "host": rec_h}
    return rep

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
from fdigen.verify.tools import ToolFailedError, require_tool

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


def _library(design: FdiDesign, platform: bool) -> tuple[dict, dict]:
    """(files of the float library, template context of the replay main)."""
    src, digest = Path(str(design.model.source or design.name)).name, model_hash(design.model)
    ctx = c_context(design, "float")
    if not platform:
        core = render_c_sources(design, float_type="float", model_source=src,
                                model_hash=digest)
        files = {n: core[n] for n in (f"{design.name}_fdi.c", f"{design.name}_fdi.h")}
        return files, {"prefix": ctx["prefix"], "macro": ctx["macro"], "real": ctx["real"],
                       "header": ctx["header"], "main": "pil/pil_main.c.j2"}
    from fdigen.platform.codegen import platform_names, render_platform_sources

    names = platform_names(design.name)
    files = render_platform_sources(design, float_type="float", model_source=src,
                                    model_hash=digest)
    return files, {"prefix": names["prefix"], "macro": names["macro"], "real": ctx["real"],
                   "header": names["header"], "leg_macro": names["leg_macro"],
                   "main": "pil/pil_platform_main.c.j2"}


def pil_sources(design: FdiDesign, *, platform: bool = False) -> dict[str, str]:
    """Every file of the PIL test binary (target and host), file name -> text; with
    ``platform``, the six-leg bank's step in place of the single core's."""
    src, digest = Path(str(design.model.source or design.name)).name, model_hash(design.model)
    files, ctx = _library(design, platform)
    main = ctx.pop("main")
    for name, template in (("pil_main.c", main), ("pil_io.h", "pil/pil_io.h.j2"),
                           ("semihost.c", "pil/semihost.c.j2"),
                           ("host_io.c", "pil/host_io.c.j2"),
                           ("startup.c", "pil/startup.c.j2"), ("link.ld", "pil/link.ld.j2")):
        text = render(template, comment="//", model_name=design.name, model_source=src,
                      model_hash=digest, real_type="float", nops=NOPS,
                      stack_bytes=STACK_BYTES, **ctx)
        if name == "link.ld":   # a linker script takes /* */ comments only
            text = "\n".join(f"/* {line[2:].strip()} */" if line.startswith("//") else line
                             for line in text.splitlines()) + "\n"
        files[name] = text
    return files


def record_dtype(n_res: int, platform: bool = False, legs: int = 6) -> np.dtype:
    """One output record of the replay (``pil_record`` of the replay main)."""
    if not platform:
        return np.dtype([("r", "<f4", (n_res,)), ("rms", "<f4", (n_res,)),
                         ("flags", "<u4"), ("fault_class", "<i4"), ("action", "<i4"),
                         ("faults", "<u4"), ("status", "<i4")])
    return np.dtype([("r", "<f4", (legs, n_res)), ("rms", "<f4", (legs, n_res)),
                     ("flags", "<u4", (legs,)), ("decision", "<i4", (legs,)),
                     ("leg_action", "<i4", (legs,)), ("action", "<i4"),
                     ("faulty_leg", "<i4"), ("safety", "<i4"), ("progress", "<f4"),
                     ("demand", "<f4", (legs,)), ("position_for_control", "<f4", (legs,)),
                     ("status", "<i4")])


def encode_logs(logs: list[tuple[np.ndarray, ...]]) -> bytes:
    """``pil_in.bin``: the log count, then per log its sample count and its rows as
    float32: (u, y) per sample, or for the bank (demand (K, 6), u (K, 6, nu),
    y (K, 6, ny)) the demands, inputs and outputs of every leg per sample."""
    parts = [np.uint32(len(logs)).tobytes()]
    for arrays in logs:
        K = len(arrays[0])
        parts.append(np.uint32(K).tobytes())
        parts.append(np.hstack([np.asarray(a).reshape(K, -1) for a in arrays])
                     .astype("<f4").tobytes())
    return b"".join(parts)


def _run(cmd, cwd, timeout, what):
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)
    if proc.returncode != 0:
        raise ToolFailedError(f"{what} failed (exit {proc.returncode}): "
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


def _stack_sizes(su_files) -> dict:
    stack = {}
    for su_file in su_files:
        for line in su_file.read_text().splitlines():
            fn = line.split("\t")[0].rsplit(":", 1)[-1].split(".")[0]
            stack[fn] = max(stack.get(fn, 0), int(line.split("\t")[1]))
    return stack


def _static_stack(stack: dict, leg: str, bank: str | None = None) -> int:
    """Worst static stack of the step: the leg's ``_step`` frame plus its deepest callee's
    (the generated step calls the residual generator and leaf helpers only), under the
    bank's ``_step`` frame for the platform."""
    callees = [v for k, v in stack.items() if k.startswith(leg) and k != f"{leg}_step"
               and k not in (f"{leg}_run", f"{leg}_init", f"{leg}_core")]
    worst = stack[f"{leg}_step"] + max(callees, default=0)
    return worst + (stack[f"{bank}_step"] if bank else 0)


def _parse_output(data: bytes, dtype: np.dtype) -> tuple[np.ndarray, np.ndarray]:
    trailer = np.frombuffer(data[-28:], dtype="<u4")
    if len(data) < 28 or trailer[0] != _TRAILER:
        raise ToolFailedError("the PIL binary wrote no trailer (it stopped early)")
    return np.frombuffer(data[:-28], dtype=dtype), trailer


def _build(d: Path, sources: list[str], timeout: float) -> dict:
    """Compile the library objects (sizes, stack usage), the target ELF and the host
    executable in ``d``."""
    gcc, size = require_tool("arm-none-eabi-gcc"), require_tool("arm-none-eabi-size")
    code = {}
    for src in sources:
        _run([gcc, *M4_FLAGS, *CORE_FLAGS, "-fstack-usage", "-c", src, "-o",
              Path(src).with_suffix(".o").name], d, timeout, f"arm-none-eabi-gcc ({src})")
        for k, v in _sections(size, d / Path(src).with_suffix(".o").name).items():
            code[k] = code.get(k, 0) + v
    _run([gcc, *M4_FLAGS, *CORE_FLAGS, "-nostartfiles", "-Wl,--gc-sections",
          "-ffunction-sections", "-fdata-sections", "-T", "link.ld", "startup.c",
          "semihost.c", "pil_main.c", *sources, "-lm", "-lc", "-lgcc", "-o", "pil.elf"],
         d, timeout, "arm-none-eabi-gcc (PIL binary)")
    _run([require_tool("gcc"), *CORE_FLAGS, "host_io.c", "pil_main.c", *sources, "-lm",
          "-o", "pil_host"], d, timeout, "gcc (host PIL binary)")
    nm = _run([gcc[:-3] + "nm", "-S", "pil.elf"], d, 60, "arm-none-eabi-nm").stdout
    m = re.search(r"^\w+ (\w+) [bBdD] pil_state$", nm, re.M)
    return {"code": code, "state_bytes": int(m.group(1), 16) if m else None,
            "stack": _stack_sizes(d / Path(src).with_suffix(".su").name for src in sources)}


def _rows(records: np.ndarray) -> np.ndarray:
    """The bytes of each record, one row per sample."""
    return np.frombuffer(records.tobytes(), dtype=np.uint8).reshape(len(records), -1)


def _max_abs_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Largest |a - b| over the float fields of two record arrays (NaN = NaN)."""
    diff = 0.0
    for key in a.dtype.names:
        if a.dtype[key].base.kind != "f":
            continue
        x, y = a[key].astype(float), b[key].astype(float)
        same = (x == y) | (np.isnan(x) & np.isnan(y))
        delta = np.where(same, 0.0, np.abs(x - y))
        diff = max(diff, float(np.nanmax(delta, initial=0.0)))
    return diff


def run_pil(design: FdiDesign, logs: list[tuple[np.ndarray, ...]], *,
            platform: bool = False, timeout: float = 600.0,
            keep_records: bool = False) -> dict:
    """Replay ``logs`` on the emulated Cortex-M4F and on the host.

    Parameters
    ----------
    design : FdiDesign
    logs : list of tuple of numpy.ndarray
        ``(u, y)`` per log; with ``platform``, ``(demand, u, y)`` per run of the bank
        (shapes (K, 6), (K, 6, nu), (K, 6, ny)).
    platform : bool
        Run the six-leg bank's step (``<m>_platform_step``) instead of the single core.

    Returns
    -------
    dict
        ``equal`` (every output byte identical), ``max_abs_difference`` (every float
        output, target vs host), ``mismatched_samples``, ``samples``,
        ``instructions_per_step``, ``stack_bytes`` (measured high-water mark),
        ``stack_bytes_static`` (``-fstack-usage``), ``code_bytes`` (sections of the
        library), ``state_bytes``, ``seconds`` (build, target, host); with
        ``keep_records``, ``records``: ``{"target": ..., "host": ...}`` (arrays of
        :func:`record_dtype`).
    """
    qemu = require_tool("qemu-system-arm")
    ctx = c_context(design, "float")
    leg, n_res = ctx["prefix"], ctx["sizes"]["r"]
    files = pil_sources(design, platform=platform)
    sources = sorted(n for n in files if n.startswith(design.name) and n.endswith(".c"))
    seconds = {}
    with tempfile.TemporaryDirectory(prefix="fdigen-pil-") as tmp:
        d = Path(tmp)
        for name, text in files.items():
            (d / name).write_text(text)
        (d / "pil_in.bin").write_bytes(encode_logs(logs))
        t0 = time.perf_counter()
        built = _build(d, sources, timeout)
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
    dtype = record_dtype(n_res, platform)
    rec_t, trailer = _parse_output(target, dtype)
    rec_h, _ = _parse_output(host, dtype)
    if len(rec_t) != len(rec_h):
        raise ToolFailedError(f"target wrote {len(rec_t)} samples, host {len(rec_h)}")
    same = rec_t.tobytes() == rec_h.tobytes()
    steps, ticks = int(trailer[1]), int(trailer[2]) + (int(trailer[3]) << 32)
    nop_ticks, nops = int(trailer[4]), int(trailer[5])
    rep = {"model": design.name, "step": f"{design.name}_platform_step" if platform
           else f"{leg}_step", "samples": steps, "equal": bool(same),
           "max_abs_difference": _max_abs_difference(rec_t, rec_h),
           "mismatched_samples": int(np.count_nonzero(
               (_rows(rec_t) != _rows(rec_h)).any(axis=1))),
           "instructions_per_step": round(ticks / steps * nops / nop_ticks, 1)
           if steps and nop_ticks else None,
           "stack_bytes": int(trailer[6]),
           "stack_bytes_static": _static_stack(built["stack"], leg,
                                               f"{design.name}_platform" if platform else None),
           "code_bytes": built["code"], "state_bytes": built["state_bytes"],
           "flags": " ".join(M4_FLAGS + CORE_FLAGS),
           "seconds": {k: round(v, 2) for k, v in seconds.items()}}
    if keep_records:
        rep["records"] = {"target": rec_t, "host": rec_h}
    return rep

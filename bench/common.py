"""Shared helpers of the benchmark suite (bench/run.py): paths, compilers, statistics."""

from __future__ import annotations

import json
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
GENERATED = ROOT / "generated" / "pneumatic_cylinder"
LOGS = Path(os.environ.get("FDIGEN_RIG_LOGS", ROOT.parent / "shared" / "rig" / "logs"))
FDI_LOGS = ("fdi_healthy", "fdi_actuator_loss", "fdi_blockage_p", "fdi_leak_p",
            "fdi_position_sensor_loss", "fdi_pressure_n_drift", "fdi_pressure_p_loss")
#: The log every timing runs on (20000 samples of the rig).
TIMING_LOG = "fdi_leak_p"

#: C flags of every timed C build: those of the shared library CFdi loads
#: (fdigen.backends.c.loader.SHARED_FLAGS without -fPIC -shared).
CFLAGS = ["-std=c99", "-O2", "-ffp-contract=off"]


_RIG_LOGS: dict = {}


def rig_log(model, name: str):
    """The rig log ``name`` (fdigen.sim.log.read_log of ``LOGS/<name>.csv``), read once
    per model and run: every section reads the same seven logs, several times."""
    from fdigen.sim.log import read_log

    key = (id(model), name)
    if key not in _RIG_LOGS:
        _RIG_LOGS[key] = (model, read_log(LOGS / f"{name}.csv", model))
    return _RIG_LOGS[key][1]


def use_generated(folder: Path) -> None:
    """Point every section at ``folder`` (``<out>/<model>`` of ``fdigen build --out``)
    instead of the repository's generated/ (bench/run.py builds it fresh)."""
    import bench_c
    global GENERATED
    GENERATED = bench_c.GENERATED = Path(folder)
    bench_c.GEN_C = GENERATED / "c"


def median(xs):
    return float(statistics.median(xs))


def spread(xs):
    """(min, max) of a sample, for the tables."""
    return float(min(xs)), float(max(xs))


def run(cmd, **kw):
    """subprocess.run that raises with the command's stderr."""
    kw.setdefault("capture_output", True)
    kw.setdefault("text", True)
    proc = subprocess.run([str(c) for c in cmd], **kw)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({proc.returncode}):\n"
                           f"{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")
    return proc


def compile_c(out: Path, sources, include=(), cc="gcc", flags=CFLAGS, extra=()):
    cmd = [cc, *flags, *extra, *(f"-I{i}" for i in include), "-o", out, *sources, "-lm"]
    run(cmd)
    return out


def tool_version(cmd) -> str:
    try:
        return subprocess.run(cmd, capture_output=True, text=True).stdout.splitlines()[0]
    except (OSError, IndexError):
        return "not available"


def machine() -> dict:
    """The machine: CPU model, cores, clock, memory, load, tool versions."""
    info = {"python": sys.version.split()[0], "platform": platform.platform()}
    try:
        lscpu = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
    except OSError:
        lscpu = ""
    fields = {}
    for line in lscpu.splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            fields[k.strip()] = v.strip()
    info["cpu_model"] = fields.get("Model name", platform.processor() or "unknown")
    if "CPU family" in fields:
        info["cpu_id"] = (f"family {fields['CPU family']} model {fields.get('Model', '?')} "
                          f"stepping {fields.get('Stepping', '?')}")
    flags = fields.get("Flags", "").split()
    info["simd"] = [f for f in ("avx2", "fma", "avx512f", "amx_tile") if f in flags]
    info["cpus"] = os.cpu_count()
    info["threads_per_core"] = fields.get("Thread(s) per core")
    info["hypervisor"] = fields.get("Hypervisor vendor")
    info["caches"] = {k: fields[k] for k in ("L1d cache", "L2 cache", "L3 cache")
                      if k in fields}
    mhz = None
    for key in ("CPU max MHz", "CPU MHz"):
        if key in fields:
            try:
                mhz = float(fields[key])
                break
            except ValueError:
                pass
    if mhz is None:
        try:
            vals = [float(m) for m in re.findall(r"cpu MHz\s*:\s*([\d.]+)",
                                                 Path("/proc/cpuinfo").read_text())]
            mhz = max(vals) if vals else None
            if mhz and fields.get("Hypervisor vendor"):
                info["ghz_source"] = "nominal, /proc/cpuinfo of the VM"
        except OSError:
            pass
    if mhz is None and "BogoMIPS" in fields:   # x86 VMs: BogoMIPS = 2 x TSC MHz
        try:
            mhz = float(fields["BogoMIPS"]) / 2
            info["ghz_source"] = "BogoMIPS / 2 (TSC; the VM hides the CPU clock)"
        except ValueError:
            pass
    info["ghz"] = None if mhz is None else round(mhz / 1000, 2)
    try:
        mem = Path("/proc/meminfo").read_text().split("\n", 1)[0]
        info["memory_gib"] = round(int(mem.split()[1]) / 2 ** 20, 1)
    except (OSError, IndexError, ValueError):
        pass
    info["gcc"] = tool_version(["gcc", "--version"])
    info["clang"] = tool_version(["clang", "--version"])
    info["arm_gcc"] = tool_version(["arm-none-eabi-gcc", "--version"])
    info["valgrind"] = tool_version(["valgrind", "--version"])
    import numpy
    info["numpy"] = numpy.__version__
    try:
        import casadi
        info["casadi"] = casadi.__version__
    except ImportError:
        pass
    return info


def load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


class Timer:
    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.s = time.perf_counter() - self.t0


def write_json(path: Path, obj) -> None:
    path.write_text(json.dumps(obj, indent=1, sort_keys=False, default=float) + "\n")


def have(tool: str) -> bool:
    return shutil.which(tool) is not None

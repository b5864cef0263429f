"""Same bytes on every machine: the built-in models built under different BLAS kernels.

OpenBLAS picks its kernels for the CPU at run time (``OPENBLAS_CORETYPE`` forces a choice);
their rounding differs in the last bits. Each kernel builds both built-in models in its own
process with a fresh design cache and a fresh output folder; the bytes must be identical
across kernels and equal to the committed ``generated/`` (docs/reproducibility.md).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("pneumatic_cylinder", "dc_motor")
IGNORED = {".fdigen-stamp", ".fdigen.lock"}   # a hash of the sources; the build lock

#: Kernels and the CPU flag each needs (a forced kernel the CPU lacks would crash).
KERNELS = {"Haswell": "avx2", "SkylakeX": "avx512f", "Prescott": "sse3"}

BUILD = r"""
import ctypes, glob, json, os, site, sys
from fdigen import pipeline

def corenames():
    # the kernel each OpenBLAS in use picked (numpy's and scipy's are separate builds)
    names = {}
    for sp in site.getsitepackages() + sys.path:
        for lib in glob.glob(os.path.join(sp, "*.libs", "lib*openblas*.so*")):
            dll = ctypes.CDLL(lib)
            for fn in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename",
                       "openblas_get_corename64_", "openblas_get_corename"):
                if hasattr(dll, fn):
                    f = getattr(dll, fn)
                    f.restype = ctypes.c_char_p
                    names[os.path.basename(lib)] = f().decode()
                    break
    return names

import numpy, scipy.linalg   # load both OpenBLAS builds
for model in sys.argv[2:]:
    pipeline.build(model, out_dir=sys.argv[1], force=True)
print(json.dumps(corenames()))
"""


def _cpu_flags() -> set:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


def _snapshot(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name not in IGNORED}


def test_builds_are_identical_across_blas_kernels_and_equal_the_committed(tmp_path):
    flags = _cpu_flags()
    kernels = [k for k, flag in KERNELS.items() if flag in flags]
    if len(kernels) < 2:
        pytest.skip(f"this CPU offers fewer than two of the kernels {list(KERNELS)}")
    procs = {}
    for kernel in kernels:
        env = dict(os.environ, OPENBLAS_CORETYPE=kernel,
                   FDIGEN_CACHE=str(tmp_path / f"cache-{kernel}"),
                   PYTHONPATH=str(ROOT / "src"), OMP_NUM_THREADS="1",
                   OPENBLAS_NUM_THREADS="1")
        out = tmp_path / f"out-{kernel}"
        procs[kernel] = (out, subprocess.Popen(
            [sys.executable, "-c", BUILD, str(out), *MODELS], cwd=tmp_path, env=env,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    cores = {}
    for kernel, (out, proc) in procs.items():
        stdout, stderr = proc.communicate(timeout=300)
        assert proc.returncode == 0, f"{kernel}: {stderr[-3000:]}"
        cores[kernel] = json.loads(stdout.strip().splitlines()[-1])
    # the forced kernel is the one in use, by numpy's and by scipy's OpenBLAS alike
    if all(cores.values()):
        picked = {k: set(v.values()) for k, v in cores.items()}
        assert all(len(v) == 1 for v in picked.values()), cores
        assert len({frozenset(v) for v in picked.values()}) == len(kernels), cores
    for model in MODELS:
        committed = _snapshot(ROOT / "generated" / model)
        assert committed, f"generated/{model} is not committed"
        for kernel, (out, _) in procs.items():
            built = _snapshot(out / model)
            differ = sorted(rel for rel in set(built) | set(committed)
                            if built.get(rel) != committed.get(rel))
            assert not differ, (f"{model} built with OpenBLAS {kernel} differs from the "
                                f"committed generated/{model}: {differ}")

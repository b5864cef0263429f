"""Whole-log processing from Python (item 2 of bench/run.py): CFdi.run and CasadiFdi
(compiled) on a long log in one call, against per-sample Python loops (ReferenceFdi.step,
the filterpy peer)."""

from __future__ import annotations

import ctypes
import resource
import time

import numpy as np

from common import FDI_LOGS, median, rig_log, spread


def long_log(model, samples: int):
    """``samples`` samples: the seven fdi_* rig logs one after the other, repeated."""
    us, ys = [], []
    for name in FDI_LOGS:
        log = rig_log(model, name)
        us.append(log.u)
        ys.append(log.y)
    u, y = np.vstack(us), np.vstack(ys)
    reps = -(-samples // len(u))
    return (np.ascontiguousarray(np.tile(u, (reps, 1))[:samples]),
            np.ascontiguousarray(np.tile(y, (reps, 1))[:samples]))


class _T(list):
    """Wall times of the repeats; ``.cpu`` the process CPU times (the loops are
    single-threaded: CPU time is what they cost when the shared machine is busy), split
    into ``.user`` and ``.sys`` (the kernel's: page faults of fresh arrays)."""


def _times(fn, repeats: int) -> _T:
    out = _T()
    out.cpu, out.user, out.sys = [], [], []
    for _ in range(repeats):
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
        out.cpu.append(time.process_time() - c0)
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        out.user.append(r1.ru_utime - r0.ru_utime)
        out.sys.append(r1.ru_stime - r0.ru_stime)
    return out


def _fresh_bytes(fn) -> int:
    """Peak bytes allocated during ``fn()`` (tracemalloc, which numpy reports to)."""
    import tracemalloc
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def _c_call_only(c, u, y):
    """The ctypes call of CFdi.run alone (outputs preallocated, no conversions)."""
    K = len(u)
    u = np.ascontiguousarray(u, dtype=c.dtype)
    y = np.ascontiguousarray(y, dtype=c.dtype)
    r = np.empty((K, c.nr), dtype=c.dtype)
    rms = np.empty((K, c.nr), dtype=c.dtype)
    aux = np.empty((K, c.naux), dtype=c.dtype)
    ints = [np.empty(K, dtype=np.int32) for _ in range(3)]
    faults = np.empty(K, dtype=np.int32)
    ip = ctypes.POINTER(ctypes.c_int32)

    def call():
        c.reset()
        c._fn("run")(ctypes.byref(c.state), ctypes.byref(c.params), K, c._ptr(u), c._ptr(y),
                     c._ptr(r), c._ptr(rms), *(a.ctypes.data_as(ip) for a in ints),
                     c._ptr(aux), faults.ctypes.data_as(ip))
    return call


def whole_log(model, design, samples: int, repeats: int, casadi_samples: int,
              casadi_repeats: int, loop_samples: int, loop_repeats: int, consts,
              log=print) -> dict:
    from fdigen.backends.c.loader import CFdi
    from fdigen.backends.reference import ReferenceFdi

    res = {"samples": samples}
    u, y = long_log(model, samples)
    c = CFdi(design)
    c.run(u[:1000], y[:1000])                       # warm-up (library loaded, pages touched)
    log(f"  CFdi.run on {samples} samples x {repeats} ...")
    t = _times(lambda: c.run(u, y), repeats)
    res["cfdi_run_s"] = median(t)
    res["cfdi_run_range"] = spread(t)
    res["cfdi_run_cpu_s"] = median(t.cpu)
    res["cfdi_run_user_s"] = median(t.user)
    res["cfdi_run_sys_s"] = median(t.sys)
    m = min(samples, 100_000)
    res["cfdi_run_alloc_bytes_per_sample"] = _fresh_bytes(lambda: c.run(u[:m], y[:m])) / m
    # only the decisions (flags, class, action): the C _run skips the other outputs
    t = _times(lambda: c.run(u, y, outputs=("flags", "fault_class", "action")), repeats)
    res["cfdi_run_decisions_only_s"] = median(t)
    res["cfdi_run_decisions_only_cpu_s"] = median(t.cpu)
    t = _times(_c_call_only(c, u, y), repeats)
    res["cfdi_c_call_only_s"] = median(t)
    res["cfdi_c_call_only_cpu_s"] = median(t.cpu)
    res["cfdi_ns_per_sample"] = res["cfdi_run_s"] / samples * 1e9
    res["cfdi_ns_per_sample_cpu"] = res["cfdi_run_cpu_s"] / samples * 1e9

    try:
        from fdigen.backends.casadi_backend.runner import CasadiFdi
        cas = CasadiFdi(design, compiled=True)
        cas.run(u[:2048], y[:2048])
        n = min(casadi_samples, samples)
        log(f"  CasadiFdi(compiled).run on {n} samples x {casadi_repeats} ...")
        t = _times(lambda: cas.run(u[:n], y[:n]), casadi_repeats)
        res["casadi_samples"] = n
        res["casadi_run_s_measured"] = median(t)
        res["casadi_run_range"] = spread(t)
        res["casadi_run_s"] = median(t) * samples / n     # scaled if fewer samples
        res["casadi_run_cpu_s"] = median(t.cpu) * samples / n
        res["casadi_run_user_s"] = median(t.user) * samples / n
        res["casadi_run_sys_s"] = median(t.sys) * samples / n
        res["casadi_run_cpu_all_s"] = [x * samples / n for x in t.cpu]
        m = min(n, 100_000)
        res["casadi_run_alloc_bytes_per_sample"] = _fresh_bytes(
            lambda: cas.run(u[:m], y[:m])) / m
        res["casadi_ns_per_sample"] = median(t) / n * 1e9
        res["casadi_ns_per_sample_cpu"] = median(t.cpu) / n * 1e9
        # agreement with the C core on the first chunk
        a, b = cas.run(u[:4096], y[:4096]), c.run(u[:4096], y[:4096])
        res["casadi_equals_c"] = bool(np.array_equal(a["flags"], b["flags"])
                                      and np.allclose(a["r"], b["r"], rtol=1e-9, atol=0))
    except Exception as exc:  # CasADi backend unavailable or broken: say so
        res["casadi_error"] = f"{type(exc).__name__}: {exc}"

    # per-sample Python loops
    n = loop_samples
    ref = ReferenceFdi(design)
    log(f"  ReferenceFdi.step loop on {n} samples x {loop_repeats} ...")

    def ref_loop():
        ref.reset()
        for k in range(n):
            ref.step(u[k], y[k])
    t = _times(ref_loop, loop_repeats)
    res["reference_us_per_sample"] = median(t) / n * 1e6
    res["reference_us_per_sample_cpu"] = median(t.cpu) / n * 1e6
    res["reference_range_us"] = [x / n * 1e6 for x in spread(t)]
    res["loop_samples"] = n
    try:
        from peers_filterpy import FilterpyFdi
        fp = FilterpyFdi(consts)
        log(f"  filterpy loop on {n} samples x {loop_repeats} ...")
        t = _times(lambda: fp.run(u[:n], y[:n]), loop_repeats)
        res["filterpy_us_per_sample"] = median(t) / n * 1e6
        res["filterpy_us_per_sample_cpu"] = median(t.cpu) / n * 1e6
        res["filterpy_range_us"] = [x / n * 1e6 for x in spread(t)]
        a, b = fp.run(u[:n], y[:n]), c.run(u[:n], y[:n])
        scale = np.maximum(np.abs(b["r"]).max(axis=0), np.asarray(consts["thresholds"]))
        res["filterpy_r_max_scaled_diff"] = float(
            (np.abs(a["r"] - b["r"]).max(axis=0) / np.maximum(scale, 1e-300)).max())
        res["filterpy_flags_identical"] = bool(np.array_equal(a["flags"], b["flags"]))
    except ImportError as exc:
        res["filterpy_error"] = f"{exc} (pip install -e '.[bench]')"
    # ratios: per-sample loop cost extrapolated to the whole log / the whole-log call;
    # "_cpu" from process CPU times (primary: the machine is shared), else wall times
    for tag, wall_key, cpu_key in (("cfdi", "cfdi_run_s", "cfdi_run_cpu_s"),
                                   ("casadi", "casadi_run_s", "casadi_run_cpu_s")):
        if wall_key not in res:
            continue
        for peer in ("reference", "filterpy"):
            if f"{peer}_us_per_sample" not in res:
                continue
            res[f"ratio_{peer}_vs_{tag}"] = (res[f"{peer}_us_per_sample"] * 1e-6 * samples
                                             / res[wall_key])
            res[f"ratio_{peer}_vs_{tag}_cpu"] = (res[f"{peer}_us_per_sample_cpu"] * 1e-6
                                                 * samples / res[cpu_key])
    return res

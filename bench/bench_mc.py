"""Monte Carlo throughput (item 5 of bench/run.py): closed-loop simulation
(fdigen.sim.plant.simulate) + the C FDI core (CFdi.run) per run, in-process and on a
Dask LocalCluster with one and with two worker processes."""

from __future__ import annotations

import os
import time

from common import median, spread

_CACHE: dict = {}


def _runner():
    if "runner" not in _CACHE:
        from fdigen.backends.c.loader import CFdi
        from fdigen.design.cache import cached_design
        from fdigen.model.model_file import load_model

        model = load_model()
        _CACHE["model"] = model
        _CACHE["runner"] = CFdi(cached_design(model))
    return _CACHE["model"], _CACHE["runner"]


def mc_task(seed: int, duration: float) -> dict:
    """One Monte Carlo run: simulate (healthy, noise seed ``seed``) and run the FDI."""
    from fdigen.sim.plant import simulate

    model, runner = _runner()
    c0, t0 = time.process_time(), time.perf_counter()
    sim = simulate(model, duration, seed=seed)
    t1 = time.perf_counter()
    out = runner.run(sim.u, sim.y)
    t2, c2 = time.perf_counter(), time.process_time()
    return {"samples": int(len(sim.t)), "simulate_s": t1 - t0, "fdi_s": t2 - t1,
            "cpu_s": c2 - c0, "max_rms0": float(out["rms"][:, 0].max())}


def warm(dask_worker=None):
    _runner()
    mc_task(0, 0.05)
    return os.getpid()


def _campaign(submit_all, runs, duration, seed0):
    t0 = time.perf_counter()
    results = submit_all([(seed0 + i, duration) for i in range(runs)])
    wall = time.perf_counter() - t0
    samples = sum(r["samples"] for r in results)
    return {"wall_s": wall, "samples": samples, "samples_per_s": samples / wall,
            "task_simulate_s": sum(r["simulate_s"] for r in results),
            "task_fdi_s": sum(r["fdi_s"] for r in results),
            "task_cpu_s": sum(r["cpu_s"] for r in results),
            "maxima": [r["max_rms0"] for r in results]}


def monte_carlo(runs: int, duration: float, repeats: int, log=print) -> dict:
    res = {"runs": runs, "duration_s": duration, "repeats": repeats,
           "loadavg_before": list(os.getloadavg())}
    warm()

    def local(args):
        return [mc_task(*a) for a in args]

    # where one simulate call goes: CasADi's mapaccum construction vs its evaluation
    import cProfile
    import pstats

    from fdigen.sim.plant import simulate
    model, _ = _runner()
    prof = cProfile.Profile()
    prof.enable()
    t0 = time.perf_counter()
    sim = simulate(model, duration, seed=77)
    wall = time.perf_counter() - t0
    prof.disable()
    st = pstats.Stats(prof)
    split = {"total_s": st.total_tt, "wall_s": wall, "samples": int(len(sim.t)),
             "mapaccum_construction_s": 0.0, "casadi_evaluation_s": 0.0}
    # cumulative time of the per-call work besides the CasADi evaluation
    named = {"lambdify": "lambdify_s", "model_hash": "model_hash_s",
             "reference_signal": "reference_signal_s", "_plant_runner": "plant_lookup_s"}
    for (f, _l, name), (_cc, _nc, tt, ct, _c) in st.stats.items():
        if "Function_mapaccum" in name:
            split["mapaccum_construction_s"] += tt
        elif "Function_call" in name:
            split["casadi_evaluation_s"] += tt
        elif name in named and ("fdigen" in f or "sympy" in f):
            split[named[name]] = split.get(named[name], 0.0) + ct
    top = sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:6]
    split["top_tottime"] = [{"function": f"{f.rsplit('/', 1)[-1]}:{line}({name})",
                             "tottime_s": v[2]} for (f, line, name), v in top]
    res["simulate_profile"] = split

    log(f"  in-process: {runs} runs x {duration:g} s, {repeats} repeats ...")
    rows = [_campaign(local, runs, duration, 100) for _ in range(repeats)]
    res["in_process"] = _summary(rows)
    try:
        import logging

        from distributed import Client, LocalCluster
    except ImportError as exc:
        res["dask_error"] = f"{exc} (pip install -e '.[bench]')"
        return res
    for workers in (1, 2):
        log(f"  Dask LocalCluster, {workers} worker process(es) ...")
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                          dashboard_address=":0", silence_logs=logging.ERROR) as cluster, \
                Client(cluster) as client:
            # workers are spawned with this process's sys.path: they import bench_mc
            client.run(warm)

            def submit_all(args):
                futs = [client.submit(mc_task, *a, pure=False) for a in args]
                return client.gather(futs)
            rows = [_campaign(submit_all, runs, duration, 100) for _ in range(repeats)]
            res[f"dask_{workers}"] = _summary(rows)
    res["speed_up_1_to_2_workers"] = res["dask_1"]["wall_s"] / res["dask_2"]["wall_s"]
    res["identical_results"] = (res["in_process"]["maxima"] == res["dask_1"]["maxima"]
                                == res["dask_2"]["maxima"])
    for k in ("in_process", "dask_1", "dask_2"):
        res[k].pop("maxima")
    res["loadavg_after"] = list(os.getloadavg())
    return res


def _summary(rows):
    walls = [r["wall_s"] for r in rows]
    mid = sorted(rows, key=lambda r: r["wall_s"])[len(rows) // 2]
    out = dict(mid)
    out["wall_s"] = median(walls)
    out["wall_range"] = spread(walls)
    out["samples_per_s"] = mid["samples"] / out["wall_s"]
    out["samples_per_cpu_s"] = mid["samples"] / mid["task_cpu_s"]
    return out

"""Throughput of the ``fdigen tune`` campaigns: samples per second per core, Dask speed-up.

Runs the same small healthy campaign (default 12 runs of 5 s: one simulation plus one C FDI
run per task) on

* a Dask ``LocalCluster`` with 1 worker process (1 thread), and
* a Dask ``LocalCluster`` with 2 worker processes (1 thread each),

both started and warmed up first (fdigen imported, C core compiled: not timed), then
*interleaved* ``--repeats`` times (1, 2, 1, 2, ...) so that load from other processes on
the machine hits both alike. Reported, in one run of this script:

* simulated samples per second per core: samples / wall time with 1 worker, and samples per
  CPU second of the tasks (``time.process_time`` in the worker: independent of how busy
  the machine is);
* the speed-up from 1 to 2 workers: ratio of the best wall times (and of the medians);
* the machine's load average before and after, to judge how much the cores were shared;
* that all schedulers return identical results (the in-process run is the reference).

Usage::

    python bench/tune_throughput.py [--runs 12] [--duration 5] [--repeats 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time


def _campaign(ex, design, cases, settle):
    t0 = time.perf_counter()
    res = ex.run(design, cases, settle, "bench")
    wall = time.perf_counter() - t0
    samples = sum(r["samples"] for r in res)
    cpu = sum(r["timing"]["simulate_cpu"] + r["timing"]["fdi_cpu"] for r in res)
    task = sum(r["timing"]["simulate"] + r["timing"]["fdi"] for r in res)
    return {"wall_s": wall, "samples": samples, "task_wall_s": task, "task_cpu_s": cpu,
            "maxima": [r["max_rms"] for r in res]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=12)
    ap.add_argument("--duration", type=float, default=5.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None, help="also write the numbers here")
    args = ap.parse_args(argv)

    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.tune import (NO_FLAG, CampaignExecutor, TuneSettings, design_with_thresholds,
                             make_cases)

    model = load_model()
    names = [n for n in cached_design(model).residual_names if n in model.fdi["thresholds"]]
    design = design_with_thresholds(model, {n: NO_FLAG for n in names})
    settings = TuneSettings(runs=args.runs, duration=args.duration, validation_runs=0,
                            faults=(), seed=11)
    cases = make_cases(model, settings)["healthy"]
    settle = design.config.window
    out = {"runs": args.runs, "duration": args.duration, "repeats": args.repeats,
           "cpus": os.cpu_count(), "loadavg_before": os.getloadavg()}

    with CampaignExecutor(scheduler="synchronous", progress=False) as ex:
        ex.warm_up(design)
        reference = _campaign(ex, design, cases, settle)
    out["in_process"] = {k: v for k, v in reference.items() if k != "maxima"}

    runs = {1: [], 2: []}
    identical = True
    with CampaignExecutor(1, progress=False) as one, CampaignExecutor(2, progress=False) as two:
        for ex in (one, two):
            ex.warm_up(design)
        for _ in range(args.repeats):
            for n, ex in ((1, one), (2, two)):
                r = _campaign(ex, design, cases, settle)
                identical &= r.pop("maxima") == reference["maxima"]
                runs[n].append(r)
    out["loadavg_after"] = os.getloadavg()
    samples = reference["samples"]
    for n in (1, 2):
        walls = [r["wall_s"] for r in runs[n]]
        out[f"dask_{n}_worker"] = {
            "wall_s": walls, "best_wall_s": min(walls), "median_wall_s": statistics.median(walls),
            "samples_per_s_wall_best": samples / min(walls),
            "samples_per_cpu_s": samples * len(walls) / sum(r["task_cpu_s"] for r in runs[n]),
            "task_wall_over_cpu": (sum(r["task_wall_s"] for r in runs[n])
                                   / sum(r["task_cpu_s"] for r in runs[n]))}
    one, two = out["dask_1_worker"], out["dask_2_worker"]
    out["samples_per_s_per_core"] = one["samples_per_s_wall_best"]
    out["samples_per_cpu_s"] = one["samples_per_cpu_s"]
    out["speed_up_1_to_2_workers_best"] = one["best_wall_s"] / two["best_wall_s"]
    out["speed_up_1_to_2_workers_median"] = one["median_wall_s"] / two["median_wall_s"]
    out["identical_results"] = identical

    ip = out["in_process"]
    print(f"campaign: {args.runs} healthy runs x {args.duration:g} s = {samples} samples, "
          f"{args.repeats} interleaved repeats; {out['cpus']} CPUs; load average before "
          f"{out['loadavg_before'][0]:.2f}, after {out['loadavg_after'][0]:.2f}")
    print(f"  in-process      wall {ip['wall_s']:6.2f} s  {samples / ip['wall_s']:8.0f} "
          f"samples/s  ({samples / ip['task_cpu_s']:.0f} per CPU s)")
    for n in (1, 2):
        r = out[f"dask_{n}_worker"]
        print(f"  dask {n} worker{'s' if n > 1 else ' '} wall "
              + ", ".join(f"{w:.2f}" for w in r["wall_s"])
              + f" s  best {r['samples_per_s_wall_best']:8.0f} samples/s  "
              f"({r['samples_per_cpu_s']:.0f} per CPU s; task wall/CPU "
              f"{r['task_wall_over_cpu']:.2f})")
    print(f"simulated samples per second per core: {out['samples_per_s_per_core']:.0f} "
          f"(1 worker, best wall; {out['samples_per_cpu_s']:.0f} per CPU second)")
    print(f"speed-up 1 -> 2 workers: {out['speed_up_1_to_2_workers_best']:.2f} (best), "
          f"{out['speed_up_1_to_2_workers_median']:.2f} (median)")
    print(f"results identical across schedulers: {identical}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return out


if __name__ == "__main__":
    main()

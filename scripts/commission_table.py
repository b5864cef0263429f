"""Commissioning on simulated rigs: quiet on fresh healthy runs, faults isolated.

For each rig (the model with library effects at their nominal sizes, alone or in pairs,
and the uncertain parameters off their datasheet values):

1. one healthy closed-loop run of ``--duration`` s is simulated (fdigen's simulator, the
   model's ``[simulation]`` loop and demand) and commissioned with
   :func:`fdigen.commission.commission` (default campaign unless told otherwise);
2. ``--fresh`` fresh healthy runs of the same rig (new noise seeds, demand scaled and
   shifted as in ``fdigen tune``) go through the commissioned C core: false alarms;
3. every fault of the model at its ``test_size`` (sensor offsets as ramps of test_size
   per second), onset in the middle of a run: detected? isolated to its class? delays.

Prints a markdown table (pasted into ``docs/commission.md``). Usage::

    python scripts/commission_table.py [--model pneumatic_cylinder]
        [--rigs coulomb_friction,external_load,coulomb_friction+external_load,...]
        [--duration 20] [--fresh 10] [--runs 40] [--workers 2]

A rig takes about 2-3 minutes on the shared 2-core machine (the commissioning campaigns).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path


def rig_runs(model, effects, params, args):
    """Fresh healthy runs and one run per fault of the rig; returns the simulations."""
    import dataclasses

    import numpy as np

    from fdigen.sim.plant import FaultEvent, simulate
    from fdigen.tune.cases import demand_expression

    rng = np.random.default_rng(1234)
    runs = []
    for k in range(args.fresh):
        ref = demand_expression(model, float(rng.uniform(0.8, 1.1)),
                                float(rng.uniform(0, 100)))
        m = dataclasses.replace(model, simulation={**model.simulation, "reference": ref})
        runs.append(("healthy", None, simulate(m, args.duration, effects=effects,
                                               parameters=params, seed=1000 + k)))
    for j, f in enumerate(model.faults):
        ramp = f.location == "sensor" and f.mode == "additive"
        t0 = 0.5 * args.duration
        ev = FaultEvent(f.name, t0, f.test_size, ramp)
        runs.append((f.name, t0, simulate(model, args.duration, effects=effects,
                                          parameters=params, seed=2000 + j, faults=(ev,))))
    return runs


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--model", default="pneumatic_cylinder")
    p.add_argument("--rigs", default="none,coulomb_friction,external_load,leak_n,cross_leak,"
                   "valve_deadband,sensor_offset_pp,coulomb_friction+external_load")
    p.add_argument("--duration", type=float, default=20.0)
    p.add_argument("--fresh", type=int, default=10)
    p.add_argument("--runs", type=int, default=40)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--json-out", default=None)
    args = p.parse_args(argv)

    import numpy as np

    from fdigen.commission.pipeline import CommissionSettings, commission
    from fdigen.design.cache import cached_design
    from fdigen.detect import fdi_runner
    from fdigen.discover import effects as fx
    from fdigen.model.model_file import load_model
    from fdigen.sim.log import write_log
    from fdigen.sim.plant import simulate

    model = load_model(args.model)
    rng = np.random.default_rng(7)
    rows, out = [], []
    for spec in args.rigs.split(","):
        t_rig = time.perf_counter()
        names = [] if spec == "none" else spec.split("+")
        effects = []
        for n in names:
            effects.extend(fx.get_effect(n, model).plant_effects(model))
        params = {q.name: float(q.value * (1 + rng.uniform(-0.08, 0.08)))
                  for q in model.parameters if q.uncertain}
        tmp = Path(tempfile.mkdtemp(prefix="fdigen-comm-table-"))
        sim = simulate(model, args.duration, effects=tuple(effects), parameters=params,
                       seed=17)
        write_log(tmp / "healthy.csv", sim.columns())
        res = commission(tmp / "healthy.csv", model.source, out=tmp / "c",
                         settings=CommissionSettings(runs=args.runs), workers=args.workers,
                         build=False)
        design = cached_design(load_model(res["model_file"]))
        ev = design.evaluation
        runner = fdi_runner(design, "c")
        fa, faults = 0, {}
        for kind, t0, s in rig_runs(model, tuple(effects), params, args):
            o = runner.run(s.u, s.y)
            flags = np.asarray(o["flags"], dtype=np.int64)
            cls = np.asarray(o["fault_class"], dtype=np.int64)
            if kind == "healthy":
                fa += bool(flags.any())
                continue
            k0 = int(np.searchsorted(s.t, t0))
            on = np.flatnonzero(flags)
            iso = np.flatnonzero(cls > 0)
            want = model.fault(kind).fault_class
            faults[kind] = {
                "detected": bool(on.size and on[0] >= k0),
                "early_flag": bool(on.size and on[0] < k0),
                "isolated": ev.classes[int(cls[iso[0]])] if iso.size else "none",
                "correct": bool(iso.size and iso[0] >= k0
                                and ev.classes[int(cls[iso[0]])] == want),
                "detection_delay": float(s.t[on[0]] - t0) if on.size else None,
                "isolation_delay": float(s.t[iso[0]] - t0) if iso.size else None}
        ok = sum(f["correct"] for f in faults.values())
        dd = [f["detection_delay"] for f in faults.values() if f["detection_delay"] is not None
              and f["detected"]]
        di = [f["isolation_delay"] for f in faults.values() if f["correct"]]
        row = {"rig": spec, "found": res["effects"], "fresh_false_alarms": fa,
               "fresh_runs": args.fresh, "isolated": ok, "faults": len(faults),
               "median_detection": float(np.median(dd)) if dd else None,
               "median_isolation": float(np.median(di)) if di else None,
               "missed": [k for k, f in faults.items() if not f["correct"]],
               "details": faults, "raised": list(res["raised"]),
               "seconds": time.perf_counter() - t_rig}
        out.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "details"}, default=float),
              flush=True)
    print()
    print("| rig | found | false alarms (fresh) | faults isolated | median detection [s] "
          "| median isolation [s] | not isolated |")
    print("|---|---|---|---|---|---|---|")
    for r in out:
        md = "-" if r["median_detection"] is None else f"{r['median_detection']:.3g}"
        mi = "-" if r["median_isolation"] is None else f"{r['median_isolation']:.3g}"
        print(f"| {r['rig']} | {', '.join(r['found']) or 'none'} | {r['fresh_false_alarms']}"
              f"/{r['fresh_runs']} | {r['isolated']}/{r['faults']} | {md} | {mi} | "
              f"{', '.join(r['missed']) or '-'} |")
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()

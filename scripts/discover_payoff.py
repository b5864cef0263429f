"""Does `fdigen discover` pay off in detection? Thresholds and delays before and after.

The loop: a log that carries an effect the model lacks (default the reference rig's
``discrepancy_coulomb.csv``: Coulomb friction 35 N, datasheet ``Ff`` and ``K`` off) goes
through ``fdigen discover``, which writes the augmented model file. Then the *same*
Monte Carlo campaign (``fdigen tune``: healthy runs for the thresholds, fresh healthy
runs for the false-alarm check, a fault campaign for the delays) is run twice on the
plant that carries the effect (the model file + the effect at its true size, parameter
spread +-10 %, same seeds, same runs):

* **before**: the original model's design, its thresholds tuned again on that plant;
* **after**: the augmented model's design, tuned on the same runs.

Printed as markdown (pasted into ``docs/discover.md``), and the whole report as JSON
with ``--json-out``. Usage::

    python scripts/discover_payoff.py [--log LOG.csv] [--effect coulomb_friction=35]
        [--runs 20] [--duration 10] [--validation-runs 5] [--fault-sizes 0.5,1]
        [--workers 2] [--json-out payoff.json]

The defaults take a few minutes on two cores (about 90 runs of 10 s, two design
derivations per model).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RIG_LOG = ROOT.parent / "shared" / "rig" / "logs" / "discrepancy_coulomb.csv"


def _truth_effects(model, spec: str | None, log: Path):
    """The plant's effect: ``NAME=VALUE`` or the rig log's ground truth (Coulomb)."""
    from fdigen.discover.effects import get_effect

    if spec:
        name, value = spec.split("=")
        e = get_effect(name.strip(), model)
        return e.plant_effects(model, {e.parameters[0].name: float(value)}), spec
    truth = json.loads(log.with_suffix(".json").read_text())["truth"]
    e = get_effect("coulomb_friction", model)
    return e.plant_effects(model, {"Fc": float(truth["Fc"])}), f"coulomb_friction={truth['Fc']}"


def payoff(log: Path, effect: str | None, settings, workers: int, out: Path, say=print):
    """Run discover, then the two tuning campaigns; return the report (a dict)."""
    from fdigen.discover.pipeline import discover
    from fdigen.model.model_file import load_model
    from fdigen.tune import tune

    nominal = load_model()
    t0 = time.perf_counter()
    res = discover(log, out=out, build=False, fdi=False, plot=False).as_dict()
    say(f"discover: {res['effects']} in {res['equation']}, parameters {res['parameters']}")
    if not res.get("model_file"):
        raise SystemExit("discover found no effect: nothing to compare")
    effects, label = _truth_effects(nominal, effect, log)
    say(f"plant: {nominal.name} + {label}")
    reports = {}
    for key, model in (("before", None), ("after", res["model_file"])):
        say(f"tuning the {key} design ({model or nominal.name})")
        reports[key] = tune(model, settings, workers=workers, plant=nominal,
                            plant_effects=effects, progress=False, log=say)
    return {"log": str(log), "plant_effect": label, "discover": {
        k: res[k] for k in ("equation", "effect", "parameters", "uncertainty",
                            "error_before", "error_after", "validation")},
        "before": reports["before"], "after": reports["after"],
        "seconds": time.perf_counter() - t0}


def _g(v, fmt=".3g"):
    return "-" if v is None else format(v, fmt)


def markdown(rep: dict) -> str:
    """The tables pasted into ``docs/discover.md``."""
    b, a = rep["before"], rep["after"]
    s = b["settings"]
    lines = [f"Plant: `{b['model']}` + `{rep['plant_effect']}`; discovered "
             f"`{rep['discover']['effect']}` "
             + ", ".join(f"{k} = {v:.4g}" for k, v in rep["discover"]["parameters"].items())
             + f". Campaign: {s['runs']} healthy runs of {s['duration']:g} s "
             f"(+-{100 * s['tolerance']:g} % on {', '.join(s['uncertain_parameters'])}, "
             f"demand varied), target {100 * s['false_alarm_rate']:g} % false alarms per "
             f"run, margin {s['margin']:g}; {s['validation_runs']} fresh healthy runs; every "
             f"fault at {', '.join(f'{k:g}' for k in s['fault_factors'])} x its test size.",
             "", "| residual | threshold before | threshold after | after / before |",
             "|---|---|---|---|"]
    for n in b["residuals"]:
        tb, ta = b["thresholds"][n], a["thresholds"][n]
        kept = " (kept)" if n in s["keep"] else ""
        lines.append(f"| {n}{kept} | {_g(tb)} | {_g(ta)} | {_g(ta / tb, '.2f')} |")
    fb, fa = b["false_alarm"], a["false_alarm"]
    lines += ["", f"False alarms on the fresh healthy runs: before "
              f"{fb['validation_false_alarms']}/{fb['validation_runs']}, after "
              f"{fa['validation_false_alarms']}/{fa['validation_runs']}.", "",
              "| fault | detected before | detected after | median delay before [s] | "
              "median delay after [s] | correctly isolated before | after |",
              "|---|---|---|---|---|---|---|"]
    for name, eb in b["faults"].items():
        ea = a["faults"][name]
        lines.append(
            f"| {name} | {eb['detected']}/{eb['runs']} | {ea['detected']}/{ea['runs']} | "
            f"{_g(eb['detection_delay']['median'])} | {_g(ea['detection_delay']['median'])} | "
            f"{eb['isolated_correct']}/{eb['runs']} | {ea['isolated_correct']}/{ea['runs']} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    from fdigen.tune import TuneSettings

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--log", type=Path, default=None,
                    help="log carrying the effect (default: the rig's Coulomb log, or a "
                         "simulated one if the rig logs are absent)")
    ap.add_argument("--effect", default=None, help="plant effect NAME=VALUE (default: the "
                    "rig log's ground truth, Coulomb friction)")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--validation-runs", type=int, default=5)
    ap.add_argument("--fault-sizes", default="0.5,1")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json-out", type=Path, default=None)
    args = ap.parse_args(argv)
    out = Path(tempfile.mkdtemp(prefix="fdigen-payoff-"))
    log = args.log
    if log is None and RIG_LOG.is_file():
        log = RIG_LOG
    if log is None:
        from fdigen.discover.effects import get_effect
        from fdigen.model.model_file import load_model
        from fdigen.sim.log import write_log
        from fdigen.sim.plant import simulate

        m = load_model()
        spec = args.effect or "coulomb_friction=35"
        name, value = spec.split("=")
        e = get_effect(name, m)
        sim = simulate(m, 20.0, effects=e.plant_effects(m, {e.parameters[0].name:
                                                            float(value)}),
                       parameters={"Ff": 96.0, "K": 1.03e-3}, seed=7, substeps=4)
        log = out / f"{name}.csv"
        write_log(log, sim.columns())
        args.effect = spec
    settings = TuneSettings(runs=args.runs, duration=args.duration,
                            validation_runs=args.validation_runs,
                            fault_factors=tuple(float(v) for v in args.fault_sizes.split(",")),
                            fault_starts=1, seed=args.seed, keep=("w1", "w2", "w3"))
    rep = payoff(log, args.effect, settings, args.workers, out,
                 say=lambda m: print(m, file=sys.stderr))
    if args.json_out:
        args.json_out.write_text(json.dumps(rep, indent=1, default=float) + "\n")
    print(markdown(rep))
    print(f"({rep['seconds']:.0f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

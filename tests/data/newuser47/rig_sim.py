"""The 'real rig': a building zone the tool does not know.

Two-node RC zone (room air Ta + hidden heavy slab/wall Ts), hydronic radiator
Q = UA * valve * (Tsup - Ta), PI thermostat (0..1, conditional integration) with
night setback, outdoor temperature daily sine, UNDECLARED solar gain (daytime bell,
cloudiness per day).  Sensors: room in degF (0.1 degF quantised + noise), supply water
in degC, outdoor in degC.  5-minute samples, a few dropped rows, one duplicated row.

usage: python rig_sim.py OUT.csv [--days 3] [--seed 0] [--fault none|stuck|drift|fouling]
                                 [--t0 86400] [--no-defects] [--no-units]
"""
import argparse
import json

import numpy as np

TRUTH = dict(
    Ca=3.0e6,      # J/K  room air + furniture
    Cs=3.0e7,      # J/K  heavy slab / walls (hidden)
    Has=250.0,     # W/K  air <-> slab
    Hao=40.0,      # W/K  air -> outdoor (windows, infiltration)
    Hso=35.0,      # W/K  slab -> outdoor
    UA=60.0,       # W/K  radiator at full valve
    Qsol_peak=900.0,  # W   solar gain peak (NOT in the model)
)
DT = 300.0          # s sample time
SUB = 10            # RK4 sub-steps per sample


def outdoor(t):
    h = (t / 3600.0) % 24.0
    return 2.0 - 5.0 * np.cos(2 * np.pi * (h - 3.0) / 24.0)   # min 3 h, max 15 h


def supply(t, To):
    # outdoor reset curve + slow boiler wander
    return 50.0 - 1.0 * To + 1.5 * np.sin(2 * np.pi * t / 5400.0)


def solar(t, cloud):
    h = (t / 3600.0) % 24.0
    day = int(t // 86400)
    return TRUTH["Qsol_peak"] * cloud[day % len(cloud)] * np.exp(-((h - 13.0) / 2.5) ** 2) * (7 < h < 19)


def setpoint(t):
    h = (t / 3600.0) % 24.0
    return 21.0 if 6.0 <= h < 22.0 else 18.0


def f(x, v_eff, Tsup, To, Qs, ua_scale):
    Ta, Ts = x
    Q = ua_scale * TRUTH["UA"] * v_eff * (Tsup - Ta)
    dTa = (Q - TRUTH["Has"] * (Ta - Ts) - TRUTH["Hao"] * (Ta - To) + Qs) / TRUTH["Ca"]
    dTs = (TRUTH["Has"] * (Ta - Ts) - TRUTH["Hso"] * (Ts - To)) / TRUTH["Cs"]
    return np.array([dTa, dTs])


def run(days=3.0, seed=0, fault="none", t0=86400.0, defects=True, solar_on=True):
    rng = np.random.default_rng(seed)
    cloud = rng.uniform(0.5, 1.0, size=10) if solar_on else np.zeros(10)
    n = int(round(days * 86400 / DT))
    x = np.array([20.5, 19.0])          # start slightly off
    kp, ki = 0.35, 0.35 / 3600.0       # 1/K, 1/(K s)
    I = 0.4 / ki                        # integrator preload (valve ~0.4)
    rows = []
    h = DT / SUB
    for k in range(n):
        t = k * DT
        To = outdoor(t)
        Tsup = supply(t, To)
        # sensors
        drift = 0.0
        if fault == "drift" and t >= t0:
            drift = 0.5 * (t - t0) / 3600.0       # degF
        TaF_true = 1.8 * x[0] + 32.0
        yF = np.round((TaF_true + drift + rng.normal(0, 0.1)) * 10.0) / 10.0
        ysup = Tsup + rng.normal(0, 0.2)
        yout = To + rng.normal(0, 0.2)
        # PI thermostat on the measured room temperature (degC)
        sp = setpoint(t)
        e = sp - (yF - 32.0) / 1.8
        u_un = kp * e + ki * I
        u = min(max(u_un, 0.0), 1.0)
        if not ((u_un >= 1.0 and e > 0) or (u_un <= 0.0 and e < 0)):
            I += e * DT
        rows.append((t, u, ysup, yout, yF, sp))
        # plant over one sample (valve held)
        v_eff = u
        ua_scale = 1.0
        if fault == "stuck" and t >= t0:
            v_eff = 0.3
        if fault == "fouling" and t >= t0:
            ua_scale = 0.6
        for s in range(SUB):
            ts = t + s * h
            args = lambda tt: (v_eff, supply(tt, outdoor(tt)), outdoor(tt), solar(tt, cloud), ua_scale)
            k1 = f(x, *args(ts))
            k2 = f(x + h / 2 * k1, *args(ts + h / 2))
            k3 = f(x + h / 2 * k2, *args(ts + h / 2))
            k4 = f(x + h * k3, *args(ts + h))
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    rows = np.array(rows)
    info = {"dropped": [], "duplicated": None}
    if defects and n > 20:
        drop = sorted(rng.choice(np.arange(5, n - 5), size=4, replace=False).tolist())
        keep = np.setdiff1d(np.arange(n), drop)
        dup = int(rng.choice(keep[5:-5]))
        out = []
        for i in keep:
            out.append(rows[i])
            if i == dup:
                out.append(rows[i])
        rows = np.array(out)
        info = {"dropped_rows_t": [float(d * DT) for d in drop], "duplicated_t": float(dup * DT)}
    return rows, cloud, info


def main():
    p = argparse.ArgumentParser()
    p.add_argument("out")
    p.add_argument("--days", type=float, default=3.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--fault", default="none")
    p.add_argument("--t0", type=float, default=86400.0)
    p.add_argument("--no-defects", action="store_true")
    p.add_argument("--no-units", action="store_true")
    p.add_argument("--no-solar", action="store_true")
    a = p.parse_args()
    rows, cloud, info = run(a.days, a.seed, a.fault, a.t0, not a.no_defects, not a.no_solar)
    with open(a.out, "w") as fh:
        fh.write("t,valve,Tsup,Tout,Troom_F,Tset_ref\n")
        if not a.no_units:
            fh.write("s,-,degC,degC,degF,degC\n")
        for r in rows:
            fh.write(f"{r[0]:.0f},{r[1]:.5f},{r[2]:.3f},{r[3]:.3f},{r[4]:.1f},{r[5]:.1f}\n")
    truth = dict(TRUTH, seed=a.seed, fault=a.fault, t0=a.t0 if a.fault != "none" else None,
                 cloud=cloud[: int(np.ceil(a.days))].tolist(), solar=not a.no_solar, **info)
    with open(a.out.rsplit(".", 1)[0] + ".truth.json", "w") as fh:
        json.dump(truth, fh, indent=1)
    print(f"wrote {len(rows)} rows to {a.out}; {info}")


if __name__ == "__main__":
    main()

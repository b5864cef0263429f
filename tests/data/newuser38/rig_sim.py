"""Water rig simulator (the 'truth'), independent of fdigen.

Tank 1 fed by a variable-speed pump, Torricelli outflow to tank 2, tank 2 drains
through a valve (Torricelli).  PI loop on tank-2 level drives the pump (percent).
Rig effects a simple model lacks:
  * pump flow 12 % below datasheet
  * small constant leak from tank 1 (1.5 cm^3/s)
  * level-sensor lag (first order, 2 s) on both transmitters
  * sensor noise and quantisation (ADC step)
Instruments: levels as 4-20 mA (4 mA = 0 cm, 20 mA = 50 cm), pump command in %,
time stamps with jitter, Ts = 0.5 s, a few NaN dropouts.
"""
import json
import sys

import numpy as np

# --- datasheet values (the user's model uses these) -------------------------
A1 = 80.0      # cm^2
A2 = 80.0      # cm^2
a1 = 0.30      # cm^2 effective orifice T1 -> T2
a2 = 0.25      # cm^2 effective drain valve orifice of T2
g = 981.0      # cm/s^2
Kq = 160.0     # cm^3/s pump flow at 100 % speed, zero head
Kh = 0.5       # cm^2/s head term: flow lost per cm of level in T1
HMAX = 50.0

# --- what the rig really has ---------------------------------------------------
PUMP_FACTOR = 0.88        # pump delivers 12 % less than datasheet
LEAK = 1.5                # cm^3/s constant leak out of tank 1
TAU_S = 2.0               # s, level transmitter lag
NOISE_MA = 0.02           # mA noise std (~0.06 cm)
Q_MA = 16.0 / 4096        # mA, 12-bit ADC step over 16 mA span
TS = 0.5
JITTER = 0.01             # s std of time stamp jitter

KP, KI = 2.0, 0.03        # PI on tank 2 level, %/cm and %/(cm s)


def pump_flow(u, h1, wear=0.0):
    q = PUMP_FACTOR * (1.0 - wear) * (Kq * (u / 100.0) ** 2 - Kh * h1)
    return max(q, 0.0)


def simulate(setpoints, step_len, seed, fault=None, t_fault=None, out=None):
    rng = np.random.default_rng(seed)
    n = int(len(setpoints) * step_len / TS)
    sub = 20
    dt = TS / sub
    h1, h2 = 14.0, 20.0
    m1, m2 = h1, h2           # lagged sensor states
    integ = 0.0
    u = 60.0
    rows = []
    stuck_val = None
    truth = {"fault": fault, "t0": t_fault, "effects": {
        "pump_factor": PUMP_FACTOR, "leak_cm3_s": LEAK, "sensor_lag_s": TAU_S,
        "noise_mA": NOISE_MA, "quant_mA": Q_MA}}
    # start the integrator near the steady command for the first setpoint
    integ = 63.0 / KI
    for k in range(n):
        t = k * TS
        ref = setpoints[min(int(t // step_len), len(setpoints) - 1)]
        # measurement (sensor lag state -> mA, noise, quantisation)
        y1 = 4.0 + 16.0 * m1 / 50.0 + rng.normal(0, NOISE_MA)
        y2 = 4.0 + 16.0 * m2 / 50.0 + rng.normal(0, NOISE_MA)
        y1 = np.round(y1 / Q_MA) * Q_MA
        y2 = np.round(y2 / Q_MA) * Q_MA
        if fault == "stuck1" and t >= t_fault:
            if stuck_val is None:
                stuck_val = y1
            y1 = stuck_val
        # PI on measured level 2 (converted back to cm)
        h2m = (y2 - 4.0) * 50.0 / 16.0
        e = ref - h2m
        u_unsat = KP * e + KI * integ
        u = min(max(u_unsat, 0.0), 100.0)
        if not ((u >= 100.0 and e > 0) or (u <= 0.0 and e < 0)):
            integ += e * TS
        wear = 0.30 if (fault == "pump_wear" and t >= t_fault) else 0.0
        leak_f = 0.0
        if fault == "leak_grow" and t >= t_fault:
            leak_f = 0.02 * (t - t_fault)    # cm^3/s, grows 0.02 cm^3/s per s
        # integrate plant over one sample, command held
        for _ in range(sub):
            qp = pump_flow(u, h1, wear)
            q12 = a1 * np.sqrt(2 * g * max(h1, 0.0))
            q20 = a2 * np.sqrt(2 * g * max(h2, 0.0))
            leak = (LEAK + leak_f) if h1 > 0 else 0.0
            dh1 = (qp - q12 - leak) / A1
            dh2 = (q12 - q20) / A2
            h1 = min(max(h1 + dt * dh1, 0.0), HMAX)
            h2 = min(max(h2 + dt * dh2, 0.0), HMAX)
            m1 += dt * (h1 - m1) / TAU_S
            m2 += dt * (h2 - m2) / TAU_S
        ts = t + rng.normal(0, JITTER)
        rows.append([ts, round(u, 3), y1, y2, ref])
    rows = np.array(rows)
    # a few NaN dropouts (single samples and one pair)
    for idx in rng.choice(np.arange(50, n - 50), 5, replace=False):
        col = rng.integers(2, 4)
        rows[idx, col] = np.nan
        if rng.random() < 0.3:
            rows[idx + 1, col] = np.nan
    if out:
        with open(out, "w") as f:
            f.write("t,pump,L1,L2,h2_ref\n")
            for r in rows:
                f.write("%.3f,%.3f,%s,%s,%.1f\n" % (
                    r[0], r[1],
                    "nan" if np.isnan(r[2]) else "%.4f" % r[2],
                    "nan" if np.isnan(r[3]) else "%.4f" % r[3], r[4]))
        with open(out.replace(".csv", ".json"), "w") as f:
            json.dump(truth, f, indent=1)
    return rows


if __name__ == "__main__":
    step = 150.0
    sp_comm = [20, 25, 15, 22, 18, 26, 20]       # 1050 s
    sp_val = [18, 23, 28, 16, 21, 24, 19]
    simulate(sp_comm, step, 1, out="healthy_commission.csv")
    simulate(sp_val, step, 2, out="healthy_validation.csv")
    sp_f = [20, 24, 17, 22, 19, 23, 20]
    simulate(sp_f, step, 3, fault="leak_grow", t_fault=500.0, out="fault_leak_grow.csv")
    simulate(sp_f, step, 4, fault="stuck1", t_fault=500.0, out="fault_stuck_L1.csv")
    simulate(sp_f, step, 5, fault="pump_wear", t_fault=500.0, out="fault_pump_wear.csv")

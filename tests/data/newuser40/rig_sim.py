"""Rig simulator: 200 L domestic hot-water tank, three stratified layers, 3 kW element
(rated) switched by a hysteresis thermostat, cold inlet at the bottom, draw-off at the top.

What the rig has that the user's (fully mixed) model lacks:
  * 3 stratified layers with buoyant mixing (user: one mixed volume)
  * element power 8 % below rating (2760 W instead of 3000 W)
  * thermostat PT100 in a thermowell, 30 s first-order lag
  * standby loss 40 % above the datasheet (2.1 W/K instead of 1.5 W/K)
  * temperatures quantised to 0.1 K, logged as PT100 resistance R = 100*(1+3.85e-3*T)
  * flow meter quantised to 0.1 L/min
  * 5 s sampling, a few duplicated and missing rows
Faults: element half power (one coil burnt), gain drift of the top PT100 reading,
leaking check valve (unmetered cold flow through the tank).
"""
import json
import sys

import numpy as np

CP = 4186.0
V_LAYERS = np.array([70.0, 70.0, 60.0])        # bottom, middle, top [L]
C_LAYERS = V_LAYERS * CP                      # J/K
P_RATED = 3000.0
P_TRUE = 0.92 * P_RATED                       # element 8 % below rating
UA_DATASHEET = 1.5                            # W/K
UA_TRUE = 1.4 * UA_DATASHEET                  # 40 % higher standby loss
UA_SPLIT = np.array([0.3, 0.3, 0.4])          # top loses more (lid)
T_COLD = 12.0
T_ROOM = 20.0
K_MIX = 1500.0                                # W/K buoyant mixing when unstable
K_COND = 3.0                                  # W/K conduction between layers
TAU_WELL = 30.0                               # s, thermowell lag (middle sensor)
T_ON, T_OFF = 55.0, 60.0                      # thermostat hysteresis on middle sensor
TS = 5.0


def draw_profile(duration, seed):
    """Daily-like draw events compressed into `duration` s: list of (start, length, L/min)."""
    rng = np.random.default_rng(seed)
    events = []
    t = 600.0
    while t < duration - 900:
        kind = rng.choice(["tap", "kitchen", "shower", "bath"], p=[0.5, 0.25, 0.2, 0.05])
        if kind == "tap":
            length, q = rng.uniform(20, 90), rng.uniform(3, 5)
        elif kind == "kitchen":
            length, q = rng.uniform(60, 180), rng.uniform(5, 7)
        elif kind == "shower":
            length, q = rng.uniform(300, 600), rng.uniform(7, 9)
        else:
            length, q = rng.uniform(480, 720), rng.uniform(10, 12)
        events.append((t, length, q))
        t += length + rng.exponential(1500.0) + 120
    return events


def simulate(duration, seed, fault=None, t_fault=None, fault_size=None, T_init=(50.0, 57.0, 59.0)):
    rng = np.random.default_rng(seed + 1000)
    events = draw_profile(duration, seed)
    dt = 0.5
    n = int(duration / dt)
    T = np.array(T_init, dtype=float)
    Tw = T[1]
    e = 0
    rows = []
    for k in range(n + 1):
        t = k * dt
        q = 0.0
        for (s, L, qq) in events:
            if s <= t < s + L:
                q = qq
        active = fault is not None and t >= t_fault
        # thermostat reads its (lagged) sensor
        if Tw < T_ON:
            e = 1
        elif Tw > T_OFF:
            e = 0
        if k % int(TS / dt) == 0:
            # top sensor reading (fast, immersed) with gain drift fault
            Rtop = 100 * (1 + 3.85e-3 * (round((T[2] + rng.normal(0, 0.03)) * 10) / 10))
            Rmid = 100 * (1 + 3.85e-3 * (round((Tw + rng.normal(0, 0.03)) * 10) / 10))
            if active and fault == "sensor_drift":
                gain = fault_size * min(1.0, (t - t_fault) / 1800.0)   # ramps over 30 min
                Rtop = Rtop * (1 + gain)
            qm = round(q * 10) / 10
            rows.append((t, e, qm, Rtop, Rmid))
        P = P_TRUE * e
        if active and fault == "element_half":
            P *= 0.5
        m = (q + (fault_size if active and fault == "check_valve" else 0.0)) / 60.0  # kg/s
        dT = np.zeros(3)
        # through-flow: cold into bottom, bottom->middle->top, top out
        dT[0] += m * CP * (T_COLD - T[0])
        dT[1] += m * CP * (T[0] - T[1])
        dT[2] += m * CP * (T[1] - T[2])
        dT[0] += P
        dT -= UA_TRUE * UA_SPLIT * (T - T_ROOM)
        for i in range(2):
            k_ex = K_MIX if T[i] > T[i + 1] else K_COND
            Q = k_ex * (T[i] - T[i + 1])
            dT[i] -= Q
            dT[i + 1] += Q
        T = T + dt * dT / C_LAYERS
        Tw = Tw + dt * (T[1] - Tw) / TAU_WELL
    return rows, events


def write_log(path, rows, seed, truth):
    rng = np.random.default_rng(seed + 7)
    out = []
    for r in rows:
        u = rng.random()
        if u < 0.004:
            continue                       # missing row
        out.append(r)
        if u > 0.997:
            out.append(r)                  # duplicated row
    with open(path, "w") as f:
        f.write("t,element,flow,R_top,R_mid\n")
        for (t, e, q, a, b) in out:
            f.write(f"{t:.1f},{e:d},{q:.1f},{a:.4f},{b:.4f}\n")
    with open(path.replace(".csv", ".json"), "w") as f:
        json.dump(truth, f, indent=1)
    return len(out)


if __name__ == "__main__":
    outdir = sys.argv[1] if len(sys.argv) > 1 else "."
    truth_common = dict(P_true=P_TRUE, P_rated=P_RATED, UA_true=UA_TRUE, UA_datasheet=UA_DATASHEET,
                        layers=V_LAYERS.tolist(), tau_well=TAU_WELL, T_cold=T_COLD, T_room=T_ROOM,
                        thermostat=[T_ON, T_OFF], sample_time=TS)
    specs = [
        ("commission_healthy", 8 * 3600, 1, None, None, None),
        ("validate_healthy", 6 * 3600, 2, None, None, None),
        ("fault_element_half", 6 * 3600, 3, "element_half", 3 * 3600, 0.5),
        ("fault_sensor_drift", 6 * 3600, 4, "sensor_drift", 3 * 3600, 0.02),
        ("fault_check_valve", 6 * 3600, 5, "check_valve", 3 * 3600, 0.5),
    ]
    for name, dur, seed, fault, t0, size in specs:
        rows, events = simulate(dur, seed, fault, t0, size)
        truth = dict(truth_common, fault=fault, t_fault=t0, fault_size=size, seed=seed,
                     draws=[[round(a, 1), round(b, 1), round(c, 2)] for a, b, c in events])
        nrow = write_log(f"{outdir}/{name}.csv", rows, seed, truth)
        arr = np.array(rows)
        Tm = (arr[:, 4] / 100 - 1) / 3.85e-3
        Tt = (arr[:, 3] / 100 - 1) / 3.85e-3
        print(f"{name}: {nrow} rows, duty {arr[:,1].mean():.2f}, Tmid {Tm.min():.1f}..{Tm.max():.1f}, "
              f"Ttop {Tt.min():.1f}..{Tt.max():.1f}, draws {len(events)}, mean flow {arr[:,2].mean():.2f} L/min")

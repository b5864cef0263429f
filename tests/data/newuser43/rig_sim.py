"""Simulated Li-ion module rig ("the real rig"), logged at 1 s.

Physics the first model lacks on purpose:
  * a second (slow) RC polarisation pair (R2, tau2 = 400 s)
  * temperature dependence of R0 (Arrhenius)
  * a small current-sensor offset (+0.4 A) in every log
The model also gets a slightly different OCV curve (polynomial fit).
"""
import json, sys
import numpy as np

TRUTH = dict(
    Q_Ah=50.0, R0_25=1.5e-3, Ea_K=2500.0,   # R0(T) = R0_25*exp(Ea*(1/(T+273.15)-1/298.15))
    R1=0.8e-3, tau1=10.0, R2=1.2e-3, tau2=400.0,
    Cth=1000.0, hA=2.0, Ta=25.0,
    I_offset=0.4, I_noise=0.2, V_noise=1.0e-3, V_quant=1.0e-3,
    T_noise=0.05, R25_kohm=10.0, B_K=3950.0, soc0=0.9,
)

def ocv(s):
    s = np.clip(s, 0.0, 1.0)
    return 3.40 + 0.65*s - 0.30*np.exp(-15.0*s) + 0.05*np.tanh(12.0*(s - 0.55))

def thermistor_kohm(T, p=TRUTH):
    return p["R25_kohm"]*np.exp(p["B_K"]*(1.0/(T + 273.15) - 1.0/298.15))

def drive_cycle(n, rng):
    """Current demand [A] (+ = discharge), 1 s resolution, urban/highway-like segments."""
    I = np.zeros(n); k = 0
    while k < n:
        d = int(rng.integers(5, 60))
        kind = rng.random()
        if kind < 0.15:   lvl = 0.0                       # stop
        elif kind < 0.35: lvl = -rng.uniform(20, 90)      # regen braking
        elif kind < 0.80: lvl = rng.uniform(10, 80)       # cruise
        else:             lvl = rng.uniform(90, 180)      # acceleration
        I[k:k+d] = lvl; k += d
    # first-order smoothing of the driver's pedal (3 s)
    out = np.zeros(n); y = 0.0
    for i in range(n):
        y += (I[i] - y)/3.0; out[i] = y
    return out

def simulate(duration, seed, fault=None, sub=10, p=TRUTH):
    rng = np.random.default_rng(seed)
    n = int(duration)
    Ireq = drive_cycle(n, rng)
    Qc = p["Q_Ah"]*3600.0
    soc, v1, v2, T = p["soc0"], 0.0, 0.0, p["Ta"]
    rows = []
    for k in range(n):
        t = float(k)
        I = Ireq[k]
        R0mult, hA, Ioff = 1.0, p["hA"], p["I_offset"]
        if fault:
            on = t >= fault["t0"]
            if on and fault["name"] == "weld":     R0mult = 1.0 + fault["size"]
            if on and fault["name"] == "cooling":  hA = p["hA"]*(1.0 - fault["size"])
            if on and fault["name"] == "current_offset": Ioff = p["I_offset"] + fault["size"]
        R0 = R0mult*p["R0_25"]*np.exp(p["Ea_K"]*(1.0/(T + 273.15) - 1.0/298.15))
        # sample (measurements at the start of the interval)
        V = ocv(soc) - R0*I - v1 - v2
        Vm = np.round((V + rng.normal(0, p["V_noise"]))/p["V_quant"])*p["V_quant"]
        Im = I + Ioff + rng.normal(0, p["I_noise"])
        Tm = T + rng.normal(0, p["T_noise"])
        rows.append((t, Vm, Im, thermistor_kohm(Tm), soc, v1, v2, T, R0))
        h = 1.0/sub
        for _ in range(sub):
            R0 = R0mult*p["R0_25"]*np.exp(p["Ea_K"]*(1.0/(T + 273.15) - 1.0/298.15))
            q = I*I*R0 + v1*v1/p["R1"] + v2*v2/p["R2"]
            soc += -h*I/Qc
            v1 += h*(-v1/p["tau1"] + I*p["R1"]/p["tau1"])
            v2 += h*(-v2/p["tau2"] + I*p["R2"]/p["tau2"])
            T += h*(q - hA*(T - p["Ta"]))/p["Cth"]
    return np.array(rows)

def write_log(path, rows, rng, drop=0.01, jitter=0.03):
    keep = rng.random(len(rows)) >= drop
    keep[0] = keep[-1] = True
    with open(path, "w") as f:
        f.write("t,V,I,Rth\n")
        for r, kp in zip(rows, keep):
            if not kp: continue
            t = r[0] + (rng.uniform(-jitter, jitter) if r[0] > 0 else 0.0)
            f.write(f"{t:.3f},{r[1]:.3f},{r[2]:.2f},{r[3]:.4f}\n")
    return int((~keep).sum())

if __name__ == "__main__":
    out = sys.argv[1] if len(sys.argv) > 1 else "."
    logs = {
        "healthy":  dict(duration=3600, seed=1, fault=None),
        "healthy2": dict(duration=3600, seed=2, fault=None),
        "short":    dict(duration=240,  seed=3, fault=None),
        "fault_current_offset": dict(duration=3600, seed=4, fault=dict(name="current_offset", t0=1800.0, size=5.0)),
        "fault_weld":    dict(duration=3600, seed=5, fault=dict(name="weld", t0=1800.0, size=1.0)),
        "fault_cooling": dict(duration=3600, seed=6, fault=dict(name="cooling", t0=1200.0, size=0.9)),
    }
    for name, cfg in logs.items():
        rows = simulate(cfg["duration"], cfg["seed"], cfg["fault"])
        dropped = write_log(f"{out}/{name}.csv", rows, np.random.default_rng(100 + cfg["seed"]))
        np.savetxt(f"{out}/{name}_states.csv", rows, delimiter=",",
                   header="t,V,Im,Rth,soc,v1,v2,T,R0", comments="")
        truth = dict(log=name, truth=TRUTH, fault=cfg["fault"], dropped_rows=dropped,
                     soc_start=float(rows[0, 4]), soc_end=float(rows[-1, 4]),
                     T_min=float(rows[:, 7].min()), T_max=float(rows[:, 7].max()),
                     I_true_mean=float(np.mean(rows[:, 2]) - TRUTH["I_offset"]),
                     R0_min=float(rows[:, 8].min()), R0_max=float(rows[:, 8].max()))
        if cfg["fault"]:
            f = cfg["fault"]
            truth["description"] = {
                "current_offset": "current-sensor offset step of +5 A (total +5.4 A) at t0",
                "weld": "R0 doubles (+100 %, +1.5 mOhm at 25 degC) at t0: bad weld",
                "cooling": "fan stops: hA 2.0 -> 0.2 W/K at t0",
            }[f["name"]]
        with open(f"{out}/{name}.json", "w") as fh:
            json.dump(truth, fh, indent=1)
        print(name, truth["soc_start"], round(truth["soc_end"], 3), round(truth["T_min"], 2),
              round(truth["T_max"], 2), "dropped", dropped)

"""My own Li-ion cell 'rig' simulator (plain numpy), independent of fdigen.

Equivalent circuit: hidden SOC, one hidden RC pair, OCV polynomial in SOC,
lumped cell temperature with thermal mass and forced-air cooling.
Effects the model file does NOT contain (selectable):
  * 'offset'   : current-sensor offset, I_meas = I_true + 0.3 A
  * 'arrhenius': R0(T) = R0ref*exp(EaR*(1/(T+273.15) - 1/(Tref+273.15)))
Faults: resistance rise (R0 x (1+r)) or fan failure (hA x (1-f)) from t_fault on.
Log: t [s], I [A] (measured, positive = discharge), V [V], T [degC] at 1 s.
"""
import argparse, json
import numpy as np

TRUTH = dict(
    Qc=4.6 * 3600.0,      # A*s  (aged cell, datasheet says 5.0 Ah)
    R0=0.018,             # Ohm at 25 degC
    R1=0.010,             # Ohm
    C1=2000.0,            # F    (tau1 = 20 s)
    Cth=80.0,             # J/K
    hA=0.45,              # W/K
    Ta=25.0,              # degC ambient
    a0=3.35, a1=0.9, a2=-0.6, a3=0.55,  # OCV(soc) polynomial
    EaR=3000.0, Tref=25.0,
    I_offset=0.3,
)
NOISE = dict(V=0.002, I=0.05, T=0.1)
QUANT = dict(V=0.001, I=0.01, T=0.1)


def drive_cycle(n, seed, style="urban", mean_target=3.5):
    """Piecewise-constant (1 s) current profile: accelerations, cruise, regen, idle."""
    rng = np.random.default_rng(seed)
    I = np.zeros(n)
    k = 0
    while k < n:
        r = rng.random()
        if style == "urban":
            p_acc, p_cruise, p_regen = 0.3, 0.3, 0.2
        else:  # highway: longer cruise, fewer stops
            p_acc, p_cruise, p_regen = 0.15, 0.6, 0.1
        if r < p_acc:
            L = rng.integers(4, 15); lvl = rng.uniform(15, 35)
            seg = lvl * np.sin(np.linspace(0.2, np.pi - 0.2, L)) + rng.normal(0, 1, L)
        elif r < p_acc + p_cruise:
            L = rng.integers(20, 120 if style == "urban" else 300); lvl = rng.uniform(2, 9)
            seg = lvl + rng.normal(0, 0.8, L)
        elif r < p_acc + p_cruise + p_regen:
            L = rng.integers(3, 12); lvl = rng.uniform(-18, -5)
            seg = lvl * np.sin(np.linspace(0.2, np.pi - 0.2, L))
        else:
            L = rng.integers(5, 60); seg = rng.uniform(0.0, 0.4) * np.ones(L)
        seg = seg[: n - k]
        I[k:k + len(seg)] = seg
        k += len(seg)
    # scale discharge part so the mean is about mean_target
    m = I.mean()
    if m > 0:
        I = I * (mean_target / m)
    return I


def simulate(n, seed, effect="offset", fault=None, t_fault=None, fault_size=0.0,
             style="urban", soc0=0.95, T0=25.0, substeps=10):
    p = dict(TRUTH)
    rng = np.random.default_rng(1000 + seed)
    I_true = drive_cycle(n, seed, style)
    dt = 1.0 / substeps

    def R0_of(T, k):
        R0 = p["R0"]
        if effect == "arrhenius":
            R0 = R0 * np.exp(p["EaR"] * (1.0 / (T + 273.15) - 1.0 / (p["Tref"] + 273.15)))
        if fault == "resistance" and k >= t_fault:
            R0 = R0 * (1.0 + fault_size)
        return R0

    def hA_of(k):
        if fault == "fan" and k >= t_fault:
            return p["hA"] * (1.0 - fault_size)
        return p["hA"]

    def f(x, I, k):
        soc, v1, T = x
        R0 = R0_of(T, k)
        dsoc = -I / p["Qc"]
        dv1 = -v1 / (p["R1"] * p["C1"]) + I / p["C1"]
        dT = (I * I * R0 + v1 * v1 / p["R1"] - hA_of(k) * (T - p["Ta"])) / p["Cth"]
        return np.array([dsoc, dv1, dT])

    x = np.array([soc0, 0.0, T0])
    X = np.zeros((n, 3)); V = np.zeros(n)
    for k in range(n):
        X[k] = x
        soc, v1, T = x
        ocv = p["a0"] + p["a1"] * soc + p["a2"] * soc ** 2 + p["a3"] * soc ** 3
        V[k] = ocv - I_true[k] * R0_of(T, k) - v1
        for _ in range(substeps):
            k1 = f(x, I_true[k], k)
            k2 = f(x + dt / 2 * k1, I_true[k], k)
            k3 = f(x + dt / 2 * k2, I_true[k], k)
            k4 = f(x + dt * k3, I_true[k], k)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    off = p["I_offset"] if effect == "offset" else 0.0
    q = lambda y, s: np.round(y / s) * s
    Im = q(I_true + off + rng.normal(0, NOISE["I"], n), QUANT["I"])
    Vm = q(V + rng.normal(0, NOISE["V"], n), QUANT["V"])
    Tm = q(X[:, 2] + rng.normal(0, NOISE["T"], n), QUANT["T"])
    t = np.arange(n) * 1.0
    truth = dict(seed=seed, effect=effect, fault=fault, t_fault=t_fault,
                 fault_size=fault_size, style=style, params=p, noise=NOISE, quant=QUANT,
                 soc_start=float(X[0, 0]), soc_end=float(X[-1, 0]),
                 T_min=float(X[:, 2].min()), T_max=float(X[:, 2].max()),
                 I_mean=float(I_true.mean()), I_min=float(I_true.min()),
                 I_max=float(I_true.max()))
    return t, Im, Vm, Tm, X, I_true, truth


def write(path, t, I, V, T, truth):
    with open(path, "w") as fh:
        fh.write("t,I,V,T\n")
        for row in zip(t, I, V, T):
            fh.write("%.1f,%.2f,%.3f,%.1f\n" % row)
    with open(path.replace(".csv", "_truth.json"), "w") as fh:
        json.dump(truth, fh, indent=1)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("out"); ap.add_argument("--n", type=int, default=3600)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--effect", default="offset")
    ap.add_argument("--fault", default=None); ap.add_argument("--t-fault", type=int, default=None)
    ap.add_argument("--size", type=float, default=0.0)
    ap.add_argument("--style", default="urban"); ap.add_argument("--soc0", type=float, default=0.95)
    ap.add_argument("--T0", type=float, default=25.0)
    a = ap.parse_args()
    t, I, V, T, X, It, truth = simulate(a.n, a.seed, a.effect, a.fault, a.t_fault, a.size,
                                        a.style, a.soc0, a.T0)
    write(a.out, t, I, V, T, truth)
    print(a.out, {k: truth[k] for k in ("soc_start", "soc_end", "T_min", "T_max", "I_mean", "I_min", "I_max")})

#!/usr/bin/env python
"""Stand-in for the real two-mass drive rig (independent of fdigen).

Truth the fdigen model does NOT contain:
  * backlash (dead zone 0.02 rad total, i.e. +-0.01 rad) in the shaft
  * Coulomb friction on the load, Tc_true
  * motor torque constant 8 % below datasheet (Kt_true = 0.92*Kt; back-emf const too)
  * constant load torque Tload_true
Sensors: current shunt amp 0.5 V/A + noise, two 1024 cpr encoders, speed by
differencing counts at the (jittered) sample instants divided by the nominal 2 ms.
Time column in milliseconds, jitter +-0.1 ms, NaN dropouts in the load speed.
"""
import json, math, sys
import numpy as np
from scipy.io import savemat

# datasheet (what the model file uses)
DS = dict(Ra=1.0, La=5e-3, Kt=0.1, Jm=1e-3, Jl=2e-3, k=5.0, c=0.02, bm=1e-4, bl=5e-4)
# truth extras
TRUE = dict(Kt_factor=0.92, backlash=0.02, Tc=0.02, Tload=0.05)
DT = 2e-3
CPR = 1024
SHUNT = 0.5        # V/A
I_NOISE = 0.01     # V rms on the shunt amp output
VMAX = 24.0
KP, KI = 0.3, 3.0  # PI speed loop on measured motor speed


def deadzone(x, half):
    return x - half if x > half else (x + half if x < -half else 0.0)


def f(x, V, p):
    i, wm, wl, th = x
    Kt = p['Kt']
    d = deadzone(th, p['backlash'] / 2)
    in_contact = 1.0 if d != 0.0 else 0.0
    Tsh = p['k'] * d + in_contact * p['c'] * (wm - wl)
    di = (V - p['Ra'] * i - Kt * wm) / p['La']
    dwm = (Kt * i - p['bm'] * wm - Tsh) / p['Jm']
    dwl = (Tsh - p['bl'] * wl - p['Tc'] * math.tanh(wl / 0.05) - p['Tload']) / p['Jl']
    dth = wm - wl
    return np.array([di, dwm, dwl, dth])


def profile(name, t):
    if name == 'A':   # steps
        levels = [0, 40, 80, 20, -40, -80, 0, 60, -20, 50]
        return levels[int(t // 3.0) % len(levels)]
    if name == 'B':   # ramps / sine
        return 60 * np.sin(2 * np.pi * 0.15 * t) + 20 * np.sin(2 * np.pi * 0.53 * t)
    if name == 'C':   # trapezoids + steps
        ph = t % 8.0
        base = 70 * min(ph / 2, 1.0) if ph < 4 else 70 * max(1 - (ph - 4) / 2, -1.0)
        return base + (15 if int(t) % 5 == 2 else 0)
    raise ValueError(name)


def run(name, dur, prof, seed, fault=None, t0=None, nan_sensor='wl', write_mat=False):
    rng = np.random.default_rng(seed)
    p = dict(DS)
    p['Kt'] = DS['Kt'] * TRUE['Kt_factor']
    p['backlash'] = TRUE['backlash']; p['Tc'] = TRUE['Tc']; p['Tload'] = TRUE['Tload']
    n = int(round(dur / DT))
    tk = np.arange(n) * DT + rng.uniform(-1e-4, 1e-4, n)
    tk[0] = 0.0
    x = np.zeros(4)
    thm = 0.0; thl = 0.0          # true angles
    cm_prev = 0; cl_prev = 0
    integ = 0.0
    V = 0.0
    rows = []
    truth_faults = []
    for k in range(n):
        t = tk[k]
        active = fault is not None and t >= t0
        # --- measure
        cm = int(np.floor(thm / (2 * np.pi) * CPR)); cl = int(np.floor(thl / (2 * np.pi) * CPR))
        wm_meas = (cm - cm_prev) * 2 * np.pi / CPR / DT if k > 0 else 0.0
        wl_meas = (cl - cl_prev) * 2 * np.pi / CPR / DT if k > 0 else 0.0
        cm_prev, cl_prev = cm, cl
        i_meas = SHUNT * x[0] + rng.normal(0, I_NOISE)
        if active and fault == 'enc_offset':
            wm_meas += 6.0                      # rad/s step
        if active and fault == 'wl_drift':
            wl_meas += 2.0 * (t - t0)           # rad/s per s
        # --- control (PI on measured motor speed)
        ref = profile(prof, t)
        e = ref - wm_meas
        Vu = KP * e + KI * integ
        V = float(np.clip(Vu, -VMAX, VMAX))
        if not ((Vu > VMAX and e > 0) or (Vu < -VMAX and e < 0)):
            integ += e * DT
        rows.append([t * 1e3, V, i_meas, wm_meas, wl_meas, ref])
        # --- plant to next sample instant
        h_tot = (tk[k + 1] - t) if k + 1 < n else DT
        pp = dict(p)
        if active and fault == 'kt_loss':
            pp['Kt'] = p['Kt'] * 0.7
        if active and fault == 'shaft':
            pp['k'] = p['k'] * 0.5
        ns = 5
        h = h_tot / ns
        for _ in range(ns):
            k1 = f(x, V, pp); k2 = f(x + h / 2 * k1, V, pp)
            k3 = f(x + h / 2 * k2, V, pp); k4 = f(x + h * k3, V, pp)
            dx = (k1 + 2 * k2 + 2 * k3 + k4) / 6
            thm += h * (x[1] + (h / 2) * dx[1])  # good enough angle update
            thl += h * (x[2] + (h / 2) * dx[2])
            x = x + h * dx
    arr = np.array(rows)
    # NaN dropouts in the load-speed sensor (short ones)
    if nan_sensor:
        col = {'i': 2, 'wm': 3, 'wl': 4}[nan_sensor]
        for s in rng.choice(np.arange(100, n - 100), size=4, replace=False):
            arr[s:s + rng.integers(1, 4), col] = np.nan
    hdr = 't,V,i_meas,wm_meas,wl_meas,wref'
    np.savetxt(f'logs/{name}.csv', arr, delimiter=',', header=hdr, comments='', fmt='%.6g')
    if write_mat:
        savemat(f'logs/{name}.mat', {c: arr[:, j] for j, c in enumerate(hdr.split(','))})
    truth = dict(log=name, profile=prof, duration=dur, seed=seed, fault=fault, onset_s=t0,
                 effects=dict(Kt_true=p['Kt'], Kt_datasheet=DS['Kt'], backlash_rad=TRUE['backlash'],
                              Tc_load_Nm=TRUE['Tc'], Tload_Nm=TRUE['Tload']),
                 fault_sizes=dict(enc_offset='+6 rad/s step on wm_meas', wl_drift='+2 rad/s/s ramp on wl_meas',
                                  kt_loss='Kt x0.7', shaft='k x0.5'),
                 time_unit='ms')
    json.dump(truth, open(f'logs/{name}.json', 'w'), indent=1)
    print(name, arr.shape, 'wm range', np.nanmin(arr[:, 3]), np.nanmax(arr[:, 3]),
          'V range', arr[:, 1].min(), arr[:, 1].max(), 'i_meas', np.nanmin(arr[:, 2]), np.nanmax(arr[:, 2]))


if __name__ == '__main__':
    import os
    os.makedirs('logs', exist_ok=True)
    which = sys.argv[1:] or ['all']
    jobs = [
        ('healthy_A', 30, 'A', 1, None, None, True),
        ('healthy_B', 30, 'B', 2, None, None, False),
        ('healthy_C_unseen', 24, 'C', 3, None, None, False),
        ('short_3s', 3, 'B', 4, None, None, False),
        ('fault_enc_offset', 20, 'C', 5, 'enc_offset', 10.0, False),
        ('fault_wl_drift', 20, 'C', 6, 'wl_drift', 10.0, False),
        ('fault_kt_loss', 20, 'C', 7, 'kt_loss', 10.0, False),
        ('fault_shaft', 20, 'C', 8, 'shaft', 10.0, False),
    ]
    for j in jobs:
        if 'all' in which or j[0] in which:
            run(j[0], j[1], j[2], j[3], j[4], j[5], write_mat=j[6])

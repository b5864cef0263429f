"""Own emulation of the water-heater rig (NOT fdigen simulate).
Truth: heat loss UA*(T-Tamb), heater efficiency 0.93, thermocouple first-order lag 8 s,
quantisation 0.1 degC, noise std 0.05 degC. PI temperature controller on the heater.
"""
import json, sys
import numpy as np

TRUTH = dict(C=21500.0, cp=4186.0, Tin=15.0, UA=4.0, Tamb=22.0, eta=0.93, tau_s=8.0,
             q_quant=0.1, noise=0.05, kp=0.6, ki=0.004, Pmax=3.0)

def ref(t):
    # setpoint profile, degC
    edges = [0, 240, 480, 780, 1020]
    vals = [40.0, 45.0, 38.0, 44.0, 36.0]
    return vals[np.searchsorted(edges, t, side='right') - 1]

def flow(t):
    edges = [0, 180, 420, 700, 900, 1100]
    vals = [0.7, 1.0, 0.5, 0.8, 0.9, 0.6]
    return vals[np.searchsorted(edges, t, side='right') - 1]

def simulate(duration=1200.0, dt=2.0, seed=0, sensor_offset=None, sensor_drift=None,
             heater_scale=None, t_fault=600.0, sub=20):
    p = TRUTH
    rng = np.random.default_rng(seed)
    n = int(round(duration / dt))
    T, Ts = 38.0, 38.0      # tank and sensor-junction temperature
    I = 0.0
    rows = []
    h = dt / sub
    for k in range(n):
        t = k * dt
        q = flow(t)
        # measurement
        y = Ts + rng.normal(0, p['noise'])
        if sensor_offset is not None and t >= t_fault:
            y += sensor_offset
        if sensor_drift is not None and t >= t_fault:
            y += sensor_drift * (t - t_fault) / 60.0   # degC per minute
        y = np.round(y / p['q_quant']) * p['q_quant']
        r = ref(t)
        e = r - y
        u = p['kp'] * e + p['ki'] * I
        if u > p['Pmax']:
            u = p['Pmax']
            if e < 0: I += e * dt
        elif u < 0.0:
            u = 0.0
            if e > 0: I += e * dt
        else:
            I += e * dt
        rows.append((t, u, q, y, r))
        eff = p['eta'] * (heater_scale if (heater_scale is not None and t >= t_fault) else 1.0)
        def f(x):
            T, Ts = x
            dT = (1000.0 * eff * u - q / 60.0 * p['cp'] * (T - p['Tin']) - p['UA'] * (T - p['Tamb'])) / p['C']
            dTs = (T - Ts) / p['tau_s']
            return np.array([dT, dTs])
        x = np.array([T, Ts])
        for _ in range(sub):
            k1 = f(x); k2 = f(x + h/2*k1); k3 = f(x + h/2*k2); k4 = f(x + h*k3)
            x = x + h/6*(k1 + 2*k2 + 2*k3 + k4)
        T, Ts = x
    return np.array(rows)

def write(name, arr, truth):
    hdr = 't,P,q,T_meas,T_ref'
    np.savetxt(name + '.csv', arr, delimiter=',', header=hdr, comments='', fmt='%.6g')
    json.dump(truth, open(name + '_truth.json', 'w'), indent=1)

if __name__ == '__main__':
    base = dict(TRUTH)
    write('heater_healthy', simulate(seed=0), dict(base, fault=None, seed=0))
    write('heater_healthy2', simulate(seed=1), dict(base, fault=None, seed=1))
    write('heater_offset', simulate(seed=2, sensor_offset=1.5), dict(base, fault='sensor offset +1.5 degC', t0=600, seed=2))
    write('heater_partial', simulate(seed=3, heater_scale=0.6), dict(base, fault='heater at 60% power', t0=600, seed=3))
    write('heater_drift', simulate(seed=4, sensor_drift=0.5), dict(base, fault='sensor drift 0.5 degC/min', t0=600, seed=4))
    write('heater_short', simulate(duration=180.0, seed=5), dict(base, fault=None, seed=5, duration=180))
    write('heater_slow', simulate(dt=10.0, seed=6, sub=100), dict(base, fault=None, seed=6, dt=10))
    write('heater_partial_slow', simulate(dt=10.0, seed=7, sub=100, heater_scale=0.6), dict(base, fault='heater at 60%', t0=600, seed=7, dt=10))

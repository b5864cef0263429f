"""'Real' compressed-air station (truth the tool does not know).
State: receiver gauge pressure p [bar(g)], isothermal receiver.
dp/dt = Pn*(Qc - Qd - Ql)/(60*V)   flows in Nm^3/min, Pn = 1.01325 bar
Qc = load*Q0*(n/n0)*(1 - kq*(p - 7))*(1-eff_loss)
Ql = cl*sqrt(p)  (leak NOT in model);  extra fault leak cl2*sqrt(p) from t0
P_el = load*(Pl0 + kpw*p) + (1-load)*Pu   [kW]
Sensors: p_meas = p + off_p + drift + N(0,0.01) (4-20 mA 0-16 bar, quantised 16 bit)
         P_meas = P_el + N(0,0.3)
         qd_meas = Qd + off_q + N(0,0.05)   (flow meter offset +0.4 Nm3/min)
Controller: load when p_meas < 6.5, unload when p_meas > 7.5 (PLC at each sample)
"""
import argparse, json, numpy as np

TRUE = dict(V=2.0, Q0=10.4, n=1482.0, n0=1480.0, kq=0.03, cl=0.25, Pl0=41.0, kpw=3.2,
            Pu=14.5, off_p=0.02, off_q=0.40, p_lo=6.5, p_hi=7.5, Pn=1.01325)

def demand(t, rng, T):
    # piecewise-constant shifts + slow sine + small fast noise (true demand, Nm3/min)
    nseg = int(T // 300) + 2
    levels = rng.uniform(3.5, 7.5, nseg)
    seg = np.minimum((t // 300).astype(int), nseg - 1)
    return levels[seg] + 0.6*np.sin(2*np.pi*t/900.0) + 0.0*t

def run(T, seed, fault=None, t0=3600.0, dt=1.0, sub=20, out='log.csv'):
    rng = np.random.default_rng(seed)
    P = dict(TRUE)
    N = int(round(T/dt))
    tg = np.arange(N)*dt
    qd_true = demand(tg, rng, T) + 0.15*rng.standard_normal(N).cumsum()*0.0
    qd_true = np.clip(qd_true + 0.1*rng.standard_normal(N), 0.5, 12)
    p = 7.0; load = 0
    rows = []
    for k in range(N):
        t = tg[k]
        active = fault is not None and t >= t0
        drift = 0.0
        if active and fault == 'drift':
            drift = (t - t0) * (0.4/1800.0)   # 0.4 bar over 30 min, then continues
        pm = p + P['off_p'] + drift + 0.01*rng.standard_normal()
        pm = np.round((4 + 16*pm/16.0)*2**16/20.0)*20.0/2**16   # mA quantisation
        pm = (pm - 4)*16/16.0
        # on/off controller on the measured pressure
        if pm < P['p_lo']: load = 1
        elif pm > P['p_hi']: load = 0
        Pel = load*(P['Pl0'] + P['kpw']*p) + (1-load)*P['Pu']
        Pm = Pel + 0.3*rng.standard_normal()
        qm = qd_true[k] + P['off_q'] + 0.05*rng.standard_normal()
        rows.append([t, load, qm, pm, Pm])
        # integrate over [t, t+dt) with held load and demand
        h = dt/sub
        eff = 0.2 if (active and fault == 'efficiency') else 0.0
        cl2 = 0.6 if (active and fault == 'leak') else 0.0
        for _ in range(sub):
            Qc = load*P['Q0']*(P['n']/P['n0'])*(1 - P['kq']*(p - 7.0))*(1 - eff)
            Ql = (P['cl'] + cl2)*np.sqrt(max(p, 0.0))
            p += h*P['Pn']*(Qc - qd_true[k] - Ql)/(60*P['V'])
            p = max(p, 0.0)
    rows = np.array(rows)
    # timestamp jitter (+-5 % of dt), a few NaN fields, a few dropped rows
    rows[:, 0] = rows[:, 0] + rng.uniform(-0.05, 0.05, N)*dt
    rows[0, 0] = 0.0
    for _ in range(max(2, N//1500)):
        i = rng.integers(10, N-10); c = rng.integers(2, 5); rows[i, c] = np.nan
    drop = set(rng.choice(np.arange(10, N-10), size=max(1, N//3000), replace=False).tolist())
    with open(out, 'w') as f:
        f.write('t,load,qd,p,P\n')
        f.write('s,1,Nm^3/min,bar,kW\n')
        for i, r in enumerate(rows):
            if i in drop: continue
            f.write(','.join('' if np.isnan(v) else f'{v:.6g}' for v in r) + '\n')
    truth = dict(TRUE, seed=seed, duration=T, fault=fault, t0=t0 if fault else None,
                 fault_size={'leak': 'cl2=0.6 (x sqrt(p) Nm3/min)', 'efficiency': '-20% flow',
                             'drift': '0.4 bar/1800 s ramp'}.get(fault), dropped_rows=sorted(drop))
    json.dump(truth, open(out.replace('.csv', '.json'), 'w'), indent=1)

if __name__ == '__main__':
    a = argparse.ArgumentParser()
    a.add_argument('-o', required=True); a.add_argument('--T', type=float, default=7200)
    a.add_argument('--seed', type=int, default=1); a.add_argument('--fault')
    a.add_argument('--t0', type=float, default=3600)
    x = a.parse_args()
    run(x.T, x.seed, x.fault, x.t0, out=x.o)

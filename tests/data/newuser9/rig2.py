"""My heatsink rig: own simulator. Truth: Rsa = 1.2 K/W (datasheet 1.0 in thermal.toml, +20 %),
   Cs 40, Cd 5, Rjs 0.5, Ta 25. Die temperature hidden. Thermistor noise 0.05 K, 0.0625 K quantum.
   PI on Ts, 300 samples at 0.5 s (150 s)."""
import json, numpy as np
T = dict(Cd=5.0, Rjs=0.5, Cs=40.0, Rsa=1.2, Ta=25.0)
def f(x, P):
    Td, Ts = x
    return np.array([(P - (Td-Ts)/T['Rjs'])/T['Cd'], ((Td-Ts)/T['Rjs'] - (Ts-T['Ta'])/T['Rsa'])/T['Cs']])
def ref(t, v):
    if v == 0: return 45.0 + 10.0*(t >= 30) - 16.0*(t >= 90)
    return 45.0 - 6.0*(t >= 20) + 14.0*(t >= 70) - 5.0*(t >= 115)
def run(seed, out, v=0, off=0.0, tf=75.0):
    rng = np.random.default_rng(seed); dt = 0.5; sub = 20
    x = np.array([25+20*1.7, 25+20*1.2])  # equilibrium at 20 W for the TRUE plant
    I = 0.0; rows = []; X = []
    for k in range(300):
        t = k*dt
        y = x[1] + rng.normal(0, 0.05) + (off if t >= tf else 0.0)
        y = np.round(y/0.0625)*0.0625
        r = ref(t, v); e = r - y
        Pu = 20.0 + 3.0*e + 0.1*I; P = min(max(Pu, 0), 60)
        if P == Pu or (Pu > 60 and e < 0) or (Pu < 0 and e > 0): I += e*dt
        P = np.round(P, 2)
        rows.append((t, P, y, r)); X.append(x.copy())
        h = dt/sub
        for _ in range(sub):
            k1=f(x,P);k2=f(x+h/2*k1,P);k3=f(x+h/2*k2,P);k4=f(x+h*k3,P); x = x + h/6*(k1+2*k2+2*k3+k4)
    with open(out,'w') as fh:
        fh.write('t,P,Ts,Tref\n')
        for r_ in rows: fh.write('%.2f,%.2f,%.4f,%.2f\n' % r_)
    np.save(out.replace('.csv','_truth.npy'), np.array(X))
    json.dump(dict(seed=seed, variant=v, tsensor_offset_K=off, t_fault=tf, **T), open(out.replace('.csv','_truth.json'),'w'))
if __name__ == '__main__':
    run(11, 'heat_healthy.csv', 0)
    run(12, 'heat_healthy2.csv', 1)
    run(13, 'heat_ts_offset.csv', 1, off=2.0, tf=75.0)

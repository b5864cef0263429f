"""Stand-in for the real electro-hydraulic rig (independent of fdigen).
Differential cylinder, 4/3 proportional valve with spool lag + overlap (dead band),
internal leakage, viscous + Coulomb friction, valve flow gain 10 % below datasheet.
Logs at 1 ms: t[ms], u[V], x[mm], pA[bar], pB[bar], xref[mm] with a units row."""
import math, json, sys
import numpy as np

# ---- datasheet (what the model file will say) ----
DS = dict(AA=1.963e-3, AB=1.0e-3, M=20.0, beta=14000.0, V0A=2.0e-4, V0B=2.0e-4,
          Kv=5.63e-6, ps=140.0, pt=2.0, L=200.0)   # Kv: m^3/s per V per sqrt(bar)
# ---- truth of the rig ----
TRUE = dict(Kv=0.9*DS['Kv'], db=0.3,      # V-equivalent spool overlap (3 % of 10 V)
            tau_s=0.008,                  # spool lag [s]
            Ci=2.0e-7,                    # internal leak [m^3/(s bar)]
            b=2000.0, Fc=300.0, v_eps=1.0)  # viscous N s/m, Coulomb N, tanh width mm/s
KP, KI, ULIM = 1.0, 2.0, 10.0
NOISE_X, Q_X, NOISE_P = 0.002, 0.001, 0.15

def f(s, st, u_cmd, p, flt):
    x, v, pA, pB, sp = st
    ps, pt = DS['ps'], DS['pt']
    # spool position in V-equivalent, dead band (overlap)
    se = math.copysign(max(abs(sp) - p['db'], 0.0), sp)
    Kv = p['Kv']
    if se >= 0:
        QA = Kv*se*math.sqrt(max(ps - pA, 0.0)); QB = -Kv*se*math.sqrt(max(pB - pt, 0.0))
    else:
        QA = Kv*se*math.sqrt(max(pA - pt, 0.0)); QB = -Kv*se*math.sqrt(max(ps - pB, 0.0))
    Qi = p['Ci']*(pA - pB)                     # internal leak A->B
    Qe = flt.get('leak_A', 0.0)*max(pA - 0.0, 0.0)  # external leak from A to drain
    VA = DS['V0A'] + DS['AA']*x/1000.0
    VB = DS['V0B'] + DS['AB']*(DS['L'] - x)/1000.0
    dpA = DS['beta']/VA*(QA - Qi - Qe - DS['AA']*v/1000.0)
    dpB = DS['beta']/VB*(QB + Qi + DS['AB']*v/1000.0)
    F = (pA*DS['AA'] - pB*DS['AB'])*1e5 - p['b']*v/1000.0 - p['Fc']*math.tanh(v/p['v_eps'])
    # end stops
    a = 1000.0*F/DS['M']
    dsp = (u_cmd - sp)/p['tau_s']
    return (v, a, dpA, dpB, dsp)

def run(ref, T, seed, fault=None, onset=None, out='log.csv', nan_rows=(), gap=None):
    rng = np.random.default_rng(seed)
    p = dict(TRUE)
    dt, sub = 1e-3, 10
    h = dt/sub
    N = int(round(T/dt))
    # pre-roll 1 s at ref(0)
    x0 = ref(0.0)
    st = [x0, 0.0, 60.0, 60.0*DS['AA']/DS['AB'], 0.0]
    I = 0.0
    rows = []
    truth = dict(datasheet=DS, truth=TRUE, controller=dict(kp=KP, ki=KI, lim=ULIM),
                 fault=fault, onset_s=onset, seed=seed)
    k0 = -1000
    xm_prev = x0
    for k in range(k0, N):
        t = k*dt
        flt = {}
        if fault and onset is not None and t >= onset:
            flt = {fault[0]: fault[1]}
        # measurements at t
        x, v, pA, pB, sp = st
        xm = np.round((x + NOISE_X*rng.standard_normal())/Q_X)*Q_X
        pAm = pA + NOISE_P*rng.standard_normal()
        pBm = pB + NOISE_P*rng.standard_normal()
        if 'pos_offset' in flt: xm += flt['pos_offset']
        if 'pA_drift' in flt: pAm += flt['pA_drift']*(t - onset)
        xr = ref(max(t, 0.0))
        e = xr - xm
        u = KP*e + KI*I
        if abs(u) < ULIM or (u > 0) != (e > 0):
            I += e*dt
        u = min(max(KP*e + KI*I, -ULIM), ULIM)
        if k >= 0:
            rows.append([t*1000.0, u, xm, pAm, pBm, xr])
        ua = u*(1.0 + flt.get('valve_gain', 0.0))   # valve gain loss (e.g. -0.4)
        for _ in range(sub):
            k1 = f(t, st, ua, p, flt)
            s2 = [a + h/2*b for a, b in zip(st, k1)]; k2 = f(t, s2, ua, p, flt)
            s3 = [a + h/2*b for a, b in zip(st, k2)]; k3 = f(t, s3, ua, p, flt)
            s4 = [a + h*b for a, b in zip(st, k3)]; k4 = f(t, s4, ua, p, flt)
            st = [a + h/6*(b1 + 2*b2 + 2*b3 + b4) for a, b1, b2, b3, b4 in zip(st, k1, k2, k3, k4)]
            st[2] = min(max(st[2], 0.0), 250.0); st[3] = min(max(st[3], 0.0), 250.0)
            if st[0] < 0 or st[0] > DS['L']:
                st[0] = min(max(st[0], 0.0), DS['L']); st[1] = 0.0
    A = np.array(rows)
    for r, c in nan_rows:
        A[r, c] = np.nan
    if gap:
        r0, n, c = gap; A[r0:r0+n, c] = np.nan
    with open(out, 'w') as fh:
        fh.write('t,u,x,pA,pB,xref\n')
        fh.write('ms,V,mm,bar,bar,mm\n')
        for row in A:
            fh.write(','.join('' if np.isnan(vv) else ('%.0f' % vv if i == 0 else '%.6g' % vv)
                              for i, vv in enumerate(row)) + '\n')
    truth['log'] = out
    json.dump(truth, open(out.replace('.csv', '.truth.json'), 'w'), indent=1)
    return A

ramp = lambda t: 50.0 + min(t, 15.0)*100.0/15.0                      # out only, 6.7 mm/s
rev = lambda t: 100.0 + 40*math.sin(2*math.pi*0.2*t) + 15*math.sin(2*math.pi*0.7*t)
rev2 = lambda t: 100.0 + 50*math.sin(2*math.pi*0.13*t + 0.5) + 10*math.sin(2*math.pi*1.1*t)
if __name__ == '__main__':
    which = sys.argv[1:] or ['all']
    nans = [(1234, 2), (5000, 3), (9001, 4)]
    jobs = {
     'healthy_ramp': lambda: run(ramp, 16, 1, out='healthy_ramp.csv', nan_rows=nans, gap=(7000, 3, 2)),
     'healthy_rev': lambda: run(rev, 16, 2, out='healthy_rev.csv', nan_rows=nans, gap=(7000, 3, 3)),
     'healthy_rev2': lambda: run(rev2, 16, 3, out='healthy_rev2.csv', nan_rows=nans),
     'fault_pos_offset': lambda: run(rev2, 16, 11, ('pos_offset', 1.0), 8.0, 'fault_pos_offset.csv', nans),
     'fault_pA_drift': lambda: run(rev2, 16, 12, ('pA_drift', 2.0), 8.0, 'fault_pA_drift.csv', nans),
     'fault_leak_A': lambda: run(rev2, 16, 13, ('leak_A', 3e-7), 8.0, 'fault_leak_A.csv', nans),
     'fault_valve_gain': lambda: run(rev2, 16, 14, ('valve_gain', -0.4), 8.0, 'fault_valve_gain.csv', nans),
    }
    for name, job in jobs.items():
        if 'all' in which or name in which:
            job(); print('wrote', name)

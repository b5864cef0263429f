"""My two-tank rig: own simulator. Truth differs from tanks.toml:
   kp 4.2 (model 4.0), a1 0.115 (0.12), a2 0.14 (same), leak in tank 2 Kl*sqrt(h2) NOT in model.
   4-20 mA transmitters (i0 4.0, 0.32 mA/cm), noise 0.01 mA, ADC quantum 24/4096 mA,
   pump-flow disturbance, PI on LT2, 1 s sampling, 600 s."""
import sys, json
import numpy as np
g = 981.0; A1 = A2 = 60.0
TRUE = dict(kp=4.2, a1=0.115, a2=0.14, Kl=0.6)   # Kl in cm^2.5/s ~ 10 % of a2*sqrt(2g)=6.2
def f(h, u, Kl, leak1=0.0):
    h1, h2 = max(h[0], 0), max(h[1], 0)
    q1 = TRUE['a1']*np.sqrt(2*g*h1); q2 = TRUE['a2']*np.sqrt(2*g*h2)
    return np.array([(TRUE['kp']*u - q1 - leak1)/A1, (q1 - q2 - Kl*np.sqrt(h2))/A2])
def ref(t, variant):
    if variant == 0:
        return 10.4 + 5.0*(t >= 150) - 7.0*(t >= 300) + 4.0*(t >= 450)
    return 10.4 - 3.0*(t >= 100) + 8.0*(t >= 250) - 6.0*(t >= 420)
def run(seed, out, variant=0, lt2_off=0.0, t_fault=300.0, Kl=TRUE['Kl']):
    rng = np.random.default_rng(seed)
    N, dt, sub = 600, 1.0, 50
    # start near the equilibrium of the true plant at u=5
    h = np.array([14.0, 9.0]); q = 24.0/4096
    I = 0.0; rows = []; truth_h = []
    dist = 0.0
    for k in range(N):
        t = k*dt
        y = 4.0 + 0.32*h + rng.normal(0, 0.01, 2)
        if t >= t_fault: y[1] += lt2_off
        y = np.round(y/q)*q
        r = ref(t, variant)
        e = r - (y[1]-4.0)/0.32
        u_un = 5.0 + 0.6*e + 0.008*I
        u = min(max(u_un, 0.0), 10.0)
        if u == u_un or (u_un > 10 and e < 0) or (u_un < 0 and e > 0):
            I += e*dt
        u = np.round(u/0.01)*0.01
        rows.append((t, u, y[0], y[1], r)); truth_h.append(h.copy())
        # pump flow disturbance: slow AR(1) +-2 %
        dist = 0.98*dist + rng.normal(0, 0.003)
        ueff = u*(1+dist)
        hs = dt/sub
        for _ in range(sub):
            k1 = f(h, ueff, Kl); k2 = f(h+hs/2*k1, ueff, Kl); k3 = f(h+hs/2*k2, ueff, Kl); k4 = f(h+hs*k3, ueff, Kl)
            h = np.clip(h + hs/6*(k1+2*k2+2*k3+k4), 0, 50)
    with open(out, 'w') as fh:
        fh.write('t,u,LT1,LT2,href\n')
        for r_ in rows: fh.write('%.1f,%.2f,%.5f,%.5f,%.3f\n' % r_)
    np.save(out.replace('.csv', '_truth.npy'), np.array(truth_h))
    json.dump(dict(seed=seed, variant=variant, lt2_offset_mA=lt2_off, t_fault=t_fault, Kl=Kl, **{k:v for k,v in TRUE.items() if k!='Kl'}),
              open(out.replace('.csv', '_truth.json'), 'w'))
if __name__ == '__main__':
    run(1, 'tanks_healthy.csv', 0)
    run(2, 'tanks_healthy2.csv', 1)
    run(3, 'tanks_lt2_offset.csv', 1, lt2_off=0.3, t_fault=300.0)
    run(4, 'tanks_noleak.csv', 0, Kl=0.0)

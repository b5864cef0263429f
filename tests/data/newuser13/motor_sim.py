"""Own emulation of the DC-motor speed rig (NOT fdigen simulate).
Truth: Coulomb friction Tc (not in the model), a load-torque step at t_load (not declared),
PI speed controller on the encoder speed, encoder 4096 counts/rev differenced each 1 ms,
current sensor with noise and 10 mA ADC quantisation."""
import json, numpy as np

TRUTH = dict(Ra=1.2, La=2.5e-3, Kt=0.05, Ke=0.05, J=1.0e-4, b=2.0e-5, Tc=0.008, w_eps=0.1,
             Tload=0.02, t_load=3.0, cpr=4096, i_noise=0.03, i_quant=0.01,
             kp=0.02, ki=0.4, Vmax=24.0, dt=1e-3)
RPM = 30/np.pi

def ref_rpm(t):
    edges = [0, 1.0, 2.5, 4.0, 5.5, 7.0, 8.5]
    vals = [1000., 2500., -1500., -3000., 1500., 3000., -2000.]
    return vals[np.searchsorted(edges, t, side='right') - 1]

def simulate(duration=10.0, seed=0, t_fault=6.0, cur_gain=None, enc_offset=None, winding=None, sub=20):
    p = TRUTH; rng = np.random.default_rng(seed); dt = p['dt']; n = int(round(duration/dt)); h = dt/sub
    x = np.zeros(3)  # i, w, theta
    cnt_prev = 0; I = 0.0; rows = []
    for k in range(n):
        t = k*dt; fault = t >= t_fault
        cnt = np.floor(x[2]*p['cpr']/(2*np.pi))
        rpm = (cnt - cnt_prev)/dt*60/p['cpr'] if k > 0 else 0.0
        cnt_prev = cnt
        if enc_offset is not None and fault: rpm += enc_offset
        im = x[0]*(1 + (cur_gain if (cur_gain is not None and fault) else 0.0)) + rng.normal(0, p['i_noise'])
        im = np.round(im/p['i_quant'])*p['i_quant']
        r = ref_rpm(t); e = r - rpm
        u = p['kp']*e + p['ki']*I
        if u > p['Vmax']:
            u = p['Vmax']; I += e*dt if e < 0 else 0.0
        elif u < -p['Vmax']:
            u = -p['Vmax']; I += e*dt if e > 0 else 0.0
        else:
            I += e*dt
        rows.append((t, u, rpm, im, r))
        Ra = p['Ra']*(1 + (winding if (winding is not None and fault) else 0.0))
        TL = p['Tload'] if t >= p['t_load'] else 0.0
        def f(x):
            i, w, th = x
            di = (u - Ra*i - p['Ke']*w)/p['La']
            dw = (p['Kt']*i - p['b']*w - p['Tc']*np.tanh(w/p['w_eps']) - TL)/p['J']
            return np.array([di, dw, w])
        for _ in range(sub):
            k1 = f(x); k2 = f(x+h/2*k1); k3 = f(x+h/2*k2); k4 = f(x+h*k3); x = x + h/6*(k1+2*k2+2*k3+k4)
    return np.array(rows)

def write(name, arr, truth):
    np.savetxt(name+'.csv', arr, delimiter=',', header='t,V,speed_rpm,i_meas,speed_ref', comments='', fmt='%.8g')
    json.dump(truth, open(name+'_truth.json', 'w'), indent=1)

if __name__ == '__main__':
    b = dict(TRUTH)
    write('motor_healthy', simulate(seed=0), dict(b, fault=None))
    write('motor_healthy2', simulate(seed=1), dict(b, fault=None, seed=1))
    write('motor_cgain', simulate(seed=2, cur_gain=0.10), dict(b, fault='current sensor gain +10%', t0=6.0))
    write('motor_encoff', simulate(seed=3, enc_offset=60.0), dict(b, fault='encoder offset +60 rpm', t0=6.0))
    write('motor_winding', simulate(seed=4, winding=0.30), dict(b, fault='winding resistance +30%', t0=6.0))

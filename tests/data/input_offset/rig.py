"""The buffer tank rig of tests/test_input_offset.py, written independently of fdigen: the
plant gets the metered inflow plus 0.4 L/min (the meter reads low), Kv = 0.85, Euler at
0.1 s, inflow steps of 600 s over the meter's range, level noise 0.05 cm, meter noise
0.03 L/min, 1 s samples."""

import numpy as np

OFFSET, KV, AREA = 0.4, 0.85, 1200.0


def write_log(path, seed: int = 5, samples: int = 7200) -> None:
    rng = np.random.default_rng(seed)
    K = samples
    qin = np.repeat(rng.choice([0.5, 2.0, 4.0, 7.0, 10.0, 11.5], K // 600 + 1), 600)[:K]
    h, ys = 40.0, []
    for k in range(K):
        ys.append(h)
        for _ in range(10):
            h += 0.1 * 1000 * (qin[k] + OFFSET - KV * np.sqrt(max(h, 0))) / (60 * AREA)
    y = np.array(ys) + 0.05 * rng.standard_normal(K)
    qm = qin + 0.03 * rng.standard_normal(K)
    with open(path, "w") as f:
        f.write("t,qin,level\n" + "".join(
            f"{k:.1f},{a:.4f},{b:.4f}\n" for k, a, b in zip(range(K), qm, y)))

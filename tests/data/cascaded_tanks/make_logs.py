"""Make fdigen logs (t, u, y) from the Cascaded Tanks benchmark's dataBenchmark.csv.

Run from anywhere: ``python tests/data/cascaded_tanks/make_logs.py``. Writes ``est.csv``
(the estimation record: uEst, yEst) and ``val.csv`` (the validation record: uVal, yVal)
next to this file, time from 0 s at the benchmark's sample time Ts (4 s).
"""

import csv
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> None:
    with open(HERE / "dataBenchmark.csv", newline="") as f:
        rows = [r for r in csv.reader(f) if r]
    head, body = rows[0], rows[1:]
    col = {name: i for i, name in enumerate(head)}
    ts = float(body[0][col["Ts"]])
    for name, u, y in (("est", "uEst", "yEst"), ("val", "uVal", "yVal")):
        lines = ["t,u,y"]
        for k, r in enumerate(body):
            lines.append(f"{k * ts:g},{r[col[u]]},{r[col[y]]}")
        (HERE / f"{name}.csv").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()

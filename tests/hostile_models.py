"""Hostile model files far under the per-expression limits (issue 23, case 11): each is
refused by fdigen.model.size before any derivation (they kept `build` busy past 240 s)."""
import sys
from pathlib import Path
DC = (Path(__file__).resolve().parents[1] / "src" / "fdigen" / "models" / "dc_motor.toml").read_text()

def with_defs(defs: dict, use: str) -> str:
    text = DC
    block = "[definitions]\n" + "".join(f'{k} = "{v}"\n' for k, v in defs.items()) + "\n"
    text = text.replace("[dynamics]", block + "[dynamics]", 1)
    return text.replace(chr(10) + "w = \"", chr(10) + "w = \"" + use + " + ", 1)

def hostile_models() -> dict:
    out = {}
    out["pow64"] = with_defs({"big": "(Ra + La + Kt + J + b)**64"}, "1e-30*big")
    chain = {"d0": "Ra*w + La*i"}
    for k in range(1, 13):
        chain[f"d{k}"] = f"0.5*d{k-1} + sin(d{k-1})"
    out["chain12"] = with_defs(chain, "1e-30*d12")
    out["nested64"] = with_defs({"big": "((Ra + w)**64 + J)**64"}, "1e-30*big")
    faults = "".join(f'\n[faults.extra{k}]\nlocation = "plant"\ntarget = "w"\nterm = "extra{k}"\nclass = "mechanical"\ntest_size = 1.0\n' for k in range(500))
    out["faults500"] = DC.replace("[operating_point]", faults + "\n[operating_point]", 1)
    return out

if __name__ == "__main__":
    d = Path(sys.argv[1]); d.mkdir(exist_ok=True)
    for k, v in hostile_models().items():
        (d / f"{k}.toml").write_text(v)

"""examples/controller embeds the generated core; its decisions equal the Python path."""

import shutil
import subprocess
from pathlib import Path

import pytest

from fdigen.detect import detect_log
from conftest import RIG

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def controller(tmp_path_factory):
    if shutil.which("make") is None or shutil.which("cc") is None:
        pytest.skip("make or cc not available")
    out = tmp_path_factory.mktemp("controller")
    subprocess.run(["make", "-s", f"OUT={out}"], cwd=ROOT / "examples" / "controller",
                   check=True, capture_output=True, text=True)
    return out / "controller"


@pytest.mark.parametrize("case", ["fdi_position_sensor_loss", "fdi_leak_p", "fdi_healthy",
                                  "fdi_pressure_n_drift"])
def test_controller_matches_python(controller, cylinder_design, case):
    log = RIG / "logs" / f"{case}.csv"
    if not log.is_file():
        pytest.skip("rig logs not available")
    with open(log) as fh:
        res = subprocess.run([str(controller)], stdin=fh, capture_output=True, text=True,
                             check=True)
    lines = res.stdout.splitlines()
    flags = [(w[1], round(float(w[2]), 4)) for w in map(str.split, lines) if w[0] == "flag"]
    summary, _ = detect_log(cylinder_design, log, backend="c")
    expected = [(f["residual"], round(f["t_raised"], 4)) for f in summary["flags"]]
    assert sorted(flags, key=lambda f: (f[1], f[0])) == expected
    final = dict(kv.split("=") for kv in lines[-1].split()[1:])
    assert final["class"] == summary["diagnosis"]["fault"]
    assert final["action"] == summary["diagnosis"]["action"]
    decisions = [w for w in map(str.split, lines) if w[0] == "decision"]
    if summary["diagnosis"]["t_isolated"] is not None:
        assert float(decisions[0][3]) == pytest.approx(summary["diagnosis"]["t_isolated"])

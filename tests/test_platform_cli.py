"""The platform on the command line: `fdigen simulate/detect/report --platform` and
`fdigen platform ik`.

One short closed-loop platform run (2.5 s, a valve loss on leg 4 at 1.0 s, the generated C
bank in the loop) is written once per module and read back by every command.
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from fdigen.cli import main
from fdigen.platform.demands import MotionSequence
from fdigen.platform.geometry import DOF_NAMES, default_geometry

LEGS = [f"leg{i}.csv" for i in range(1, 7)]


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _read_csv(path: Path) -> tuple[list, np.ndarray]:
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], np.array(rows[1:], dtype=float)


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("platform_cli") / "valve_leg4"
    res = _invoke("simulate", "--platform", "-o", out, "--duration", "2.5",
                  "--fault", "4:valve@1.0=-1", "--seed", "3")
    assert res.exit_code == 0, res.output
    return out, res.output


def _independent_lengths(base, top, home_height, pose):
    """Leg lengths from scipy's rotation (not fdigen's) and the joints as printed."""
    R = Rotation.from_euler("ZYX", [pose[5], pose[4], pose[3]]).as_matrix()
    p = np.array([pose[0], pose[1], home_height + pose[2]])
    return np.linalg.norm(p + np.asarray(top) @ R.T - np.asarray(base), axis=1)


# -- fdigen simulate --platform -----------------------------------------------------------------
def test_simulate_platform_writes_one_log_per_leg_and_the_pose_demand(run_folder):
    out, text = run_folder
    assert sorted(p.name for p in out.iterdir()) == sorted(LEGS + ["pose_demand.csv",
                                                                   "truth.json"])
    truth = json.loads((out / "truth.json").read_text())
    assert truth["truth"]["faults"] == [{"leg": 4, "kind": "valve", "t0": 1.0, "size": -1.0,
                                         "ramp": False, "stuck": False}]
    online = truth["online_decision"]
    assert online["faulty_leg"] == 4 and online["fault_class"] == "pneumatic_or_actuator"
    assert f"online decision: {online['text']}" in text
    # the pose demand is the paper's sequence (heave first): compare with the generator
    head, pose = _read_csv(out / "pose_demand.csv")
    assert head == ["t", *DOF_NAMES]
    t = pose[:, 0]
    assert len(t) == 2500 and t[1] - t[0] == pytest.approx(1e-3)
    np.testing.assert_allclose(pose[:, 1:], MotionSequence().pose(t), atol=1e-9)
    # each leg's demand is the inverse kinematics of that pose until the safety sequence
    geo = default_geometry()
    k_stop = int(round(online["t_safety_start"] / 1e-3))
    assert 1.0 < online["t_safety_start"] < 1.5
    xref = []
    for i, name in enumerate(LEGS):
        head, data = _read_csv(out / name)
        assert head == ["t", "u", "x", "x2", "pp", "pn", "xref"]
        np.testing.assert_array_equal(data[:, 0], t)
        xref.append(data[:, head.index("xref")])
    xref = np.array(xref).T
    ik = np.array([_independent_lengths(geo.base, geo.top, geo.home_height, q)
                   for q in pose[:k_stop + 1, 1:]]) - geo.l_min
    np.testing.assert_allclose(xref[:k_stop + 1], ik, atol=1e-9)
    # after the trigger every leg heads for its rest position, inside the stroke
    assert np.all(xref[k_stop:] >= 0) and np.all(xref[k_stop:] <= geo.stroke)
    assert np.all(np.abs(xref[-1] - geo.rest_positions) < np.abs(xref[k_stop]
                                                                  - geo.rest_positions))


def test_simulate_platform_refuses_what_it_cannot_do(tmp_path):
    res = _invoke("simulate", "--platform", "-o", tmp_path / "r", "--duration", "1",
                  "--fault", "3:no_such_fault@0.5=1")
    assert res.exit_code == 2
    assert "leg 3" in res.output and "no fault 'no_such_fault'" in res.output
    assert not (tmp_path / "r").exists()
    res = _invoke("simulate", "--platform", "-o", tmp_path / "r", "--fault", "valve@0.5=-1")
    assert res.exit_code == 2 and "LEG:NAME@T0=SIZE" in res.output
    res = _invoke("simulate", "-o", tmp_path / "x.csv", "--bank", "python")
    assert res.exit_code == 2 and "--bank: only with --platform" in res.output
    res = _invoke("simulate", "--platform", "-o", tmp_path / "r", "--effect",
                  "coulomb_friction=30")
    assert res.exit_code == 2 and "--effect: not with --platform" in res.output
    (tmp_path / "file").write_text("")
    res = _invoke("simulate", "--platform", "-o", tmp_path / "file")
    assert res.exit_code == 2 and "is a file" in res.output


# -- fdigen detect --platform -------------------------------------------------------------------
def test_detect_platform_names_the_leg_and_equals_the_online_bank(run_folder, tmp_path):
    out, _ = run_folder
    res = _invoke("detect", "--platform", out, "--json")
    assert res.exit_code == 0, res.output
    s = json.loads(res.output)
    truth = json.loads((out / "truth.json").read_text())["online_decision"]
    p = s["platform"]
    assert p["faulty_leg"] == 4 and p["fault_class"] == "pneumatic_or_actuator"
    assert p["action"] == "safety_stop" and p["legs_with_decision"] == [4]
    # offline over the logs (compiled single-leg core + Python supervisor) = the C bank online
    for key in ("t_decision", "t_safety_start", "faulty_leg", "fault_class"):
        assert p[key] == truth[key], key
    assert [leg["leg"] for leg in s["legs"]] == [1, 2, 3, 4, 5, 6]
    assert s["legs"][3]["fdi"]["diagnosis"]["fault"] == "pneumatic_or_actuator"
    assert all(leg["fdi"]["flags"] == [] for i, leg in enumerate(s["legs"]) if i != 3)
    # the `platform` group's command says the same
    group = _invoke("platform", "detect", out, "--json")
    assert group.exit_code == 0 and json.loads(group.output) == s
    text = _invoke("detect", "--platform", out)
    assert text.exit_code == 0
    assert f"leg 4: pneumatic_or_actuator at {p['t_decision']:.3f} s, action safety_stop" \
        in text.output
    assert text.output.strip().splitlines()[-1] == f"platform: {p['text']}"


def test_detect_platform_errors_name_the_problem(run_folder, tmp_path):
    out, _ = run_folder
    res = _invoke("detect", out)                       # a folder without --platform
    assert res.exit_code == 2 and "needs --platform" in res.output
    partial = tmp_path / "partial"
    shutil.copytree(out, partial)
    (partial / "leg5.csv").unlink()
    res = _invoke("detect", "--platform", partial)
    assert res.exit_code == 2 and "leg5.csv: missing" in res.output
    lines = (partial / "leg2.csv").read_text().splitlines()
    (partial / "leg5.csv").write_text("\n".join(lines[:-100]) + "\n")
    res = _invoke("detect", "--platform", partial)
    assert res.exit_code == 2 and "time base differs" in res.output
    res = _invoke("detect", out / "leg1.csv", "--geometry", out / "truth.json")
    assert res.exit_code == 2 and "--geometry: only with --platform" in res.output


# -- fdigen report --platform -------------------------------------------------------------------
def test_report_platform_draws_the_overview_and_each_leg(run_folder, tmp_path, monkeypatch):
    out, _ = run_folder
    png = tmp_path / "overview.png"
    res = _invoke("report", "--platform", out, "-o", png, "--no-per-leg")
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert list(tmp_path.iterdir()) == [png]
    assert "leg 4: pneumatic_or_actuator" in res.output
    # each leg's residual report (fdigen.report.render_report, drawn and tested for single
    # logs in test_report.py; recorded here, a drawing costs seconds): one per leg log
    import fdigen.report
    calls = []
    monkeypatch.setattr(fdigen.report, "render_report",
                        lambda design, log, output, backend: calls.append((log, output)))
    res = _invoke("report", "--platform", out, "-o", png)
    assert res.exit_code == 0, res.output
    assert calls == [(out / f"leg{i}.csv", tmp_path / f"overview_leg{i}.png")
                     for i in range(1, 7)]
    assert all(str(path) in res.output for _, path in calls)
    res = _invoke("report", "--platform", out, "-o", tmp_path / "overview.html")
    assert res.exit_code == 2 and ".png figure" in res.output
    res = _invoke("report", out / "leg1.csv", "-o", tmp_path / "a.png", "--no-per-leg")
    assert res.exit_code == 2 and "--per-leg/--no-per-leg: only with --platform" in res.output


# -- fdigen platform ik -------------------------------------------------------------------------
def test_ik_json_prints_the_geometry_and_lengths_checked_independently():
    pose = [0.012, -0.02, 0.025, 0.06, -0.05, 0.11]
    res = _invoke("platform", "ik", "--pose", ",".join(map(str, pose)), "--json")
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    g = data["geometry"]
    base, top = np.array(g["base_joints"]), np.array(g["top_joints"])
    assert base.shape == top.shape == (6, 3)
    # the default platform: base joints on a 0.5 m circle, top joints on a 0.3 m circle,
    # pairs 20 degrees apart
    np.testing.assert_allclose(np.hypot(base[:, 0], base[:, 1]), 0.5, atol=1e-12)
    np.testing.assert_allclose(np.hypot(top[:, 0], top[:, 1]), 0.3, atol=1e-12)
    ang = np.degrees(np.arctan2(base[:, 1], base[:, 0]))
    assert abs((ang[1] - ang[0]) % 360 - 20.0) < 1e-9
    lengths = _independent_lengths(base, top, g["home_height"], pose)
    np.testing.assert_allclose(data["leg_lengths"], lengths, rtol=0, atol=1e-12)
    np.testing.assert_allclose(data["piston_positions"], lengths - g["l_min"], atol=1e-12)
    assert data["pose"] == dict(zip(DOF_NAMES, pose))
    # degrees in, the same pose
    deg = pose[:3] + [float(np.degrees(a)) for a in pose[3:]]
    res = _invoke("platform", "ik", "--pose", ",".join(map(str, deg)), "--degrees", "--json")
    np.testing.assert_allclose(json.loads(res.output)["leg_lengths"], lengths, atol=1e-12)


def test_ik_out_of_reach_is_a_clear_error():
    geo = default_geometry()
    pose = [0.0, 0.05, 0.09, 0.0, 0.12, 0.0]
    lengths = _independent_lengths(geo.base, geo.top, geo.home_height, pose)
    worst = int(np.argmax(lengths))
    excess_mm = (lengths[worst] - geo.l_min - geo.stroke) * 1e3
    assert excess_mm > 0
    res = _invoke("platform", "ik", "--pose", ",".join(map(str, pose)), "--json")
    assert res.exit_code == 2
    msg = res.stderr.strip()        # with --json, stdout holds the JSON error object
    assert msg.startswith("fdigen: error: pose (") and "out of reach" in msg
    err = json.loads(res.stdout)["error"]
    assert err["exit_code"] == 2 and err["message"] == msg[len("fdigen: error: "):]
    assert f"leg {worst + 1} " in msg and f"{excess_mm:.2f} mm beyond full extension" in msg
    res = _invoke("platform", "ik", "--pose", "0,0,0,0,0", "--json")
    assert res.exit_code == 2 and "expected 6 numbers" in res.output


def test_ik_through_the_installed_command():
    exe = Path(sys.executable).with_name("fdigen")
    if not exe.exists():
        pytest.skip("fdigen console script not installed beside the interpreter")
    proc = subprocess.run([str(exe), "platform", "ik", "--pose", "0,0,0,0,0,0", "--json"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    geo = default_geometry()
    np.testing.assert_allclose(data["leg_lengths"], geo.l_min + geo.stroke / 2, atol=1e-12)
    np.testing.assert_allclose(data["geometry"]["base_joints"], geo.base.tolist())

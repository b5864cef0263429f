"""The closed-loop simulator: faults as declared, stuck sensors, drifts, the CLI."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.detect import fdi_runner, summarise_run
from fdigen.sim.plant import FaultEvent, simulate


def test_healthy_run_tracks_the_demand_and_respects_limits(cylinder):
    sim = simulate(cylinder, 6.0, seed=1)
    x = sim.x[:, cylinder.state_index("x")]
    assert np.abs(x[2000:] - sim.ref[2000:]).max() < 0.01
    p = sim.x[:, :2]
    assert p.min() >= 101325.0 and p.max() <= 6e5
    assert np.abs(sim.u).max() <= 5.0


def test_stuck_sensor_holds_its_last_value_and_is_isolated(cylinder, cylinder_design):
    sim = simulate(cylinder, 8.0, seed=2, faults=(FaultEvent("position_sensor", 4.0, 0.0,
                                                             stuck=True),))
    x3 = sim.y[:, 0]
    assert np.all(x3[4000:] == x3[3999])
    assert np.std(np.diff(x3[:3999])) > 0
    s = summarise_run(cylinder_design, sim.t, fdi_runner(cylinder_design, "c").run(sim.u, sim.y))
    assert s["diagnosis"]["fault"] == "position_sensor" and s["diagnosis"]["t_isolated"] > 4.0


def test_drift_grows_at_its_rate(cylinder):
    sim = simulate(cylinder, 4.0, seed=3, noise=False,
                   faults=(FaultEvent("pressure_sensor_n", 2.0, 1e4, ramp=True),))
    ref = simulate(cylinder, 4.0, seed=3, noise=False)
    # the plant is the same until the drift reaches the controller (it does not: pn is
    # not fed back), so the measured difference is exactly the ramp
    diff = sim.y[:, 3] - ref.y[:, 3]
    np.testing.assert_allclose(diff[3000], 1e4 * 1.0, rtol=1e-9)
    assert np.all(diff[:2000] == 0)


def test_non_sensor_cannot_stick(cylinder):
    from fdigen.errors import FdigenError
    with pytest.raises(FdigenError, match="not a sensor fault"):
        simulate(cylinder, 1.0, faults=(FaultEvent("valve", 0.5, 0.0, stuck=True),))


def test_simulate_cli_writes_log_and_truth(tmp_path):
    out = tmp_path / "run.csv"
    res = CliRunner().invoke(main, ["simulate", "--duration", "2", "-o", str(out),
                                    "--fault", "leak_p@1.0=3e-10",
                                    "--fault", "position_sensor@1.5=stuck"])
    assert res.exit_code == 0, res.output
    header = out.read_text().splitlines()[0].split(",")
    assert header[:6] == ["t", "u", "x", "x2", "pp", "pn"]
    truth = json.loads(out.with_suffix(".json").read_text())
    kinds = {f["kind"]: f for f in truth["truth"]["faults"]}
    assert kinds["leak_p"]["size"] == 3e-10 and kinds["position_sensor"]["stuck"]
    res = CliRunner().invoke(main, ["simulate", "-o", str(out), "--fault", "nope@1=2"])
    assert res.exit_code == 2 and "unknown fault" in res.output


def test_chunked_run_does_not_depend_on_the_chunk_length(cylinder, monkeypatch):
    """A run chained over chunks equals the same run in other chunk lengths, bit for bit:
    the chunk boundary (padding, carried state, held sensor values) changes nothing."""
    import fdigen.sim.plant as plant

    events = (FaultEvent("leak_p", 0.9, 2e-7), FaultEvent("pressure_sensor_n", 1.1, 0.0,
                                                           stuck=True))
    runs = []
    for chunk in (1000, 7, 333):
        monkeypatch.setattr(plant, "CHUNK_SAMPLES", chunk)
        monkeypatch.setattr(plant, "_PLANT_CACHE", type(plant._PLANT_CACHE)())
        runs.append(simulate(cylinder, 1.5, seed=5, faults=events))
    assert len(runs[0].t) == 1500
    for other in runs[1:]:
        for name in ("u", "y", "x"):
            assert np.array_equal(getattr(runs[0], name), getattr(other, name)), name
    # the stuck sensor holds across chunk boundaries
    assert np.all(runs[1].y[1100:, 3] == runs[1].y[1099, 3])


def test_plant_is_built_once_per_identity(cylinder, monkeypatch):
    import fdigen.sim.plant as plant

    monkeypatch.setattr(plant, "_PLANT_CACHE", type(plant._PLANT_CACHE)())
    built = []
    original = plant._plant_functions
    monkeypatch.setattr(plant, "_plant_functions",
                        lambda *a, **k: built.append(a[1:]) or original(*a, **k))
    simulate(cylinder, 0.2, seed=1)
    simulate(cylinder, 0.3, seed=2)
    assert len(built) == 1
    simulate(cylinder, 0.2, seed=1, substeps=5)
    assert len(built) == 2

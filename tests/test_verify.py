"""Proof of equivalence: every backend against the symbolic reference."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.sim.plant import FaultEvent, simulate
from fdigen.verify.equivalence import POINT_RTOL, TRAJECTORY_RTOL, verify


@pytest.fixture(scope="module")
def trajectories(cylinder_design):
    """Three 20 s closed-loop runs at 1 kHz: healthy, valve loss, position sensor loss."""
    model = cylinder_design.model
    out = []
    for k, faults in enumerate([(), (FaultEvent("valve", 8.0, -1.0),),
                                (FaultEvent("position_sensor", 8.0, -1.0),),
                                (FaultEvent("pressure_sensor_n", 8.0, 2e4, ramp=True),)]):
        sim = simulate(model, 20.0, faults=faults, seed=100 + k)
        out.append((faults[0].name if faults else "healthy", sim.u, sim.y))
    return out


def test_all_backends_equal_the_reference(cylinder_design, trajectories):
    rep = verify(cylinder_design, n_points=1000, trajectories=trajectories)
    assert set(rep["backends"]) == {"casadi_sx", "casadi_compiled", "c"}
    for name, b in rep["backends"].items():
        s = b["summary"]
        assert s["points_max_rel"] <= POINT_RTOL, (name, s)
        assert s["trajectories_max_rel"] <= TRAJECTORY_RTOL, (name, s)
        assert s["discrete_mismatches"] == 0, (name, s)
        assert b["points:r.R1"]["compared"] == 1000
        assert b["trajectory:flags"]["compared"] == 4 * 20000
    # the trajectories exercise the logic: faults are isolated, not only healthy samples
    from fdigen.backends.reference import ReferenceFdi
    out = ReferenceFdi(cylinder_design).run(trajectories[1][1], trajectories[1][2])
    assert out["fault_class"][-1] > 0


def test_verify_detects_a_wrong_backend(cylinder_design, trajectories):
    """The comparison can fail: a backend with a perturbed gain is caught."""
    from fdigen.backends.reference import ReferenceFdi
    from fdigen.verify.equivalence import compare_points, random_points

    class Perturbed(ReferenceFdi):
        def core(self, z, u, y, mode):
            zn, r, aux = super().core(z, u, y, mode)
            return zn, r * (1 + 1e-9), aux

    pts = random_points(cylinder_design, 50, seed=5)
    diffs = compare_points(cylinder_design, Perturbed(cylinder_design), "perturbed", pts)
    worst = max(d.max_rel for d in diffs if d.output.startswith("r."))
    assert worst > POINT_RTOL


def test_verify_cli_json(cylinder_design):
    res = CliRunner().invoke(main_cli(), ["verify", "--json", "--points", "200",
                                          "--duration", "2", "--backend", "c"])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.output)
    assert rep["points"] == 200 and rep["backends"]["c"]["summary"]["ok"] and rep["ok"]
    entry = rep["backends"]["c"]["points:r.R4"]
    assert set(entry) >= {"max_abs", "max_rel", "compared"}


def main_cli():
    from fdigen.cli import main
    return main


def test_random_points_cover_the_range(cylinder_design):
    from fdigen.verify.equivalence import random_points
    pts = random_points(cylinder_design, 1000, seed=0)
    x3 = pts["y"][:, 0]
    assert 0.02 < x3.min() < 0.04 and 0.16 < x3.max() < 0.18
    assert set(np.unique(pts["mode"])) == {0.0, 1.0}


@pytest.fixture(scope="module")
def coulomb_design(cylinder):
    """The cylinder augmented with Coulomb friction (as `fdigen discover` writes it), whose
    Kalman filters predict through the nonlinear model, and a healthy run of that rig."""
    from fdigen.design.fdi_design import fdi_design
    from fdigen.discover import effects as fx
    from fdigen.discover.augment import augmented_text, check_augmented
    from fdigen.model.model_file import builtin_model_path

    e = fx.get_effect("coulomb_friction", cylinder)
    values = {"Fc": e.parameters[0].nominal}
    text = augmented_text(builtin_model_path("pneumatic_cylinder").read_text(), cylinder,
                          [e], values)
    design = fdi_design(check_augmented(text, cylinder, [e], "coulomb_augmented.toml"))
    sim = simulate(cylinder, 3.0, effects=e.plant_effects(cylinder, values), seed=7,
                   substeps=4)
    return design, sim


def test_nonlinear_prediction_is_bit_identical_on_every_backend(coulomb_design):
    """RK4 of the model's own f (a friction tanh) inside the Kalman filters: every backend
    equals the reference bit for bit, on random points and on a closed-loop trajectory."""
    design, sim = coulomb_design
    assert {k.schedule for k in design.kalman} == {"nonlinear"}
    rep = verify(design, n_points=300, trajectories=[("healthy", sim.u, sim.y)])
    assert set(rep["backends"]) == {"casadi_sx", "casadi_compiled", "c"}
    for name, b in rep["backends"].items():
        s = b["summary"]
        assert s["points_max_rel"] == 0.0 and s["trajectories_max_rel"] == 0.0, (name, s)
        assert s["discrete_mismatches"] == 0, (name, s)
        assert b["points:r.R5"]["compared"] == 300

"""Shared fixtures: designs are derived once per test session."""

from pathlib import Path

import numpy as np
import pytest

from fdigen.design.fdi_design import fdi_design
from fdigen.model.model_file import load_model

RIG = Path(__file__).resolve().parents[2] / "shared" / "rig"
if not RIG.is_dir():  # CI clones main with shared/ beside it
    RIG = Path(__file__).resolve().parents[1] / ".." / "shared" / "rig"


@pytest.fixture(scope="session")
def cylinder():
    return load_model()


@pytest.fixture(scope="session")
def cylinder_design(cylinder):
    return fdi_design(cylinder)


@pytest.fixture(scope="session")
def motor():
    return load_model("dc_motor")


@pytest.fixture(scope="session")
def motor_design(motor):
    return fdi_design(motor)


def read_rig_log(name):
    """(u, y) arrays of a reference rig log, in the built-in model's input/output order."""
    path = RIG / "logs" / f"{name}.csv"
    if not path.is_file():
        pytest.skip(f"reference rig log {path} not available")
    data = np.genfromtxt(path, delimiter=",", names=True)
    u = data["u"][:, None]
    y = np.stack([data["x"], data["x2"], data["pp"], data["pn"]], axis=1)
    return data["t"], u, y

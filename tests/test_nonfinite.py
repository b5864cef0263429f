"""Non-finite or absurd measurements raise the sensor's flag and never poison the core."""

import numpy as np
import pytest

from fdigen.backends.c.loader import CFdi
from fdigen.backends.reference import ReferenceFdi
from conftest import read_rig_log


@pytest.mark.parametrize("column,value,cls", [
    (0, np.nan, "position_sensor"), (0, np.inf, "position_sensor"),
    (1, -np.inf, "position_sensor"), (2, np.nan, "pressure_sensor_p"),
    (3, 1e30, "pressure_sensor_n"), (2, -np.inf, "pressure_sensor_p"),
])
def test_invalid_sample_isolates_the_sensor_and_stays_finite(cylinder_design, column, value, cls):
    t, u, y = read_rig_log("fdi_healthy")
    u, y = u[:6000].copy(), y[:6000].copy()
    y[3000:3050, column] = value                  # 50 ms of an invalid signal
    ev = cylinder_design.evaluation
    out = CFdi(cylinder_design).run(u, y)
    for key in ("r", "rms", "aux"):
        assert np.all(np.isfinite(out[key])), key
    name = f"nf_{cylinder_design.model.outputs[column].name}"
    bit = 1 << cylinder_design.residual_names.index(name)
    assert out["flags"][2999] == 0 and out["flags"][3000] & bit
    assert ev.classes[out["fault_class"][-1]] == cls
    with np.errstate(all="ignore"):
        ref = ReferenceFdi(cylinder_design).run(u, y)
    assert np.array_equal(ref["flags"], out["flags"])
    assert np.array_equal(ref["fault_class"], out["fault_class"])
    np.testing.assert_allclose(out["rms"], ref["rms"], rtol=1e-9, atol=0)


def test_invalid_first_sample_initialises_from_the_operating_point(cylinder_design):
    t, u, y = read_rig_log("fdi_healthy")
    u, y = u[:500].copy(), y[:500].copy()
    y[0, :] = np.nan
    u[0, 0] = np.inf
    out = CFdi(cylinder_design).run(u, y)
    assert np.all(np.isfinite(out["r"])) and np.all(np.isfinite(out["rms"]))

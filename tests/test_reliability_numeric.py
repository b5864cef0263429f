"""Numeric safety of the generated FDI core (issue 13, item 7).

* NaN never hides a fault: a residual that becomes non-finite reads as an infinite RMS and
  raises its latched flag, identically in the reference, CasADi and C (double) backends
  (and in C float); the window sums stay finite.
* ``_step`` on a state never given to ``_init`` (or corrupted) returns ``_ERR_STATE``
  instead of indexing out of bounds (checked under ASan and UBSan).
* The shipped parameter bounds lie where the design's stability checks pass (every bound,
  and the corners of the widest ones), so ``_init``, which refuses values outside the
  bounds, refuses the values that made the filters diverge (M = 0.01, V0 = 1e-8).
"""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from reliability_log import reporter
from test_reliability_c import CDIR, SRC, _cc

from fdigen.backends.c.loader import CFdi
from fdigen.backends.casadi_backend.runner import CasadiFdi
from fdigen.backends.reference import ReferenceFdi
from fdigen.design.parameter_range import corner_parameters, unstable_bounds

report = reporter("generated C core")

#: Parameter values (outside the shipped bounds) that make the motor's parallel model
#: diverge within tens of samples: the residuals become infinite, then NaN.
DIVERGENT = {"J": 1e-8, "La": 1e-6}


def _log(design, K=300):
    m = design.model
    u = np.full((K, 1), m.operating_point["V"])
    y = np.empty((K, 2))
    y[:, 0] = m.operating_point["w"]
    y[:, 1] = m.operating_point["i"]
    return u, y


def _check_flags_follow_nonfinite(out, nr):
    bad = ~np.isfinite(out["r"])
    assert bad.any(), "the divergent parameters did not make a residual non-finite"
    flags = out["flags"].astype(np.int64)
    for k, i in zip(*np.nonzero(bad)):
        assert flags[k] >> i & 1, (k, i, out["r"][k, i], out["rms"][k, i])
        assert out["rms"][k, i] == np.inf, (k, i, out["rms"][k, i])
    assert not np.isnan(out["rms"]).any()
    hidden = 0        # non-finite while the flag was still down: an old NaN-RMS would hide it
    for i in range(nr):
        ks = np.nonzero(bad[:, i])[0]
        if ks.size and (ks[0] == 0 or not flags[ks[0] - 1] >> i & 1):
            hidden += 1
    return int(bad.sum()), hidden


@pytest.mark.parametrize("values,what", [
    (DIVERGENT, "divergent parameters J = 1e-8, La = 1e-6: residuals grow, then inf/NaN"),
    ({"b": float("nan")}, "a NaN parameter b (as a corrupted struct): NaN from sample 0"),
], ids=["divergent", "nan-parameter"])
def test_nan_residual_keeps_its_flag_raised_in_every_backend(motor_design, values, what):
    d = motor_design
    nr = len(d.residual_names)
    u, y = _log(d)
    with np.errstate(all="ignore"):
        ref = ReferenceFdi(d, values).run(u, y)
        cas = CasadiFdi(d, values).run(u, y)
        outs = {"reference": ref, "casadi": cas}
        for ft in ("double", "float"):
            c = CFdi(d, float_type=ft)           # init with valid parameters, then swap
            names = [q.name for q in d.model.parameters]
            for name, value in values.items():
                setattr(c.params, name, value)
                c.p[names.index(name)] = value
            outs[f"c {ft}"] = c.run(u, y)
    counts = {}
    for name, out in outs.items():
        counts[name] = _check_flags_follow_nonfinite(out, nr)
    for name in ("casadi", "c double"):
        for key in ("flags", "fault_class", "action"):
            assert np.array_equal(outs[name][key], ref[key]), (name, key)
        for key in ("r", "rms"):
            assert np.array_equal(outs[name][key], ref[key], equal_nan=True), (name, key)
    n_bad, hidden = counts["reference"]
    report("test_nan_residual_keeps_its_flag_raised_in_every_backend",
           "residuals driven non-finite on a 300-sample log in the reference, CasADi, C "
           f"double and C float backends: {what}", n_bad * len(outs), "pass",
           f"{n_bad} non-finite residual samples per backend, {hidden} residuals went "
           "non-finite with their flag down (an RMS of 0 hid them before); every one read "
           "RMS = inf with its flag raised; CasADi and C double bit-identical to the "
           "reference")


STATE_DRIVER = r"""
#include "pneumatic_cylinder_fdi.h"
#include <stdio.h>
#include <string.h>

#define P(x) PNEUMATIC_CYLINDER_FDI_##x
static pneumatic_cylinder_fdi_state s;

int main(void)
{
    pneumatic_cylinder_fdi_params p;
    pneumatic_cylinder_fdi_output out;
    double u[P(NU)] = {0}, y[P(NY)] = {0.1, 0.1, 3.5e5, 3.5e5};
    int cases = 0, bad = 0, st;
    pneumatic_cylinder_fdi_default_params(&p);
#define EXPECT(what, status) do { st = pneumatic_cylinder_fdi_step(&s, &p, u, y, &out); \
    cases++; if (st != (status)) { bad++; printf("%s: %d\n", what, st); } } while (0)
    memset(&s, 0xA5, sizeof s);
    EXPECT("garbage state", P(ERR_STATE));
    memset(&s, 0, sizeof s);
    EXPECT("zeroed state", P(ERR_STATE));
    memset(&s, 0xFF, sizeof s);
    EXPECT("all-ones state", P(ERR_STATE));
    pneumatic_cylinder_fdi_init(&s, &p);
    s.index = P(WINDOW);
    EXPECT("index = WINDOW", P(ERR_STATE));
    pneumatic_cylinder_fdi_init(&s, &p);
    s.index = -1;
    EXPECT("index = -1", P(ERR_STATE));
    pneumatic_cylinder_fdi_init(&s, &p);
    s.decision = P(NCLASSES);
    EXPECT("decision = NCLASSES", P(ERR_STATE));
    pneumatic_cylinder_fdi_init(&s, &p);
    s.candidate = -7;
    EXPECT("candidate = -7", P(ERR_STATE));
    pneumatic_cylinder_fdi_init(&s, &p);
    s.initialised = 1;
    EXPECT("initialised = 1 (old flag value)", P(ERR_STATE));
    pneumatic_cylinder_fdi_init(&s, &p);
    EXPECT("after init", P(OK));
    EXPECT("second step", P(OK));
    pneumatic_cylinder_fdi_reset(&s);
    EXPECT("after reset", P(OK));
    printf("{\"cases\": %d, \"bad\": %d}\n", cases, bad);
    return bad != 0;
}
"""


def test_step_on_a_state_not_set_up_by_init_is_refused(tmp_path):
    cc = _cc()
    driver = tmp_path / "state.c"
    driver.write_text(STATE_DRIVER)
    exe = tmp_path / "state"
    cmd = [cc, "-std=c99", "-D_POSIX_C_SOURCE=200809L", "-O1", "-g", "-Wall", "-Wextra",
           "-Werror", "-pedantic", "-fsanitize=address,undefined",
           "-fno-sanitize-recover=all", f"-I{CDIR}", str(driver), str(SRC), "-o", str(exe),
           "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stdout + run.stderr
    stats = json.loads(run.stdout.strip().splitlines()[-1])
    report("test_step_on_a_state_not_set_up_by_init_is_refused",
           "_step on a state never given to _init (garbage, zeroed, all-ones) or corrupted "
           "(index, decision, candidate out of range, old 'initialised' flag), under "
           f"ASan+UBSan ({cc})", stats["cases"] - 3, "pass",
           "every one -> ERR_STATE, no out-of-bounds access; after _init/_reset -> OK")


@pytest.mark.parametrize("which", ["motor", "cylinder"])
def test_shipped_bounds_pass_the_design_checks(which, request):
    design = request.getfixturevalue(f"{which}_design")
    failures = unstable_bounds(design)
    corners = corner_parameters(design)
    n_bounded = sum(q.bounds is not None for q in design.model.parameters)
    assert not failures, failures[:3]
    report(f"test_shipped_bounds_pass_the_design_checks[{design.name}]",
           f"{design.name}: RK4 step and scheduled-filter checks at every parameter bound "
           f"and the corners of {', '.join(corners)}", 2 * n_bounded + 2 ** len(corners),
           "pass", "every bound and corner stable: _init's bounds refuse the unstable values")


def test_init_refuses_the_values_that_made_the_filters_diverge(cylinder_design):
    refused = 0
    for values in ({"M": 0.01}, {"V0": 1e-8}):
        with pytest.raises(ValueError, match="rejected by pneumatic_cylinder_fdi_init"):
            CFdi(cylinder_design, values)
        refused += 1
    report("test_init_refuses_the_values_that_made_the_filters_diverge",
           "M = 0.01, V0 = 1e-8 (were within the bounds; filters diverged in 3-28 samples)",
           refused, "pass", "_init returns ERR_PARAM(i)")

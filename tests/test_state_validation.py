"""A corrupted FDI state is detected, never trusted (issue 23 case 9, issue 24).

Each kind of state field is corrupted after a healthy prefix of a rig log; the next step
of every backend (reference, CasADi, generated C) must read the corrupted residuals as an
infinite RMS and raise their flags, identically, and the C step returns _WARN_STATE.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import read_rig_log
from fdigen.backends.c import CFdi
from fdigen.backends.casadi_backend import CasadiFdi
from fdigen.backends.reference import ReferenceFdi

WARN_STATE = 2
PREFIX = 150           # healthy samples before the corruption (fewer than the window)
RESIDUAL = 3           # the residual whose evaluation state is corrupted


@pytest.fixture(scope="module")
def backends(cylinder_design, tmp_path_factory):
    return {"reference": ReferenceFdi(cylinder_design),
            "casadi": CasadiFdi(cylinder_design),
            "c": CFdi(cylinder_design, cache_dir=tmp_path_factory.mktemp("c_state"))}


@pytest.fixture(scope="module")
def healthy():
    _, u, y = read_rig_log("fdi_healthy")
    return u, y


def _corrupt(name, fdi, kind, value):
    """Write ``value`` into one state field of a backend's state."""
    i = RESIDUAL
    if name == "reference":
        st = fdi.state
        if kind == "sums":
            st.sums[i] = value
        elif kind == "buffer":
            st.buffer[st.index, i] = value
        else:
            setattr(st, kind, int(value))
    elif name == "casadi":
        s = fdi.state.copy()
        lay = fdi.layout
        offset = {"sums": lay["sums"].start + i, "buffer": lay["buffer"].start + i,
                  "count": lay["count"].start, "frozen": lay["frozen"].start}[kind]
        s[offset] = value
        fdi.state = s
    else:
        st = fdi.state
        if kind == "sums":
            st.sums[i] = value
        elif kind == "buffer":
            st.buf[st.index][i] = value
        else:
            setattr(st, kind, int(value))


def _prefix(fdi, u, y):
    if hasattr(fdi, "reset"):
        fdi.reset()
    for k in range(PREFIX):
        out = fdi.step(u[k], y[k])
    return out


CASES = [("sums", np.nan), ("sums", -1e300), ("sums", np.inf), ("sums", 1e308),
         ("buffer", np.nan), ("buffer", -1e300), ("buffer", -np.inf), ("buffer", 1e306),
         ("count", -1), ("frozen", -7)]


@pytest.mark.parametrize("kind,value", CASES)
def test_corrupted_state_raises_flags_in_every_backend(backends, healthy, kind, value):
    u, y = healthy
    results = {}
    for name, fdi in backends.items():
        before = _prefix(fdi, u, y)
        assert before["flags"] == 0, f"{name}: the healthy prefix raised flags"
        _corrupt(name, fdi, kind, value)
        out = fdi.step(u[PREFIX], y[PREFIX])
        results[name] = out
        if kind in ("sums", "buffer"):
            assert out["flags"] >> RESIDUAL & 1, f"{name}: {kind}={value} raised no flag"
            assert np.isinf(out["rms"][RESIDUAL]), f"{name}: {kind}={value}: finite RMS"
        else:
            assert out["flags"] == (1 << len(out["rms"])) - 1, \
                f"{name}: corrupted {kind} did not raise every flag"
            assert np.isinf(out["rms"]).all()
        if name == "c":
            assert fdi.last_status == WARN_STATE, f"C step returned {fdi.last_status}"
        if name == "reference":
            assert fdi.state_corrupt
    for name in ("casadi", "c"):
        for key in ("flags", "fault_class", "action", "faults"):
            assert results[name][key] == results["reference"][key], (name, key)
        np.testing.assert_array_equal(results[name]["rms"], results["reference"]["rms"])
        np.testing.assert_array_equal(results[name]["r"], results["reference"]["r"])


@pytest.mark.parametrize("field", ["flags", "late"])
def test_flag_bits_beyond_the_residuals_are_corruption(backends, healthy, field):
    """Masks exist in the C and reference states only (CasADi keeps one 0/1 per flag)."""
    u, y = healthy
    for name in ("reference", "c"):
        fdi = backends[name]
        _prefix(fdi, u, y)
        setattr(fdi.state, field, 1 << 30)
        out = fdi.step(u[PREFIX], y[PREFIX])
        assert np.isinf(out["rms"]).all(), f"{name}: {field} bit 30 not detected"
        assert out["flags"] & ((1 << len(out["rms"])) - 1) == (1 << len(out["rms"])) - 1


def test_corrupted_buffer_entry_is_caught_when_it_leaves_the_window(backends, healthy):
    """An entry is validated when it is read: at the latest WINDOW steps later."""
    u, y = healthy
    fdi = backends["c"]
    _prefix(fdi, u, y)
    window = fdi.design.evaluation.window
    ahead = 17
    row = (fdi.state.index + ahead) % window
    fdi.state.buf[row][RESIDUAL] = float("nan")
    for k in range(ahead):
        out = fdi.step(u[PREFIX + k], y[PREFIX + k])
        assert out["flags"] == 0 and fdi.last_status == 0, f"step {k}: early detection"
    out = fdi.step(u[PREFIX + ahead], y[PREFIX + ahead])
    assert out["flags"] >> RESIDUAL & 1 and fdi.last_status == WARN_STATE


def test_healthy_state_is_never_reported_corrupted(backends, healthy):
    """No false alarm: a whole healthy log keeps every step's status below _WARN_STATE."""
    u, y = healthy
    fdi = backends["c"]
    fdi.reset()
    statuses = set()
    for k in range(0, len(u)):
        fdi.step(u[k], y[k])
        statuses.add(fdi.last_status)
    assert WARN_STATE not in statuses


FUZZ_TRIALS = 300


def test_random_corruptions_are_all_detected(backends, healthy):
    """Random implausible values in random state fields of the C step (any buffer row, so
    detection may wait until the row leaves the window): every one is reported
    (_WARN_STATE) within WINDOW steps, with the corrupted residual's flag raised."""
    from reliability_log import reporter

    u, y = healthy
    fdi = backends["c"]
    window = fdi.design.evaluation.window
    nr = fdi.nr
    rng = np.random.default_rng(2024)
    bad_reals = [np.nan, np.inf, -np.inf, -1e300, 1e308, -1.0]
    delays = []
    for trial in range(FUZZ_TRIALS):
        fdi.reset()
        start = int(rng.integers(0, len(u) - 2 * window - PREFIX))
        for k in range(start, start + PREFIX):
            fdi.step(u[k], y[k])
        field = rng.choice(["sums", "buf", "count", "frozen", "flags", "late"])
        i = int(rng.integers(0, nr))
        st = fdi.state
        if field == "sums":
            value = bad_reals[int(rng.integers(0, len(bad_reals) - 1))]   # -1.0 is in range
            st.sums[i] = value
        elif field == "buf":
            st.buf[int(rng.integers(0, window))][i] = bad_reals[int(rng.integers(0, 6))]
        elif field in ("count", "frozen"):
            setattr(st, field, -int(rng.integers(1, 2**31)))
        else:
            setattr(st, field, getattr(st, field) | (1 << int(rng.integers(nr, 32))))
        for step in range(window + 1):
            k = start + PREFIX + step
            out = fdi.step(u[k], y[k])
            if fdi.last_status == WARN_STATE:
                break
        else:
            pytest.fail(f"trial {trial}: {field} corrupted, not detected in {window} steps")
        expected = (1 << i) if field in ("sums", "buf") else (1 << nr) - 1
        assert out["flags"] & expected == expected, (trial, field)
        delays.append(step)
    report = reporter("generated C core")
    report("test_random_corruptions_are_all_detected",
           "corrupted FDI state (NaN, inf, -1e300, 1e308 in running sums or the ring buffer; "
           "negative counters; flag bits beyond the residuals)", FUZZ_TRIALS, "pass",
           f"all detected (_WARN_STATE, flags raised) within {max(delays)} steps (median "
           f"{int(np.median(delays))}; a buffer entry when it leaves the window)")


@pytest.mark.parametrize("value", [-1, 99])
def test_platform_refuses_a_corrupted_decision(cylinder_design, healthy, tmp_path, value):
    """The bank's latched decision indexes its action table: out of range, _step refuses
    the state (_ERR_STATE, -5) instead of reading out of bounds (found by `fdigen prove
    --platform`)."""
    from fdigen.platform.codegen import PlatformCFdi

    u, y = healthy
    bank = PlatformCFdi(cylinder_design, cache_dir=tmp_path)
    legs_u, legs_y = np.repeat(u[:1], 6, axis=0), np.repeat(y[:1], 6, axis=0)
    bank.step(legs_u, legs_y, legs_y[:, 0])
    bank.state.decision[2] = value
    with pytest.raises(RuntimeError, match="status -5"):
        bank.step(legs_u, legs_y, legs_y[:, 0])

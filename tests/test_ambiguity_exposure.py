"""inspect warns when the default ambiguity policy may act on a fault more severely than
its class asks (``fdigen.design.ambiguity_exposure``)."""

from pathlib import Path

from fdigen.design.ambiguity_exposure import ambiguity_warnings, severe_under_ambiguity
from fdigen.design.cache import cached_design
from fdigen.model.model_file import builtin_model_path, load_model


def _tanks(tmp_path, extra=""):
    text = Path(builtin_model_path("three_tank")).read_text()
    path = tmp_path / "three_tank.toml"
    path.write_text(text.replace("[fdi]\n", "[fdi]\n" + extra, 1))
    return cached_design(load_model(path))


def test_the_level_sensors_are_exposed_to_the_plant_classes_safety_stop(tmp_path):
    design = _tanks(tmp_path)
    exposed = severe_under_ambiguity(design)
    ev = design.evaluation
    level = {n: m & ev.class_flags for n, m in zip(ev.fault_names, ev.fault_masks)}
    # computed independently: a sensor class (action none) shares a class-level flag with
    # a fault of a safety_stop class; the plant faults' classes are the most severe
    for f in design.model.faults:
        own = design.config.actions[f.fault_class]
        worse = {g.name for g in design.model.faults if g.fault_class != f.fault_class
                 and level[f.name] & level[g.name]
                 and design.config.actions[g.fault_class] == "safety_stop"}
        if own == "none" and worse:
            assert exposed[f.name][:2] == ("none", "safety_stop")
            assert set(exposed[f.name][2]) == worse
        else:
            assert f.name not in exposed
    assert set(exposed) == {"s1", "s2", "s3"}
    (msg,) = ambiguity_warnings(design)
    assert "s1 (none -> safety_stop" in msg and "ambiguity_time" in msg


def test_no_warning_once_the_engineer_chose(tmp_path):
    timed = _tanks(tmp_path, "ambiguity_time = 60.0\n")
    assert severe_under_ambiguity(timed) and not ambiguity_warnings(timed)
    assert severe_under_ambiguity(_tanks(tmp_path, 'ambiguity = "wait"\n')) == {}


def test_hold_windows_without_realignment_is_warned_about(tmp_path):
    """hold_windows holds the realignment's correction: with realign_noise_scale = 0 (the
    default) there is none, and a user's key silently did nothing."""
    from fdigen.design.ambiguity_exposure import hold_warnings

    held = _tanks(tmp_path, "hold_windows = 1\n")
    assert held.config.realign_noise_scale > 0 and hold_warnings(held) == ()
    text = Path(builtin_model_path("three_tank")).read_text()
    path = tmp_path / "open_loop.toml"
    path.write_text(text.replace("realign_noise_scale = 0.05", "realign_noise_scale = 0.0")
                    .replace("[fdi]\n", "[fdi]\nhold_windows = 1\n", 1))
    (msg,) = hold_warnings(cached_design(load_model(path)))
    assert "does nothing" in msg and "realign_noise_scale" in msg

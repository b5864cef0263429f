"""Attack round 9, on this session's features: the on/off controller, `simulate
--parameter`, duplicated log rows, `--min-tolerance`, the tolerance vertices."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.errors import LogError, ModelFileError
from fdigen.model.model_file import parse_model_text

DATA = Path(__file__).parent / "data" / "onoff"
TEXT = (DATA / "hot_water.toml").read_text()
MEAS = 'measurement = "(R_T/100 - 1)/3.85e-3"'


@pytest.mark.parametrize("old,new,field", [
    (MEAS, 'measurement = "log(R_T - 1000)"', "thermostat.measurement"),
    (MEAS, 'measurement = "R_T/(Ta - 20)"', "thermostat.measurement"),
    ('reference = "55"', 'reference = "log(t)"', "thermostat.reference"),
    ("levels = [0.0, 1.0]", "levels = [0.0, 50.0]", "thermostat.levels"),
])
def test_a_controller_that_cannot_act_at_the_operating_point_is_refused(old, new, field):
    """A thermostat reading NaN never switched; the tank cooled for hours and tune
    designed thresholds on the dead loop."""
    assert old in TEXT
    with pytest.raises(ModelFileError) as err:
        parse_model_text(TEXT.replace(old, new, 1), source="hw.toml")
    assert f"simulation.controllers.{field}" in str(err.value)


def test_two_controllers_on_one_input_say_so():
    text = TEXT.replace('input = "draw"', 'input = "el"', 1)
    with pytest.raises(ModelFileError, match="input driven by two controllers"):
        parse_model_text(text, source="hw.toml")


def test_a_demand_that_overflows_writes_no_log(tmp_path):
    path = tmp_path / "hw.toml"
    path.write_text(TEXT.replace('reference = "55"', 'reference = "55 + exp(1000*t)"', 1))
    res = CliRunner().invoke(main, ["simulate", "--model", str(path), "-o",
                                    str(tmp_path / "x.csv")])
    assert res.exit_code == 2 and "thermostat_ref" in res.output and "not finite" in res.output
    assert not (tmp_path / "x.csv").exists()


@pytest.mark.parametrize("args,says", [
    (["Pel=1_0_0_0"], "finite number"), (["Pel=３０００"], "finite number"),
    (["Pel=10000.0000001"], "10000.0000001 is outside its bounds"),
    (["Pel=200", "Pel=900"], "Pel given more than once"),
])
def test_a_plant_parameter_is_a_plain_number_given_once(tmp_path, args, says):
    cmd = ["simulate", "--model", str(DATA / "hot_water.toml"), "-o", str(tmp_path / "x.csv")]
    for a in args:
        cmd += ["--parameter", a]
    res = CliRunner().invoke(main, cmd)
    assert res.exit_code == 2 and says in res.output, res.output


def test_a_log_of_one_row_written_many_times_says_so(tmp_path):
    from fdigen.model.model_file import load_model
    from fdigen.sim.log import read_log

    log = tmp_path / "same.csv"
    log.write_text("t,el,flow,R_T\n" + "0,0,0,121.17\n" * 5)
    with pytest.raises(LogError, match="every row repeats the first"):
        read_log(log, load_model(DATA / "hot_water.toml"), missing="keep")


def test_the_vertex_runs_stay_bounded():
    import dataclasses

    from fdigen.model.model_file import load_model
    from fdigen.tune.cases import tolerance_vertices

    m = load_model(DATA / "hot_water.toml")
    many = dataclasses.replace(m, parameters=tuple(dataclasses.replace(q, uncertain=True)
                                                   for q in m.parameters))
    assert len([q for q in many.parameters if q.uncertain]) == 6
    assert len(tolerance_vertices(many, 0.1)) == 2 * 6 + 2
    from fdigen.tune import cases

    old = cases.MAX_AXIS_VERTEX_PARAMETERS
    try:
        cases.MAX_AXIS_VERTEX_PARAMETERS = 5
        assert len(tolerance_vertices(many, 0.1)) == 2
    finally:
        cases.MAX_AXIS_VERTEX_PARAMETERS = old


def test_min_tolerance_stops_at_the_widest_spread(tmp_path):
    res = CliRunner().invoke(main, ["commission", str(tmp_path / "x.csv"), "--model",
                                    str(DATA / "hot_water.toml"), "--min-tolerance", "0.95"])
    assert res.exit_code == 2 and "--min-tolerance" in res.output


def test_an_error_after_rows_are_put_back_names_the_files_row(tmp_path):
    """A row going back in time after a dropped row was reported at row 38 of a 21-line
    file: the put-back rows were counted as rows of the file."""
    from fdigen.model.model_file import load_model
    from fdigen.sim.log import read_log

    rows = [f"{5 * k},0,0,121.17{k % 10}" for k in range(12) if k != 4]     # t = 20 dropped
    rows.insert(10, "0,0,0,121.1")                                         # file row 12
    log = tmp_path / "back.csv"
    log.write_text("t,el,flow,R_T\n" + "\n".join(rows) + "\n")
    with pytest.raises(LogError, match=r"row 12, column 't': time does not increase"):
        read_log(log, load_model(DATA / "hot_water.toml"), missing="keep")

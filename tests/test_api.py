"""The Python API: a model built from sympy expressions goes through the same pipeline."""

import sympy as sp

from fdigen.design.fdi_design import fdi_design
from fdigen.model.model import Fault, Model, Output, Parameter, Variable


def dc_motor_from_python(motor_file_model):
    """The dc_motor example written with the Python API instead of TOML."""
    Ra, La, Ke, Kt, J, b, Vnom = sp.symbols("Ra La Ke Kt J b Vnom", real=True)
    i, w, V = sp.symbols("i w V", real=True)
    drive, load, winding, tach, cs = sp.symbols("drive load winding tach current_sensor",
                                                 real=True)
    params = tuple(Parameter(q.name, q.value, q.unit, q.description, q.bounds, q.uncertain)
                   for q in motor_file_model.parameters)
    return Model(
        name="dc_motor",
        states=(Variable("i", "A", range=(-5.0, 5.0)), Variable("w", "rad/s", range=(-300.0, 300.0))),
        inputs=(Variable("V", "V", range=(-12.0, 12.0), column="u"),),
        outputs=(Output("w_tach", w, "rad/s", noise_std=0.5, column="w"),
                 Output("i_meas", i, "A", noise_std=0.01, column="i")),
        parameters=params,
        definitions=(),
        dynamics=((V - Ra * i - Ke * w) / La, (Kt * i - b * w) / J),
        faults=(Fault("drive", "actuator", "multiplicative", "V", drive * V, "drive"),
                Fault("load", "plant", "additive", "w", -load / J, "mechanical"),
                Fault("winding", "plant", "multiplicative", "i", -winding * Ra * i / La,
                      "electrical"),
                Fault("tach", "sensor", "additive", "w_tach", tach, "tachometer"),
                Fault("current_sensor", "sensor", "additive", "i_meas", cs, "current_sensor")),
        operating_point=dict(motor_file_model.operating_point),
        fdi=motor_file_model.fdi,
    )


def test_python_api_model_equals_model_file(motor, motor_design):
    api = dc_motor_from_python(motor)
    assert sp.simplify(api.f() - motor.f()) == sp.zeros(2, 1)
    design = fdi_design(api)
    assert design.residual_names == motor_design.residual_names
    assert design.signature_table == motor_design.signature_table
    for a, b in zip(design.kalman, motor_design.kalman):
        assert a.residual == b.residual
        assert abs(a.gain.M - b.gain.M).max() <= 1e-12 * abs(b.gain.M).max()


def test_api_validation_names_the_problem():
    import pytest
    from fdigen.errors import ModelFileError
    x = sp.Symbol("x", real=True)
    with pytest.raises(ModelFileError, match="undefined symbol") as info:
        Model(name="m", states=(Variable("x"),), inputs=(), outputs=(Output("y", x),),
              parameters=(), definitions=(), dynamics=(sp.Symbol("k", real=True) * x,),
              operating_point={"x": 0.0})
    assert info.value.symbol == "k" and info.value.field == "dynamics.x"

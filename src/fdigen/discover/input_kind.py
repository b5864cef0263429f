"""An actuator effect found on an input that may be a measured disturbance.

An input is a command unless the model file says ``kind = "measured"`` (an inlet
temperature, a demand, a fan flow read from the log): the effect library then tries no
dead band, saturation or gain loss on it. A user who does not know the key gets it
named where it matters: a user's air tunnel, whose inlet temperature and fan flow were
plain inputs, was offered ``actuator_deadband_Tin`` and ``gain_loss_Tin`` ("heater
ageing" of an air temperature). When the model's ``[simulation]`` declares the inputs its
controllers command, an actuator effect chosen or tied on another input gets a warning
naming the key.
"""

from __future__ import annotations

#: Effect families that act on a command (an actuator's own nonlinearity or wear).
ACTUATOR_FAMILIES = ("deadband", "gain", "actuator_saturation")


def uncommanded_inputs(model) -> set[str]:
    """The inputs no controller of ``[simulation]`` commands, when it declares some
    controllers (empty otherwise: nothing says which inputs are commands)."""
    from fdigen.errors import FdigenError
    from fdigen.model.simulation_spec import simulation_spec

    try:
        commanded = {c.input for c in simulation_spec(model).controllers}
    except FdigenError:
        return set()
    if not commanded:
        return set()
    return {u.name for u in model.inputs if u.is_actuator and u.name not in commanded}


def acted_input(model, effect) -> str | None:
    """The input an actuator effect acts on: the suffix of its name (``gain_loss_Tin``,
    ``actuator_saturation_P``, ``actuator_deadband_q1``), or the model's one actuator
    input for an unsuffixed dead band; its gains may read other inputs (a gain loss of
    the inlet temperature is proportional to the flow too)."""
    actuators = [u.name for u in model.inputs if u.is_actuator]
    for u in sorted(actuators, key=len, reverse=True):
        if effect.name.endswith("_" + u):
            return u
    if effect.family == "deadband" and len(actuators) == 1:
        return actuators[0]
    return None


def measured_input_warnings(model, effects) -> list[str]:
    """One warning per actuator effect of ``effects`` that reads an input no declared
    controller commands."""
    free = uncommanded_inputs(model)
    out = []
    for e in effects:
        if e.family not in ACTUATOR_FAMILIES or not free:
            continue
        u = acted_input(model, e)
        if u in free:
            out.append(f"{e.name} acts on input {u}, which no controller of [simulation] "
                       f"commands: if {u} is a measured disturbance (an inlet temperature, "
                       f"a demand), declare it `kind = \"measured\"` in [inputs] and "
                       "discover will not try a dead band, saturation or gain loss on it")
    return out

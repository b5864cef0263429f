"""The plant model, written once: states, inputs, outputs, parameters, definitions, faults.

A :class:`Model` is an immutable description. Derivations (``fdigen.derive``) read it and
return new objects; nothing here computes anything beyond substitution.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

import sympy as sp

from fdigen.errors import ModelFileError

@dataclass(frozen=True)
class Parameter:
    """A named constant of the model.

    Attributes
    ----------
    name, unit, description : str
    value : float
        Default (datasheet) value.
    bounds : tuple of float or None
        Physical range; values outside it are rejected by the generated ``init``.
    uncertain : bool
        Whether calibration may estimate it.
    tolerance : float or None
        Its own relative spread ``+-tol`` for the campaigns of ``fdigen tune`` (an uncertain
        parameter only); ``fdigen commission`` writes the calibrated ones. ``None``: the
        campaign's ``--tolerance``.
    """

    name: str
    value: float
    unit: str = ""
    description: str = ""
    bounds: tuple[float, float] | None = None
    uncertain: bool = False
    tolerance: float | None = None

    @property
    def symbol(self) -> sp.Symbol:
        return sp.Symbol(self.name, real=True)


@dataclass(frozen=True)
class Variable:
    """A state or an input.

    ``range`` is the span it covers in normal operation (verification points are drawn
    from it); ``limits`` are hard physical bounds as expressions of the parameters (end
    stops, supply and atmospheric pressure) that the parallel model respects. An input's
    ``kind`` is ``"actuator"`` (a command: pump, heater, valve; the default) or
    ``"measured"`` (a measured disturbance: an inlet temperature, a demand), which has no
    dead band, saturation or gain loss of its own (``fdigen discover`` does not try them).
    """

    name: str
    unit: str = ""
    description: str = ""
    range: tuple[float, float] | None = None
    column: str = ""
    limits: tuple | None = None
    kind: str = ""

    @property
    def is_actuator(self) -> bool:
        """Whether this input is a command (not a measured disturbance)."""
        return self.kind != "measured"

    @property
    def symbol(self) -> sp.Symbol:
        return sp.Symbol(self.name, real=True)


@dataclass(frozen=True)
class Output:
    """A measured output ``y = expr(states, inputs, parameters)`` with its sensor noise."""

    name: str
    expr: sp.Expr
    unit: str = ""
    description: str = ""
    noise_std: float = 0.0
    column: str = ""

    @property
    def symbol(self) -> sp.Symbol:
        return sp.Symbol(self.name, real=True)


@dataclass(frozen=True)
class Fault:
    """A fault input: where it acts and how it enters.

    The fault magnitude is the symbol named like the fault. ``term`` is added to the
    target: to the input (actuator faults), to the target state's derivative (plant
    faults) or to the target output (sensor faults). A multiplicative fault's term is
    proportional to the signal it scales (e.g. ``valve*v``: the valve delivers
    ``v*(1 + valve)``; ``valve = -1`` is a loss of the control signal).

    A fault may enter several equations at once (a clogged pipe changes the balances of
    both tanks it joins): ``terms`` holds ``(target, term)`` pairs, each target a state
    (the term is added to its derivative), an output (added to the measurement) or an
    input (added to the input), and ``target``/``term`` are the first pair. The fault's
    symbol may also appear in the model's definitions; such a fault may have no term at
    all. Either way it is one fault: one column of ``E = df/dphi`` and ``F = dh/dphi``.
    """

    name: str
    location: str
    mode: str
    target: str
    term: sp.Expr
    fault_class: str
    description: str = ""
    test_size: float = 0.0
    terms: tuple = ()
    #: ramp rate of the campaign's drift case [units/s] (additive sensor faults; None:
    #: derived from the plant's time scale, :func:`fdigen.tune.cases.ramp_rate`)
    test_rate: float | None = None

    def __post_init__(self):
        if len(self.terms) <= 1 and self.target:  # single form (also after replace())
            object.__setattr__(self, "terms", ((self.target, self.term),))
        object.__setattr__(self, "terms", tuple((str(t), e) for t, e in self.terms))

    @property
    def symbol(self) -> sp.Symbol:
        return sp.Symbol(self.name, real=True)

    @property
    def multi(self) -> bool:
        """Whether the fault is more than its single ``target``/``term`` pair."""
        return len(self.terms) != 1


@dataclass(frozen=True)
class Model:
    """A plant model: ``dx/dt = f(x, u, p) + faults``, ``y = h(x, u, p) + faults``.

    Attributes
    ----------
    name : str
        A C identifier, used to prefix every generated symbol.
    states, inputs : tuple of Variable
    outputs : tuple of Output
    parameters : tuple of Parameter
    definitions : tuple of (str, sympy.Expr)
        Intermediate quantities in dependency order (``Vp = V0 + A*x``); they are kept
        as symbols in ``dynamics`` and ``outputs`` and substituted by :meth:`expand`.
    dynamics : tuple of sympy.Expr
        One right-hand side per state.
    faults : tuple of Fault
    operating_point : mapping of str to float
        Values of states and inputs where the model is linearised.
    fdi : mapping
        The FDI design configuration (sample time, noise weights, thresholds...).
    simulation : mapping
        Closed-loop test settings (controller expression, reference), used by the
        numeric checks.
    source : str
        The file the model came from, or ``"<api>"``.
    text_hash : str
        Hash of the canonical model description (filled by the loader).
    """

    name: str
    states: tuple[Variable, ...]
    inputs: tuple[Variable, ...]
    outputs: tuple[Output, ...]
    parameters: tuple[Parameter, ...]
    definitions: tuple[tuple[str, sp.Expr], ...]
    dynamics: tuple[sp.Expr, ...]
    faults: tuple[Fault, ...] = ()
    operating_point: Mapping[str, float] = field(default_factory=dict)
    fdi: Mapping = field(default_factory=dict)
    simulation: Mapping = field(default_factory=dict)
    description: str = ""
    source: str = "<api>"

    def __post_init__(self):
        object.__setattr__(self, "operating_point", dict(self.operating_point))
        from fdigen.model.validation import validate_model

        validate_model(self)

    # -- symbols -------------------------------------------------------------------------
    @property
    def x(self) -> sp.Matrix:
        """State vector as a column of symbols."""
        return sp.Matrix([s.symbol for s in self.states])

    @property
    def u(self) -> sp.Matrix:
        """Input vector as a column of symbols."""
        return sp.Matrix([s.symbol for s in self.inputs])

    @property
    def p(self) -> sp.Matrix:
        """Parameter vector as a column of symbols."""
        return sp.Matrix([q.symbol for q in self.parameters])

    @property
    def f_sym(self) -> sp.Matrix:
        """Fault vector as a column of symbols."""
        return sp.Matrix([q.symbol for q in self.faults])

    @property
    def parameter_values(self) -> dict[sp.Symbol, float]:
        return {q.symbol: float(q.value) for q in self.parameters}

    def state_index(self, name: str) -> int:
        return [s.name for s in self.states].index(name)

    def output_index(self, name: str) -> int:
        return [o.name for o in self.outputs].index(name)

    def output(self, name: str) -> Output:
        return self.outputs[self.output_index(name)]

    def fault(self, name: str) -> Fault:
        return {f.name: f for f in self.faults}[name]

    # -- expressions ---------------------------------------------------------------------
    def expand(self, expr, with_faults: bool = False):
        """Substitute the definitions into ``expr``: each definition's symbol by its value
        with the definitions it reads substituted (one pass over ``expr``).

        Fault symbols written in definitions are set to 0 unless ``with_faults``.
        """
        resolved = self._resolved_definitions(with_faults)
        return expr.xreplace(resolved) if resolved else expr

    def _resolved_definitions(self, with_faults: bool) -> dict:
        """``{symbol: value}`` of every definition, the earlier ones it reads substituted;
        kept on the instance (a derivation expands the same model hundreds of times: a
        user's separator spent 6.5 s substituting its definitions one by one)."""
        memo = self.derived("definitions")
        if with_faults not in memo:
            zero = None if with_faults else {f.symbol: 0 for f in self.faults}
            out: dict = {}
            for name, value in self.definitions:
                if zero and value.free_symbols & zero.keys():
                    value = value.xreplace(zero)
                out[sp.Symbol(name, real=True)] = value.xreplace(out) if out else value
            memo[with_faults] = out
        return memo[with_faults]

    def derived(self, key: str) -> dict:
        """A per-instance cache of what is derived from this model under ``key`` (never
        pickled, never compared): the model is frozen, so what a pure function derives
        from it holds as long as the instance."""
        memo = self.__dict__.get("_derived")
        if memo is None:
            memo = {}
            object.__setattr__(self, "_derived", memo)
        return memo.setdefault(key, {})

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k != "_derived"}

    def __setstate__(self, state):
        for k, v in state.items():
            object.__setattr__(self, k, v)

    def outputs_reached(self, fault: Fault) -> tuple[str, ...]:
        """The outputs whose measured value a fault changes directly, in output order:
        its terms' output targets and the outputs whose expressions read it through a
        definition (a sensor's gain loss written in its map); ``h_j(x, u, phi) -
        h_j(x, u, 0) != 0`` at fixed states and inputs."""
        targets = {t for t, _ in fault.terms if self.target_kind(t) == "output"}
        written = self.expand(sp.Matrix([o.expr for o in self.outputs]), True)
        return tuple(o.name for j, o in enumerate(self.outputs)
                     if o.name in targets or fault.symbol in written[j].free_symbols)

    def target_kind(self, name: str) -> str | None:
        """``"state"``, ``"output"`` or ``"input"`` for a fault target's name."""
        for kind, items in (("state", self.states), ("output", self.outputs),
                            ("input", self.inputs)):
            if any(s.name == name for s in items):
                return kind
        return None

    def f(self, with_faults: bool = False) -> sp.Matrix:
        """The state derivative ``dx/dt = f(x, u, p)`` (eqs 1-3 for the cylinder).

        With ``with_faults``, actuator faults replace each input ``u_i`` by
        ``u_i + term`` and plant faults add their term to the target state's derivative.
        The definitions are substituted first, so an actuator fault acts wherever its
        input acts, definitions included (``q = Kv*u*sqrt(Ps - P)`` sees ``u + term``).
        """
        memo = self.derived("f")
        if with_faults not in memo:
            rhs = self.expand(sp.Matrix(self.dynamics), with_faults)
            if with_faults:
                rhs = self._with_faults(rhs, plant=True)
            memo[with_faults] = rhs
        return memo[with_faults].copy()

    def h(self, with_faults: bool = False) -> sp.Matrix:
        """The measured outputs ``y = h(x, u, p)``, with sensor fault terms if asked.

        Definitions are substituted before the faults (see :meth:`f`).
        """
        memo = self.derived("h")
        if with_faults not in memo:
            out = self.expand(sp.Matrix([o.expr for o in self.outputs]), with_faults)
            if with_faults:
                out = sp.Matrix(self._with_faults(out, plant=False))
                for fault in self.faults:
                    for target, term in fault.terms:
                        if self.target_kind(target) == "output":
                            k = self.output_index(target)
                            out[k] = out[k] + self.expand(term, True)
            memo[with_faults] = out
        return memo[with_faults].copy()

    def _with_faults(self, rhs, plant):
        """Add the fault terms to expanded equations: ``u -> u + term`` everywhere for
        inputs (one simultaneous substitution), ``+ term`` for states; terms expanded."""
        actuator = {}
        for fault in self.faults:
            for target, term in fault.terms:
                if self.target_kind(target) == "input":
                    s = sp.Symbol(target, real=True)
                    actuator[s] = actuator.get(s, s) + self.expand(term, True)
        if actuator:
            rhs = rhs.xreplace(actuator)
        if plant:
            rhs = sp.Matrix(rhs)
            for fault in self.faults:
                for target, term in fault.terms:
                    if self.target_kind(target) == "state":
                        k = self.state_index(target)
                        rhs[k] = rhs[k] + self.expand(term, True)
        return rhs

    def with_parameters(self, **values) -> "Model":
        """A new model whose parameter defaults are replaced by ``values``."""
        unknown = set(values) - {q.name for q in self.parameters}
        if unknown:
            raise ModelFileError("unknown parameter", source=self.source,
                                 field="parameters", symbol=sorted(unknown)[0])
        params = tuple(replace(q, value=float(values.get(q.name, q.value)))
                       for q in self.parameters)
        return replace(self, parameters=params)

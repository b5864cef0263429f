"""The CasADi backend: the FDI design as CasADi functions, interpreted or compiled.

* :mod:`.convert`: :func:`sympy_to_casadi`, sympy expression trees to ``casadi.SX``;
* :mod:`.functions`: the model functions, the core step and the extended state's layout;
* :mod:`.step_kernel`: the step with evaluation, without the window buffer;
* :mod:`.log_functions`: the full step with evaluation on an extended state, the
  whole-log ``mapaccum``, the blocks and chunks the runner calls;
* :mod:`.compiled`: generated C (:func:`casadi_sources`) and the cached shared library
  (:func:`compile_library`);
* :mod:`.runner`: :class:`CasadiFdi`, with the interface of
  :class:`fdigen.backends.reference.ReferenceFdi`.

Names are imported lazily, so that ``import fdigen.backends.casadi_backend.convert`` stays
light.
"""

from importlib import import_module

_EXPORTS = {
    "sympy_to_casadi": "convert",
    "model_functions": "functions",
    "core_function": "functions",
    "step_function": "log_functions",
    "whole_log_function": "log_functions",
    "state_layout": "functions",
    "casadi_sources": "compiled",
    "compile_library": "compiled",
    "compiled_functions": "compiled",
    "CasadiFdi": "runner",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

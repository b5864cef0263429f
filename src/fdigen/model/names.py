"""The rules every name from a model file must follow before it reaches generated text.

A name (the model's, a state's, an input's, an output's, a parameter's, a definition's, a
fault's, a fault class's, a residual's, a voter channel's or a log column's) is pasted
into C, CasADi and numpy source as an identifier. It is accepted only if it is

* ASCII ``[A-Za-z][A-Za-z0-9_]*`` and at most :data:`MAX_NAME_LENGTH` characters (a
  non-ASCII name is refused with its NFKC form, so ``𝐊t`` cannot shadow ``Kt``);
* free of a double underscore (reserved by C++ and by CasADi's generated code) and of a
  trailing underscore (the C printer escapes a reserved word ``w`` as ``w_``);
* none of the words the backends' printers reserve (C99/C++ keywords, ``<math.h>``,
  ``<stdint.h>`` and ``<stddef.h>`` names, the macros of ``<stdio.h>``, ``<stdlib.h>``,
  ``<limits.h>`` and the FMI headers, ``linux``/``unix`` that GNU mode predefines, the
  names the numpy printer of the reference backend prints, Python keywords), nor a
  function an equation may call (``sin``);
* not shaped like a name the generated code gives its own intermediates
  (:data:`GENERATED_PATTERNS`: ``V_raw``, ``par_w``, ``yhat_R4``...); a name that still
  collides with one is caught when the step program is assembled
  (:func:`fdigen.design.program.Program.check_unique_names`).

Class names must also not be ``none`` (the "no fault" decision, class index 0).
"""

from __future__ import annotations

import functools
import keyword
import re
import unicodedata

from fdigen.errors import ModelFileError

#: Longest accepted name: generated identifiers join two names and an affix, and C99
#: guarantees 63 significant characters for internal identifiers.
MAX_NAME_LENGTH = 32

_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")

#: C++ keywords (the generated header is usable from C++: parameter names become fields).
_CPP_KEYWORDS = """alignas alignof and and_eq asm bitand bitor bool catch char16_t char32_t
char8_t class compl concept consteval constexpr constinit const_cast co_await co_return
co_yield decltype delete dynamic_cast explicit export false friend mutable namespace new
noexcept not not_eq nullptr operator or or_eq private protected public reinterpret_cast
requires static_assert static_cast template this thread_local throw true try typeid
typename using virtual wchar_t xor xor_eq""".split()

#: Further names of the C headers the generated code includes (macros and typedefs a
#: local must not take) beyond those the C printer already reserves.
_C_HEADER_NAMES = """float_t double_t FP_NAN FP_INFINITE FP_ZERO FP_SUBNORMAL FP_NORMAL
FP_FAST_FMA FP_FAST_FMAF FP_FAST_FMAL FP_ILOGB0 FP_ILOGBNAN MATH_ERRNO MATH_ERREXCEPT
max_align_t memcpy memset memmove memcmp strlen INT8_MIN INT16_MIN INT32_MIN INT64_MIN
INT8_MAX INT16_MAX INT32_MAX INT64_MAX UINT8_MAX UINT16_MAX UINT32_MAX UINT64_MAX
INTPTR_MIN INTPTR_MAX UINTPTR_MAX INTMAX_MIN INTMAX_MAX UINTMAX_MAX PTRDIFF_MIN PTRDIFF_MAX
SIZE_MAX SIG_ATOMIC_MIN SIG_ATOMIC_MAX WCHAR_MIN WCHAR_MAX WINT_MIN WINT_MAX INT8_C INT16_C
INT32_C INT64_C UINT8_C UINT16_C UINT32_C UINT64_C INTMAX_C UINTMAX_C main
EOF BUFSIZ FILENAME_MAX FOPEN_MAX L_tmpnam SEEK_CUR SEEK_END SEEK_SET TMP_MAX stderr stdin
stdout FILE fpos_t EXIT_SUCCESS EXIT_FAILURE RAND_MAX MB_CUR_MAX NULL div_t ldiv_t lldiv_t
errno EDOM ERANGE EILSEQ assert NDEBUG HUGE_VAL HUGE_VALF HUGE_VALL INFINITY NAN
CHAR_BIT CHAR_MIN CHAR_MAX SCHAR_MIN SCHAR_MAX UCHAR_MAX SHRT_MIN SHRT_MAX USHRT_MAX
INT_MIN INT_MAX UINT_MAX LONG_MIN LONG_MAX ULONG_MAX LLONG_MIN LLONG_MAX ULLONG_MAX
MB_LEN_MAX DECIMAL_DIG""".split()

#: Macros C compilers predefine on some targets outside strict ISO mode (gcc defines
#: ``sun`` on Solaris, ``linux`` and ``unix`` on Linux in GNU mode): the generated code is
#: compiled wherever the user's controller is.
_C_TARGET_MACROS = "linux unix i386 sun vax mips sparc".split()

#: Macro families of the C headers a controller embedding the generated code includes
#: (``<math.h>``'s ``M_PI``..., ``<float.h>``) and of the FMI headers the FMU wrapper
#: includes (``fmi2True``...): a macro expands wherever the name stands, so a parameter
#: ``M_PI`` or ``EXIT_SUCCESS`` breaks the header in the user's translation unit (attack
#: round 2). GNU mode predefines ``linux`` and ``unix`` (listed above).
_C_MACRO_PATTERNS = (r"M_[A-Za-z0-9_]+", r"(?:DBL|FLT|LDBL)_[A-Z0-9_]+", r"fmi[0-9].*",
                     r"FMI[0-9].*")
_C_MACRO = re.compile("(?:" + "|".join(_C_MACRO_PATTERNS) + r")\Z")

#: Names of the step program's own variables, and the affixes of the names it derives
#: from the model's names (see ``design/step_program.py``, ``parallel_model.py``,
#: ``scheduled_prediction.py``, ``derived_parameters.py``): a model name of one of these
#: shapes could be redefined by the generated code.
GENERATED_PATTERNS = (
    r"freeze", r"accommodate", r"realign_gate", r"check", r"mode", r"params",
    r".*_raw",                                  # raw input/output sample
    r"par_.*", r"parc_.*", r"par[0-9]+_.*",     # parity parallel model and its RK4 stages
    r"nf_.*", r"r_nf_.*",                       # measurement validity residuals
    r"yhat_.*", r"eu_.*",                       # Kalman prediction and innovation
    r"sched_.*",                                # scheduled-prediction signals
    r"vd[0-9]+", r"dp[0-9]+",                   # voter distances, derived parameters
    r".*_(post|next|Ar|Br|Ad|Bd)[0-9]+",        # Kalman update, next state, scheduled A, B
)
_GENERATED = re.compile("(?:" + "|".join(GENERATED_PATTERNS) + r")\Z")

#: Name kinds whose names are symbols of the equations and the generated programs.
SYMBOL_KINDS = ("states", "inputs", "outputs", "parameters", "definitions", "faults")


def model_names(model) -> dict:
    """Every name a model gives: name -> what it is (``parameter``, ``definition``,
    ``input``, ``output``, ``state``, ``fault``). A residual may take none of them."""
    return {**{q.name: "parameter" for q in model.parameters},
            **{n: "definition" for n, _ in model.definitions},
            **{v.name: "input" for v in model.inputs},
            **{o.name: "output" for o in model.outputs},
            **{x.name: "state" for x in model.states},
            **{f.name: "fault" for f in model.faults}}


def reserved_by(name: str) -> str:
    """What reserves ``name`` (one of :func:`reserved_words`), in a few words."""
    import builtins

    from fdigen.model.expression import ALLOWED_FUNCTIONS

    if name in _C_TARGET_MACROS:
        return ("a macro C compilers predefine on some targets outside strict ISO mode: "
                "gcc's 'sun' on Solaris, 'linux' and 'unix' on Linux")
    if name in keyword.kwlist:
        return "a Python keyword"
    if name in ALLOWED_FUNCTIONS:
        return "a function of the model language"
    if name in _CPP_KEYWORDS:
        return "a C++ keyword (the generated header is usable from C++)"
    if name in _C_HEADER_NAMES:
        return "a name of the C standard headers the generated code includes"
    if name in dir(builtins):
        return "a Python builtin the generated Python reads"
    return ("a C keyword or standard-library name, or a name the reference backend's "
            "numpy code uses")


@functools.lru_cache(maxsize=1)
def reserved_words() -> frozenset:
    """Every word a name must not be, derived from the printers of the backends.

    The C printer's reserved words (C99 keywords, ``<math.h>``/``<stdint.h>`` names),
    C++ keywords, Python keywords, the functions an equation may call, and every
    identifier the reference backend's numpy printer writes for the constructs a step
    program uses (``select``, ``maximum``, ``arctan2``...).
    """
    import sympy as sp

    from fdigen.backends.c.printer import FdiCPrinter
    from fdigen.backends.reference import _ExactPowPrinter
    from fdigen.model.expression import ALLOWED_FUNCTIONS
    from sympy.printing.numpy import _numpy_known_constants, _numpy_known_functions

    words = set(FdiCPrinter("double").reserved_words) | set(_CPP_KEYWORDS)
    words |= set(_C_HEADER_NAMES) | set(_C_TARGET_MACROS) | set(keyword.kwlist)
    words |= set(ALLOWED_FUNCTIONS)
    words |= {v.split(".")[-1] for v in _numpy_known_functions.values()}
    words |= {v.split(".")[-1] for v in _numpy_known_constants.values()}
    a, b = sp.symbols("qa qb", real=True)
    probe = [sp.Piecewise((a, (a > 0) & (b < 1)), (b, (a >= b) | ~(a <= b)), (0, True)),
             sp.Max(a, b), sp.Min(a, b, 1), sp.Abs(a), sp.sign(a), sp.Float(1.5) * sp.pi,
             1 / a, a ** 2, a ** sp.Rational(1, 3)]
    probe += [f(*([a] * lo)) for (lo, _), f in ALLOWED_FUNCTIONS.values()]
    printer = _ExactPowPrinter({"fully_qualified_modules": False, "inline": True,
                                "allow_unknown_functions": True, "user_functions": {}})
    text = " ".join(printer.doprint(e) for e in probe)
    words |= set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", text)) - {"qa", "qb"}
    words |= {"numpy", "builtins", "range", "float", "int", "array", "abs", "reduce"}
    return frozenset(words)


def check_name(name, *, source=None, field=None, kind="name", model_name=None) -> str:
    """Check one name from a model file; return it, or raise naming file, field, name.

    Parameters
    ----------
    name : object
        The name as read (a TOML key or string value).
    source : str, optional
        The model file.
    field : str, optional
        The dotted field the name was found in (``parameters``, ``fdi.parity``...).
    kind : str
        What the name is, for the message.
    model_name : str, optional
        The model's name: the name must not start with the generated C prefix
        (:func:`check_not_prefixed`).

    Raises
    ------
    ModelFileError
    """
    def refuse(message):
        raise ModelFileError(f"{kind} {message}", source=source, field=field,
                             symbol=repr(name) if not _printable(name) else name)

    if not isinstance(name, str):
        refuse(f"must be text, got {type(name).__name__}")
    if not name.isascii():
        folded = unicodedata.normalize("NFKC", name)
        hint = f" (it reads as '{folded}' after Unicode normalisation)" \
            if folded != name and folded.isascii() else ""
        refuse("must be ASCII letters, digits and '_'" + hint)
    if not _NAME.match(name):
        refuse("must be an identifier: a letter, then letters, digits or '_'")
    if len(name) > MAX_NAME_LENGTH:
        refuse(f"is longer than {MAX_NAME_LENGTH} characters")
    if "__" in name:
        refuse("must not contain '__' (reserved by C++ and CasADi's generated code)")
    if name.endswith("_"):
        refuse("must not end with '_' (the generated C escapes reserved words that way)")
    if name in reserved_words():
        refuse(f"is a word the generated C, C++ or Python code reserves ({reserved_by(name)});"
               f" rename it ('{name}_1', 'my_{name}')")
    if _C_MACRO.match(name):
        refuse("has the form of a macro of the C or FMI headers the generated code is "
               f"compiled with (patterns: {', '.join(_C_MACRO_PATTERNS)})")
    if _GENERATED.match(name):
        refuse("has the form of a name the generated code gives its own variables "
               f"(patterns: {', '.join(GENERATED_PATTERNS)})")
    if model_name is not None:
        check_not_prefixed([name], model_name, source=source, field=field)
    return name


def check_model_name(name, *, source=None) -> str:
    """The model's name: a name as :func:`check_name`, and not ``casadi...`` (the
    prefix of CasADi's generated helpers), since it prefixes every generated symbol."""
    check_name(name, source=source, field="model.name", kind="model name")
    if name.lower().startswith("casadi"):
        raise ModelFileError("model name must not start with 'casadi' (CasADi's generated "
                             "helpers use that prefix)", source=source, field="model.name",
                             symbol=name)
    return name


def check_class_name(name, *, source=None, field="faults", model_name=None) -> str:
    """A fault class name: a name, and not ``none`` (the "no fault" decision)."""
    check_name(name, source=source, field=field, kind="fault class", model_name=model_name)
    if name.lower() == "none":
        raise ModelFileError("fault class must not be 'none' (the no-fault decision)",
                             source=source, field=field, symbol=name)
    return name


def check_not_prefixed(names, model_name, *, source=None, field=None):
    """Refuse names starting with the generated C prefix ``<model>_fdi`` / ``<MODEL>_FDI``
    (the generated functions, types and macros) or equal to ``<model>_real``."""
    prefix = f"{model_name}_fdi".lower()
    for name in names:
        if name.lower().startswith(prefix) or name == f"{model_name}_real":
            raise ModelFileError(f"name clashes with the generated C prefix '{prefix}'",
                                 source=source, field=field, symbol=name)


def check_prefixed_by_residual(symbols, residuals, *, source=None):
    """Refuse a model symbol ``<residual>_...``, ``<residual>c_...`` or
    ``<residual><digits>_...``: the generated code names the filter states, updates and
    parallel-model stages of residual ``<residual>`` that way.

    Parameters
    ----------
    symbols : iterable of (str, str)
        ``(field, name)`` of every model symbol.
    residuals : iterable of str
    """
    residuals = [r for r in residuals]
    for fld, name in symbols:
        for rname in residuals:
            if re.match(re.escape(rname) + r"(c?|[0-9]+)_", name):
                raise ModelFileError(
                    f"name has the form of a generated variable of residual '{rname}'",
                    source=source, field=fld, symbol=name)


def _printable(name) -> bool:
    return isinstance(name, str) and name.isprintable() and len(name) <= 80

"""The size of a model once its definitions are substituted: what the derivation handles.

The limits of :mod:`fdigen.model.expression` bound each equation *as written* (4000
characters, 2000 nodes, exponents up to 64). A model can stay far under them and still
ask the symbolic derivation (substitution of the definitions, ``expand``, Jacobians,
``lambdify``, the CasADi conversion) for an astronomically large expression: twelve
chained definitions each using the previous one twice are 2^12 copies of the first; one
``(a + b + c + d + e)**64`` expands to 814,385 monomials; ``((a + b)**64 + c)**64`` to
more than 10^100. :func:`check_model_size` measures each state derivative, output and
fault term *after* the substitution, without building the large expression:

* :func:`tree_size`: the nodes of the expression tree, shared sub-expressions counted
  each time they are used (what printing or differentiating walks), memoised on the
  shared graph, so linear in the size of the file;
* :func:`expanded_terms`: an upper estimate of the monomials ``sympy.expand`` produces
  (a sum adds, a product multiplies, an integer power ``(t terms)**n`` gives
  ``C(n + t - 1, t - 1)``); inside a function call the argument is measured on its own;

and refuses (with the field and the numbers) a model past :data:`MAX_TREE_NODES`,
:data:`MAX_EXPANDED_TERMS` or :data:`MAX_FAULTS` before anything is derived.
"""

from __future__ import annotations

import math

import sympy as sp

from fdigen.errors import ModelFileError

#: Most nodes of one equation after the definitions are substituted.
MAX_TREE_NODES = 20000
#: Most monomials one equation may expand to.
MAX_EXPANDED_TERMS = 20000
#: Most faults of a model: each costs a structural analysis and a signature; the
#: consistent-fault set of the generated code is a bit mask.
MAX_FAULTS = 32


def tree_size(expr: sp.Basic, memo: dict | None = None) -> int:
    """Nodes of the expression tree of ``expr`` (shared sub-expressions counted at every
    use), computed on the shared graph in linear time. ``memo`` may hold the sizes of
    symbols that stand for larger expressions (definitions)."""
    memo = {} if memo is None else memo
    stack = [(expr, False)]
    while stack:
        node, done = stack.pop()
        if node in memo:
            continue
        if done or not node.args:
            memo[node] = 1 + sum(memo[a] for a in node.args)
            continue
        stack.append((node, True))
        stack.extend((a, False) for a in node.args if a not in memo)
    return memo[expr]


def expanded_terms(expr: sp.Basic, memo: dict | None = None) -> int:
    """Upper estimate of the number of monomials of ``sympy.expand(expr)`` (the largest
    of ``expr``'s own and of any function argument inside it). ``memo`` may hold the
    terms of symbols that stand for larger expressions (definitions)."""
    memo = {} if memo is None else memo
    worst = [1]

    def terms(node) -> int:
        if node in memo:                 # also a definition's symbol: its terms
            return memo[node]
        if isinstance(node, sp.Add):
            n = sum(terms(a) for a in node.args)
        elif isinstance(node, sp.Mul):
            n = math.prod(terms(a) for a in node.args)
        elif isinstance(node, sp.Pow):
            t = terms(node.base)
            e = node.exp
            n = (math.comb(int(e) + t - 1, t - 1)
                 if e.is_Integer and int(e) > 0 and t > 1 else t)
            terms(e)
        else:                     # a symbol, a number, a function call: one term
            for a in node.args:
                terms(a)
            n = 1
        memo[node] = n
        worst[0] = max(worst[0], n)
        return n

    terms(expr)
    return worst[0]


def check_model_size(model) -> None:
    """Refuse a model whose equations, once the definitions are substituted, are past
    :data:`MAX_TREE_NODES` nodes or :data:`MAX_EXPANDED_TERMS` monomials, or with more
    than :data:`MAX_FAULTS` faults.

    Raises
    ------
    ModelFileError
        Naming the field and the measured size.
    """
    src = model.source
    if len(model.faults) > MAX_FAULTS:
        raise ModelFileError(f"{len(model.faults)} faults, more than the limit {MAX_FAULTS}",
                             src, "faults")
    nodes, terms = {}, {}
    fields = []
    for name, value in model.definitions:      # in order: each uses only earlier ones
        fields.append((f"definitions.{name}", value))
    fields += [(f"dynamics.{s.name}", e) for s, e in zip(model.states, model.dynamics)]
    fields += [(f"outputs.{o.name}", o.expr) for o in model.outputs]
    fields += [(f"faults.{f.name}", term) for f in model.faults for _, term in f.terms]
    for field, expr in fields:
        expr = sp.sympify(expr)
        n = tree_size(expr, nodes)
        if n > MAX_TREE_NODES:
            raise ModelFileError(
                f"{n} expression nodes once the definitions are substituted, more than the "
                f"limit {MAX_TREE_NODES} (a definition used many times over?)", src, field)
        m = expanded_terms(expr, terms)
        if m > MAX_EXPANDED_TERMS:
            raise ModelFileError(
                f"expands to about {m:.3g} terms, more than the limit {MAX_EXPANDED_TERMS} "
                "(products and powers of sums multiply out)", src, field)
        if field.startswith("definitions."):
            symbol = sp.Symbol(field.split(".", 1)[1], real=True)
            nodes[symbol], terms[symbol] = n, terms[expr]

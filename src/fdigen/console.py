"""Rich console output that never cuts text: the consoles, tables and prose lines of the
command line and of the tuning campaign's progress bars.

On a terminal, prose is wrapped to the terminal's width and a table wider than it is
split into several tables that fit, each repeating the name column; anywhere else (a
pipe, a file, a test runner capturing output) the console is :data:`WIDE` columns wide,
so tables take their natural width and prose stays on one line. A cell that still does
not fit is folded onto the next line, never shortened to ``…``, and a number is never
separated from its unit (write them joined by :data:`NBSP`). Print a table's title with
:func:`say` before it, not as rich's ``title`` (rich wraps a title to the table's width).

Nothing is imported from rich until a function runs.
"""

from __future__ import annotations

import textwrap

from fdigen.errors import shown

#: Columns of a console that does not write to a terminal: wide enough for any table
#: fdigen prints at its natural width.
WIDE = 1000

#: No-break space: put it between a number and its unit (``f"{dt:g}{NBSP}s"``) and
#: :func:`say` never breaks the line there; it prints as an ordinary space.
NBSP = "\u00a0"


def console(stderr: bool = False):
    """A rich console on stdout (or stderr): the terminal's width on a terminal,
    :data:`WIDE` columns otherwise. Rich markup is off: a table header or cell such as
    ``flag raised at [s]`` is printed as written."""
    from rich.console import Console

    con = Console(stderr=stderr, markup=False, highlight=False)
    if not con.is_terminal:
        con = Console(stderr=stderr, markup=False, highlight=False, width=WIDE)
    return con


def print_table(con, columns, rows, *, keys: int = 1) -> None:
    """Print a table on ``con`` without cutting a cell.

    Parameters
    ----------
    con : rich.console.Console
    columns : sequence of (str, str)
        Header and justification (``"left"``, ``"center"``, ``"right"``) of each column.
    rows : sequence of sequence of str
        The cells (plain text, no rich markup).
    keys : int
        Leading columns that name a row (fault, residual): when the table is wider than
        the console, the other columns are split into groups that fit, and each group is
        printed as a table of its own after the key columns (as pandas prints a wide
        frame). A single column still too wide is folded onto several lines.

    A table is ``sum(w_j + 2) + n + 1`` cells wide for columns of text width ``w_j``
    (one space of padding each side, ``n + 1`` borders).
    """
    from rich.cells import cell_len
    from rich.table import Table

    rows = [[shown(c) for c in r] for r in rows]
    widths = [max([cell_len(h), *(cell_len(r[j]) for r in rows)]) + 2
              for j, (h, _) in enumerate(columns)]

    def width(index):
        return sum(widths[j] for j in index) + len(index) + 1

    key = list(range(min(keys, len(columns))))
    groups, group = [], []
    for j in range(len(key), len(columns)):
        if group and width(key + group + [j]) > con.width:
            groups.append(group)
            group = []
        group.append(j)
    groups.append(group)
    for index in groups:
        tab = Table()
        for j in key + index:
            header, justify = columns[j]
            tab.add_column(header, justify=justify, overflow="fold")
        for r in rows:
            tab.add_row(*(r[j] for j in key + index))
        con.print(tab)


def say(con, text: str, *, bold: int = 0) -> None:
    """Print a line of prose on ``con`` without ever cutting it.

    On a terminal it is wrapped to the width at ordinary spaces (never at :data:`NBSP`,
    so a number stays with its unit), continuation lines indented two more spaces than
    the first; elsewhere it is printed as it is (one line per line of ``text``). The
    first ``bold`` characters are printed bold. Rich markup in ``text`` is not
    interpreted.
    """
    from rich.text import Text

    text = shown(text)     # text from an input (a file name) never reaches the terminal raw
    if con.is_terminal:
        lines = []
        for part in text.split("\n"):
            lead = part[:len(part) - len(part.lstrip(" "))]
            lines += textwrap.wrap(part, width=max(con.width, 20), break_on_hyphens=False,
                                   subsequent_indent=lead + "  ") or [""]
    else:
        lines = [text]
    for i, line in enumerate(lines):
        out = con.highlighter(Text(line.replace(NBSP, " ")))
        if i == 0 and bold:
            out.stylize("bold", 0, bold)
        con.print(out, soft_wrap=True)

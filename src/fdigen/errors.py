"""Exceptions raised by fdigen. Every error names what is wrong and where."""


def shown(text, keep: str = "\n\t") -> str:
    """``text`` safe to print on a terminal, or to put in a figure title or an HTML page:
    every control or format character (Unicode categories C*: ESC, BEL, NUL, bidirectional
    overrides, zero-width characters, lone surrogates of an undecodable file name) and the
    line and paragraph separators, except those of ``keep``, written as its escape
    (``\\x1b``), so text from an input (a model file's expression, a log's file name)
    cannot move the cursor, retitle the terminal, reorder what is shown or make XML
    ill-formed. Spaces (a no-break space between a number and its unit) are kept."""
    import unicodedata

    def hidden(c):
        cat = unicodedata.category(c)
        return c not in keep and (cat[0] == "C" or cat in ("Zl", "Zp"))

    return "".join(c.encode("unicode_escape", "backslashreplace").decode("ascii")
                   if hidden(c) else c for c in str(text))


class FdigenError(ValueError):
    """Base class of every error fdigen raises on bad input or an impossible design."""


class ModelFileError(FdigenError):
    """A model file (or model definition) is malformed.

    Parameters
    ----------
    message : str
        What is wrong.
    source : str, optional
        The file (or ``"<api>"``) the model came from.
    field : str, optional
        The dotted field in which the problem was found, e.g. ``dynamics.Pp``.
    symbol : str, optional
        The offending symbol or construct.
    """

    def __init__(self, message, source=None, field=None, symbol=None):
        self.source = source
        self.field = field
        self.symbol = symbol
        where = []
        # one line: a newline inside an equation is written as its escape
        if source:
            where.append(shown(source, keep=""))
        if field:
            where.append(f"field '{shown(field, keep='')}'")
        if symbol:
            where.append(f"symbol '{shown(symbol, keep='')}'")
        prefix = ", ".join(where)
        super().__init__(f"{prefix}: {message}" if prefix else message)


class DesignError(FdigenError):
    """The FDI design cannot be built (unobservable, not detectable, bad noise weights...)."""


class BuildError(FdigenError):
    """A build stage (rendering, compiling, writing) failed; the output folder is unchanged."""


class LogError(FdigenError):
    """A measured log is malformed; the message names the row and column."""


class FdigenNote(UserWarning):
    """A note about the user's model that does not stop the work (a symbolic step that ran
    out of its budget and fell back to numbers...): the ``fdigen`` command prints it as
    one line ``fdigen: note: ...`` on stderr."""

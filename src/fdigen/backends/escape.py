"""Escaping of free text (file names, descriptions, units, columns) for generated files.

Names that are code (states, parameters...) are identifiers checked by the model reader;
free text is not, and reaches generated files only through these functions (the jinja
filters ``comment_text`` and ``c_string`` of :func:`fdigen.backends.render.environment`),
so that data can never close a comment or a string, nor continue a line:

* no line break of any kind (``\\n``, ``\\r``, vertical tab, form feed, U+0085, U+2028/9):
  the text stays on its comment line;
* no other control or format character (bidirectional overrides: "Trojan source"), no
  backslash (C and make splice ``\\``-newline into the comment), no ``??`` (a C99
  trigraph: ``??/`` is a backslash), no ``*/`` nor ``/*``; in a Makefile no ``$``;
* each such character is written as ``<U+hhhh>`` (its code point in hex), which is visible and inert everywhere.
"""

from __future__ import annotations

import unicodedata

#: Characters written as ``<U+hhhh>`` (hex code point) in every comment.
_ALWAYS = {"\\"}
#: Extra characters escaped in a Makefile ``#`` comment.
_MAKE = {"$"}


def _visible(ch: str) -> str:
    return f"<U+{ord(ch):04X}>"


def comment_text(text, leader: str = "//") -> str:
    """``text`` made safe inside a one-line comment of a generated file.

    Parameters
    ----------
    text : object
        Converted with ``str``.
    leader : str
        The comment leader of the target file: ``"//"`` or ``"/*"`` (C), ``"#"`` (make).

    Returns
    -------
    str
        One line without control characters, backslashes, ``??``, ``*/``, ``/*`` (and
        ``$`` when ``leader == "#"``); runs of white space become one space.
    """
    special = _ALWAYS | (_MAKE if leader == "#" else set())
    out = []
    for ch in " ".join(str(text).split()):   # every Unicode line break and blank -> " "
        if ch in special or unicodedata.category(ch)[0] in "CZ" and ch != " ":
            out.append(_visible(ch))
        else:
            out.append(ch)
    s = "".join(out)
    while "??" in s:
        s = s.replace("??", "?<U+003F>")
    while "*/" in s or "/*" in s:
        s = s.replace("*/", "* /").replace("/*", "/ *")
    return s


def c_string(text) -> str:
    """A C string literal of ``text``: quotes, backslashes, ``?`` (trigraphs) and every
    non-printable or non-ASCII byte escaped (octal escapes of the UTF-8 bytes)."""
    out = []
    for ch in str(text):
        if ch in '"\\?':
            out.append("\\" + ch)
        elif " " <= ch <= "~":
            out.append(ch)
        else:
            out.extend(f"\\{b:03o}" for b in ch.encode("utf-8"))
    return '"' + "".join(out) + '"'

"""Writing a model file fdigen edited: parsed back, unchanged input checked, locked.

A model file written by fdigen (tuned thresholds, a calibrated or commissioned model) must
always parse back, and must not overwrite an edit somebody made while a campaign ran:

* :func:`file_digest` is the SHA-256 of the file's bytes when it was read;
* :func:`write_model_text` parses the new text with :mod:`tomllib` and as a model file
  (a file fdigen cannot read back is never written), takes an exclusive lock on the destination (``flock`` on
  the file itself: no lock file beside it), checks that the file still has the digest it
  had when it was read (else :class:`ModelChangedError`, nothing written) and replaces it
  atomically (:mod:`fdigen.files.atomic`).

Two concurrent writers: the second to take the lock finds the digest changed and is told.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import tomllib
from pathlib import Path

from fdigen.errors import FdigenError
from fdigen.files.atomic import resolve_target, write_text


class ModelChangedError(FdigenError):
    """The model file changed between the read and the write (another writer, an edit)."""


def file_digest(path) -> str | None:
    """SHA-256 (hex) of the file's bytes; ``None`` when it does not exist."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except FileNotFoundError:
        return None


def check_toml(text: str, what: str) -> None:
    """Raise :class:`FdigenError` unless ``text`` is valid TOML (a file fdigen generated
    that does not parse back is a bug: it is refused before anything is written)."""
    try:
        text.encode("utf-8")
        tomllib.loads(text)
    except (ValueError, RecursionError) as exc:     # TOMLDecodeError, UnicodeError too
        raise FdigenError(f"{what}: the text fdigen generated does not parse back as TOML "
                          f"({exc}); nothing written") from None


def check_model(text: str, what: str) -> None:
    """Raise :class:`FdigenError` unless ``text`` reads back as a model file (its tables,
    names, numbers, expressions and ``tolerance`` fields): a commissioned file with a
    parameter's ``tolerance = 3.55`` was written and then refused by every command
    (attack round 3). The design-level checks (thresholds a derived residual needs) are
    not made here: a file written before its tuning may lack them."""
    from fdigen.errors import ModelFileError
    from fdigen.model.model_file import parse_model_text

    try:
        parse_model_text(text, source=what)
    except ModelFileError as exc:
        raise FdigenError(f"{what}: the model file fdigen generated does not read back "
                          f"({exc}); nothing written") from None


@contextlib.contextmanager
def locked(path, wait: bool = True):
    """An exclusive ``flock`` on the existing file ``path`` (its target), held for the
    block; nothing when the file does not exist yet."""
    target = resolve_target(path)
    try:
        fd = os.open(target, os.O_RDONLY)
    except FileNotFoundError:
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            raise ModelChangedError(f"{path}: another fdigen command is writing this file; "
                                    "nothing written") from None
        yield
    finally:
        os.close(fd)


def write_model_text(path, text: str, expected_digest: str | None = None, *,
                     check_input: bool = False) -> Path:
    """Write the model file ``path`` atomically after checking ``text`` parses back.

    Parameters
    ----------
    path : str or Path
    text : str
        The new model file.
    expected_digest : str, optional
        With ``check_input``: the :func:`file_digest` of ``path`` when it was read;
        ``None`` means the file did not exist.
    check_input : bool
        Refuse (:class:`ModelChangedError`) when the file's digest differs from
        ``expected_digest`` (checked under the lock).
    """
    check_toml(text, str(path))
    check_model(text, str(path))
    with locked(path, wait=False):
        if check_input and file_digest(path) != expected_digest:
            raise ModelChangedError(
                f"{path} changed since fdigen read it (edited, or written by another "
                "fdigen command); nothing written: rerun on the current file")
        return write_text(path, text)

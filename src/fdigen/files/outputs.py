"""Output paths checked before any long work: a folder that exists and can be written.

A campaign or a simulation that runs for minutes and then fails to write its result loses
it all; :func:`check_output_file` and :func:`check_output_folder` fail at once instead,
with a usage error naming the option (exit status 2).
"""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

from fdigen.errors import FdigenError
from fdigen.files.atomic import resolve_target


class OutputPathError(FdigenError):
    """An output path that cannot be written (missing or read-only folder, a folder where
    a file is expected...)."""


def check_output_file(path, option: str = "-o") -> Path:
    """Raise :class:`OutputPathError` unless ``path`` (its symbolic links followed) can be
    written as a file; returns the target path.

    The folder must exist and be writable (a file is written atomically: a temporary
    file in that folder is renamed onto it); ``path`` must not be a folder.
    """
    try:
        target = resolve_target(path)
    except OSError as exc:
        raise OutputPathError(f"{option} {path}: {exc}") from None
    if target.is_dir():
        raise OutputPathError(f"{option} {path}: is a folder, a file name is needed")
    if target.exists() and not target.is_file():
        raise OutputPathError(f"{option} {path}: is a device, FIFO or socket, not a regular "
                              "file: fdigen writes a file by replacing it atomically, which "
                              "would destroy it (to discard the output, write it to a "
                              "temporary file)")
    folder = target.parent
    if not folder.is_dir():
        raise OutputPathError(f"{option} {path}: no folder {folder}")
    _probe(folder, option, path)
    return target


def _probe(folder: Path, option: str, path) -> None:
    """Create and remove a temporary file in ``folder`` (what an atomic write does):
    the only test that holds for root, read-only mounts and special file systems."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise OutputPathError(f"{option} {path}: folder {folder} is not writable "
                              f"({exc.strerror or exc})") from None


def check_output_folder(path, option: str = "-o") -> Path:
    """Raise :class:`OutputPathError` unless ``path`` is a writable folder or can be
    created (its nearest existing ancestor is a folder in which a file can be created);
    nothing is left behind."""
    p = Path(os.path.abspath(path))
    if p.exists() and not p.is_dir():
        raise OutputPathError(f"{option} {path}: exists and is not a folder")
    probe = p
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    if not probe.is_dir():
        raise OutputPathError(f"{option} {path}: {probe} is not a folder")
    _probe(probe, option, path)
    return p


#: Keys every ground-truth JSON fdigen writes holds (``simulate``, ``platform simulate``).
TRUTH_KEYS = frozenset({"case", "sample_time", "truth"})


def _json_keys(path) -> set | None:
    """The keys of the JSON object in the regular file ``path`` (at most 64 MiB), or None
    (not a regular file, not JSON, not an object, nested too deeply)."""
    import json

    from fdigen.files.bounded import read_bytes

    try:
        doc = json.loads(read_bytes(path, 64 << 20).decode("utf-8"))
    except (FdigenError, ValueError, RecursionError):
        return None
    return set(doc) if isinstance(doc, dict) else None


def is_fdigen_truth(path) -> bool:
    """Whether ``path`` is a ground-truth JSON written by fdigen (a JSON object with the
    keys of :data:`TRUTH_KEYS`, at most 64 MiB)."""
    return TRUTH_KEYS <= (_json_keys(path) or set())


def _head(path) -> bytes:
    """The first 4 KiB of the regular file ``path`` (empty for anything else: never open a
    FIFO to read it, the open blocks until a writer comes, nor a device)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return b""
        with open(path, "rb") as fh:
            return fh.read(4096)
    except OSError:
        return b""


def is_fdigen_png(path) -> bool:
    """Whether ``path`` is a PNG figure fdigen wrote (its ``Software`` text chunk reads
    ``fdigen report``, :data:`fdigen.report.PNG_MARK`; the chunk comes before the image
    data, so the first 4 KiB hold it)."""
    head = _head(path)
    return head.startswith(b"\x89PNG") and b"tEXtSoftware\x00fdigen report" in head


def check_figure_sidecars(files, option: str, force: bool = False) -> None:
    """Refuse (:class:`OutputPathError`) to overwrite existing figure ``files`` a command
    writes beside the one the user named, unless each is a PNG fdigen wrote
    (:func:`is_fdigen_png`) or ``force``. Checked before any long work."""
    foreign = [Path(f) for f in files
               if os.path.lexists(f) and not (force or is_fdigen_png(f))]
    if foreign:
        raise OutputPathError(f"{option}: would overwrite {', '.join(map(str, foreign))}, "
                              "which fdigen did not write; move them, choose another "
                              "name, --no-per-leg, or pass --force")


def check_sidecars(files, truth, option: str, force: bool = False) -> None:
    """Refuse (:class:`OutputPathError`) to overwrite existing ``files`` a command writes
    besides the one the user named, unless ``truth`` (the run's ground-truth JSON) is
    there and was written by fdigen (then the files are an earlier fdigen run), or
    ``force``. Checked before the simulation."""
    existing = [Path(f) for f in files if os.path.lexists(f)]
    special = [str(p) for p in existing if p.exists() and not p.is_file()]
    if special:          # refused before any file is written, --force or not
        raise OutputPathError(f"{option}: {', '.join(special)} is not a regular file (a "
                              "device, FIFO or socket): fdigen would destroy it; move it")
    if not existing or force or is_fdigen_truth(truth):
        return
    names = ", ".join(str(p) for p in existing)
    raise OutputPathError(f"{option}: would overwrite {names}, which fdigen did not write "
                          f"({Path(truth).name} is not an fdigen ground truth); move "
                          "them, choose another name, or pass --force")


#: Marks fdigen writes at the start of its text outputs: generated sources, and model
#: files written by ``discover`` (augmented or calibrated) and ``commission``.
TEXT_MARKS = (b"Generated by fdigen", b"by `fdigen discover`", b"by `fdigen commission`")

#: Keys of the JSON results fdigen writes into an output folder (``discover.json``,
#: ``commission.json``): a JSON object holding all of them is fdigen's.
RESULT_KEYS = frozenset({"log", "model"})


def is_fdigen_output(path) -> bool:
    """Whether the existing file ``path`` is one fdigen wrote: a PNG figure with fdigen's
    mark (:func:`is_fdigen_png`), a JSON result object (:data:`RESULT_KEYS`) or ground
    truth (:func:`is_fdigen_truth`), or a text file whose first 4 KiB hold one of
    :data:`TEXT_MARKS`. Only regular files are read."""
    suffix = Path(path).suffix.lower()
    if suffix == ".png":
        return is_fdigen_png(path)
    if suffix == ".json":
        keys = _json_keys(path) or set()
        return RESULT_KEYS <= keys or TRUTH_KEYS <= keys
    head = _head(path)
    return any(mark in head for mark in TEXT_MARKS)


def check_own_outputs(files, option: str, force: bool = False) -> None:
    """Refuse (:class:`OutputPathError`) to overwrite any of ``files`` (the files a
    command writes into a folder the user named) that exists and fdigen did not write
    (:func:`is_fdigen_output`), unless ``force``. Call it before the long work: a user's
    hand-edited model, figure or notes under one of those names is never replaced."""
    if force:
        return
    foreign = [str(f) for f in files if os.path.lexists(f)
               and (Path(f).is_dir() or not is_fdigen_output(f))]
    if foreign:
        raise OutputPathError(f"{option}: would overwrite {', '.join(foreign)}, which fdigen "
                              "did not write; move them, choose another folder, or pass "
                              "--force")

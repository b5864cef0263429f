"""The build stamp: what fdigen wrote into ``<out>/<model>/``, and whether it may replace it.

``<out>/<model>/.fdigen-stamp`` is a JSON object::

    {"fdigen_stamp": 2, "input": "<sha256 of the build's inputs>", "model": "<name>",
     "files": {"c/<m>_fdi.c": "<sha256>", ...}}

* **Up to date** (:func:`is_up_to_date`): the inputs' hash matches, the folder is named
  after the model the stamp records (a copy under another name is not a build of that
  model), and every file of the manifest is there with its recorded hash (a deleted or
  edited generated file means a rebuild).
* **May be replaced** (:func:`replace_refusal`): a build replaces ``<out>/<model>/`` only
  when it is absent, empty, or carries a stamp and holds nothing but the files that stamp
  lists (for a stamp of an earlier fdigen, a plain hash without manifest: nothing but the
  files this build writes). Anything else (a user's ``controller.c``, ``notes/``,
  ``.git``, a package's sources) makes the build refuse, naming the folder.

Imports nothing heavy: the unchanged-build check runs before sympy or CasADi.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

STAMP = ".fdigen-stamp"
LOCK = ".fdigen.lock"
VERSION = 2


def file_digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def stamp_text(input_stamp: str, model: str, files: dict[str, str]) -> str:
    """The stamp of a build of ``model`` writing ``files`` (path -> text, or bytes)."""
    return json.dumps({"fdigen_stamp": VERSION, "input": input_stamp, "model": model,
                       "files": {rel: file_digest(text if isinstance(text, bytes)
                                                  else text.encode("utf-8"))
                                 for rel, text in sorted(files.items())}},
                      indent=1, sort_keys=True) + "\n"


def read_stamp(folder: Path) -> dict | None:
    """The stamp of ``folder`` as a dict (``{"input": hash}`` for an old plain-hash stamp),
    or None when there is none or it is not fdigen's (a link, not a regular file, over
    1 MiB, not UTF-8, not JSON, JSON nested too deeply, not a stamp object)."""
    path = Path(folder) / STAMP
    try:
        if path.is_symlink() or not path.is_file() or path.stat().st_size > 1 << 20:
            return None
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    plain = text.strip()
    if len(plain) == 64 and all(c in "0123456789abcdef" for c in plain):
        return {"input": plain}
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError):   # not JSON, or nested too deeply: not fdigen's
        return None
    if not isinstance(doc, dict) or doc.get("fdigen_stamp") != VERSION \
            or not isinstance(doc.get("files"), dict):
        return None
    return doc


def _present(folder: Path) -> set[str]:
    """Every file and link under ``folder`` (relative, POSIX), folders not followed."""
    out = set()
    for root, dirs, files in os.walk(folder, followlinks=False):
        for name in files + [d for d in dirs if os.path.islink(os.path.join(root, d))]:
            out.add(Path(os.path.relpath(os.path.join(root, name), folder)).as_posix())
    return out


def is_up_to_date(folder: Path, input_stamp: str) -> bool:
    """Whether ``folder`` holds the unchanged output of a build with these inputs."""
    doc = read_stamp(folder)
    if doc is None or doc.get("input") != input_stamp or "files" not in doc \
            or doc.get("model") != Path(folder).name:
        return False
    for rel, digest in doc["files"].items():
        path = Path(folder) / rel
        try:
            if path.is_symlink() or not path.is_file() \
                    or file_digest(path.read_bytes()) != digest:
                return False
        except OSError:
            return False
    return True


def is_complete_build(folder: Path, model: str) -> bool:
    """Whether ``folder`` holds a build of ``model`` and nothing else: a stamp with a
    manifest, naming ``model``, and no file the manifest does not list (its hashes are not
    checked: an edited generated file is still fdigen's to replace)."""
    doc = read_stamp(folder)
    if doc is None or "files" not in doc or doc.get("model") != model:
        return False
    return _present(Path(folder)) <= set(doc["files"]) | {STAMP, LOCK}


def replace_refusal(target: Path, new_files=None) -> str | None:
    """Why a build must not replace ``target`` (None when it may).

    Parameters
    ----------
    target : Path
        ``<out>/<model>``.
    new_files : iterable of str, optional
        The files this build writes (for a stamp without manifest; None: such a folder
        is not judged yet).
    """
    target = Path(target)
    if not target.exists() and not target.is_symlink():
        return None
    if target.is_symlink() or not target.is_dir():
        return f"{target} exists and is not a folder fdigen wrote"
    present = _present(target)
    if not present and not any(target.iterdir()):
        return None
    doc = read_stamp(target)
    if doc is None:
        return (f"{target} is not empty and has no {STAMP}: fdigen did not write it "
                "(move its files away or choose another --out)")
    if "files" not in doc and new_files is None:
        return None
    allowed = set(doc["files"]) if "files" in doc else set(new_files)
    allowed |= {STAMP, LOCK}
    foreign = sorted(present - allowed)
    if foreign:
        shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        return (f"{target} holds files fdigen did not write ({shown}); move them away "
                "or choose another --out")
    return None

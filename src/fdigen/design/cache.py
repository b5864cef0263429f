"""A disk cache of derived designs, keyed by the model, fdigen's sources and the libraries.

Deriving a design takes seconds (symbolic reduction, Riccati equations); commands that
only *use* a design (detect, verify, report) and ``fdigen build`` load it from here when
neither the model nor fdigen (nor sympy, numpy, scipy) changed. The cache folder is
``$FDIGEN_CACHE/designs`` or ``~/.cache/fdigen/designs``.

:func:`load_design` and :func:`store_design` are separate so that a build stores its
design only once every stage succeeded (a failed build leaves the cache as it was);
:func:`cached_design` does both, and also keeps the refusal of a derivation that
lacks only thresholds (``.refused``), which ``tune`` and ``inspect`` meet first on a model
whose derived residuals have no threshold yet. Beside each design the build keeps its description
(:func:`fdigen.design.describe.describe_design`, a pure function of the design whose
simplifications cost about half a second): :func:`load_description`.

Loading a pickle runs code, so the cache is read only from a folder and files owned by the
current user that no one else can write (like the C library cache); otherwise it is
ignored with a warning. The folder is created with mode 0700.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import pickle
import stat
import sys
import tempfile
from functools import lru_cache
from pathlib import Path

from fdigen.errors import FdigenError
from fdigen.files.trust import reason_for_stat, untrusted_reason
from fdigen.model.model import Model
from fdigen.model.model_file import model_hash


def cache_dir() -> Path:
    """The cache folder (created on demand)."""
    from fdigen.files.cache_root import cache_root

    return cache_root() / "designs"


def _code_digest() -> str:
    """Hash of fdigen's sources and of the versions of the libraries a design holds."""
    h = hashlib.sha256()
    src = Path(__file__).resolve().parents[1]
    for path in sorted(src.rglob("*.py")):
        h.update(path.read_bytes())
    h.update(_library_versions().encode())
    return h.hexdigest()[:16]


@lru_cache(maxsize=None)
def _library_versions() -> str:
    from importlib.metadata import PackageNotFoundError, version

    parts = [sys.version]
    for name in ("sympy", "numpy", "scipy", "mpmath"):
        try:
            parts.append(f"{name} {version(name)}")
        except PackageNotFoundError:
            parts.append(f"{name} -")
    return "\n".join(parts)


def _text_digest(model: Model) -> str:
    """Hash of the model's free text that generated files print (units, descriptions,
    columns, the model file's name), which :func:`model_hash` leaves out."""
    text = repr((model.name, model.states, model.inputs, model.outputs, model.parameters,
                 model.faults, getattr(model, "description", None),
                 Path(str(model.source)).name))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:12]


def design_path(model: Model) -> Path:
    """The cache file of a model's design (keyed by the model hash, its printed text and
    fdigen's code)."""
    return cache_dir() / (f"{model.name}-{model_hash(model)[:24]}-{_text_digest(model)}-"
                          f"{_code_digest()}.pkl")


_WARNED: set = set()


def _untrusted(folder: Path) -> str | None:
    """Why the cache folder must not be read (another user may write it), or None."""
    reason = untrusted_reason(folder)
    if reason is not None and str(folder) not in _WARNED:
        _WARNED.add(str(folder))
        print(f"fdigen: warning: design cache not used: {reason}", file=sys.stderr)
    return reason


def _open_private(path: Path, mode: str):
    """``path`` opened for reading if it and its folder are private to the current user
    (owner and permissions checked on the open file itself); else None."""
    if not path.parent.is_dir() or _untrusted(path.parent) is not None:
        return None
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return None
    fh = os.fdopen(fd, mode)
    reason = reason_for_stat(os.fstat(fd), path)
    if reason is not None or not stat.S_ISREG(os.fstat(fd).st_mode):
        fh.close()
        if reason is not None and str(path) not in _WARNED:
            _WARNED.add(str(path))
            print(f"fdigen: warning: design cache not used: {reason}", file=sys.stderr)
        return None
    return fh


#: First line of every cache file: the format, then the SHA-256 of the rest.
_MAGIC = b"fdigen-cache-2\n"


def _framed(data: bytes) -> bytes:
    """``data`` as a cache file: :data:`_MAGIC`, the SHA-256 of ``data`` (hex, one line),
    ``data``."""
    return _MAGIC + hashlib.sha256(data).hexdigest().encode("ascii") + b"\n" + data


def _read_framed(path: Path) -> bytes | None:
    """The payload of the cache file ``path`` (:func:`_framed`), read only when private
    (:func:`_open_private`) and only when its digest matches: a flipped byte in a cached
    design had built C with a parameter of 1.15e-44 in place of 5e-4, verified "equal"
    (the reference read the same design) and never said; others ended in "internal error
    (MemoryError)" naming no file. A corrupted entry is said, ignored and derived again."""
    fh = _open_private(path, "rb")
    if fh is None:
        return None
    with fh:
        raw = fh.read()
    head = len(_MAGIC) + 65
    if raw[:len(_MAGIC)] != _MAGIC:
        return None                      # another format (an older fdigen): not used
    digest, data = raw[len(_MAGIC):head - 1], raw[head:]
    if raw[head - 1:head] != b"\n" or hashlib.sha256(data).hexdigest().encode() != digest:
        if str(path) not in _WARNED:
            _WARNED.add(str(path))
            print(f"fdigen: warning: design cache entry {path} is corrupted (its SHA-256 "
                  "does not match its content): ignored, derived again", file=sys.stderr)
        return None
    return data


def _unpickled(path: Path):
    """The object of a framed pickle cache file, or None (absent, untrusted, corrupted,
    or unreadable)."""
    try:
        data = _read_framed(path)
        return None if data is None else pickle.loads(data)
    except Exception:       # a pickle of an older fdigen's classes: derived again
        return None


def load_design(model: Model):
    """The cached design of ``model``, or None when there is none (or it is unreadable).

    A pickle runs code when loaded: it is read only from a folder and a file owned by the
    current user and writable by no one else (else a warning and None). An entry carries
    the full hash of the model it was derived from: one whose hash differs from
    ``model``'s (a design of another model stored under this key) is ignored with a
    warning.

    Returns
    -------
    FdiDesign or None
    """
    path = design_path(model)
    entry = _unpickled(path)
    if not (isinstance(entry, tuple) and len(entry) == 4 and entry[0] == _TAG):
        return None
    if entry[1:3] != _identity(model):   # another model's design under this key
        if str(path) not in _WARNED:
            _WARNED.add(str(path))
            print(f"fdigen: warning: design cache entry {path.name} was derived from another "
                  "model (its model hash differs): ignored, derived again", file=sys.stderr)
        return None
    design = entry[3]
    if getattr(design, "model", model) != model:
        # the key leaves the folder out: the design names the file read now, not the copy
        # it was first derived from (a checkout elsewhere shares ~/.cache)
        design = dataclasses.replace(design, model=model)
    return design


#: First field of a cache entry: ``(_TAG, model_hash, text_digest, design)``.
_TAG = "fdigen-design-1"


def _identity(model: Model) -> tuple[str, str]:
    """What a cache entry must carry to serve ``model``: its full model hash and the
    digest of its printed text."""
    return model_hash(model), _text_digest(model)


def load_description(model: Model) -> dict | None:
    """The cached description of the model's design (a dict), or None; it carries the
    identity of its model like a design (another model's description under this key,
    three tanks' as the motor's ``design.json``, is not used)."""
    try:
        data = _read_framed(design_path(model).with_suffix(".json"))
        entry = None if data is None else json.loads(data.decode("utf-8"))
    except (OSError, ValueError):
        return None
    if not (isinstance(entry, dict) and entry.get("identity") == list(_identity(model))):
        return None
    return entry.get("description")


def store_design(model: Model, design, description: dict | None = None) -> None:
    """Write ``design`` (and its description) into the cache, each atomically; silently
    skipped on an OS error."""
    from fdigen.design.stored_minmax import pickle_minmax_as_stored

    pickle_minmax_as_stored()
    path = design_path(model)
    if _read_framed(path) is None:
        _write_atomic(path, _framed(pickle.dumps((_TAG, *_identity(model), design),
                                                 protocol=pickle.HIGHEST_PROTOCOL)))
    if description is not None and _read_framed(path.with_suffix(".json")) is None:
        _write_atomic(path.with_suffix(".json"), _framed(json.dumps(
            {"identity": list(_identity(model)), "description": description},
            sort_keys=True).encode("utf-8")))


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = None
    try:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        if untrusted_reason(path.parent) is not None:
            return
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except OSError:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)


def cached_design(model: Model):
    """``fdi_design(model)``, from the cache when the same model was derived before.

    Returns
    -------
    FdiDesign
    """
    from fdigen.design.retarget import evaluation_key, retargeted

    key = (evaluation_key(model), _text_digest(model))
    design = _held(model, key)
    if design is None:
        design = load_design(model)
    if design is None:
        refusal = _load_refusal(model)
        if refusal is not None:
            raise refusal
        sibling = _SIBLINGS.get(key)
        if sibling is not None:
            # the same design but for threshold values, horizons or the class decision
            design = retargeted(sibling, model)
        else:
            from fdigen.design import fdi_design as derivation   # looked up at call time

            try:
                design = derivation.fdi_design(model)
            except FdigenError as exc:
                if _needs_thresholds_only(exc):
                    _store_refusal(model, exc)
                raise
        store_design(model, design)
    _SIBLINGS.pop(key, None)
    _SIBLINGS[key] = design
    _HELD[key] = (str(design_path(model)), model_hash(model))
    while len(_SIBLINGS) > _SIBLINGS_KEPT:
        _HELD.pop(next(iter(_SIBLINGS)), None)
        _SIBLINGS.pop(next(iter(_SIBLINGS)))
    return design


def _held(model: Model, key):
    """The design this process last returned for the same model (same hash, same printed
    text, same cache entry, still on disk), without reading the entry again: unpickling a
    design rebuilds its sympy expressions (1.5 s for the cylinder, sixteen times in one
    ``commission``). ``None`` when there is none."""
    design, held = _SIBLINGS.get(key), _HELD.get(key)
    if design is None or held is None:
        return None
    path = design_path(model)
    if held != (str(path), model_hash(model)) or not path.is_file():
        return None
    if design.model != model:
        design = dataclasses.replace(design, model=model)
    return design


#: Designs of this process by :func:`~fdigen.design.retarget.evaluation_key` (and printed
#: text): a model differing from one of them only in what the evaluation reads is set from
#: it instead of derived again (:mod:`fdigen.design.retarget`). The most recent few.
_SIBLINGS: dict = {}
#: key of _SIBLINGS -> (cache entry path, model hash) of the design held there
_HELD: dict = {}
_SIBLINGS_KEPT = 4


def _needs_thresholds_only(exc) -> bool:
    """A refusal of a complete derivation that only lacks thresholds (derived residuals
    without one, or thresholds written for other residuals): ``fdigen tune`` and
    ``inspect`` fill them in and derive again, so it is worth keeping."""
    return bool(getattr(exc, "missing_thresholds", ()) or getattr(exc, "stale_residuals", ()))


def _load_refusal(model: Model):
    """The cached refusal of ``model``'s design (:func:`_needs_thresholds_only`), or None."""
    entry = _unpickled(design_path(model).with_suffix(".refused"))
    # like a design entry: tagged and carrying the full identity of its model
    if not (isinstance(entry, tuple) and len(entry) == 5 and entry[0] == _REFUSAL_TAG
            and entry[1:3] == _identity(model)):
        return None
    exc = entry[3]
    if not (isinstance(exc, FdigenError) and _needs_thresholds_only(exc)):
        return None
    return _rehomed(exc, entry[4] if len(entry) > 4 else None, model.source)


def _rehomed(exc, stored: str | None, source) -> FdigenError:
    """A cached refusal naming the file the model is read from now, not the one it was
    first derived from (the cache key leaves the folder out: a user's discover into
    ``outB`` was told of a missing threshold in ``outA``'s copy)."""
    if stored is None or source is None or str(stored) == str(source):
        return exc
    args = tuple(a.replace(str(stored), str(source)) if isinstance(a, str) else a
                 for a in exc.args)
    exc.args = args
    if getattr(exc, "source", None) == stored:
        exc.source = source
    return exc


#: First field of a cached refusal:
#: ``(_REFUSAL_TAG, model_hash, text_digest, error, the model's source when refused)``.
_REFUSAL_TAG = "fdigen-refusal-2"


def _store_refusal(model: Model, exc) -> None:
    """Keep the refusal of a derivation that lacks only thresholds: a second ``inspect``
    or ``tune`` of the same file then does not derive it again (minutes for a model whose
    symbolic reductions run out of their budget)."""
    path = design_path(model).with_suffix(".refused")
    if not path.is_file():
        try:
            data = pickle.dumps((_REFUSAL_TAG, *_identity(model), exc,
                                 None if model.source is None else str(model.source)),
                                protocol=pickle.HIGHEST_PROTOCOL)
        except (pickle.PicklingError, TypeError, AttributeError):
            return
        _write_atomic(path, _framed(data))

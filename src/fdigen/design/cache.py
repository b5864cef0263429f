"""A disk cache of derived designs, keyed by the model and fdigen's own sources.

Deriving a design takes seconds (symbolic reduction, Riccati equations); commands that
only *use* a design (detect, verify, report) load it from here when neither the model nor
fdigen changed. The cache folder is ``$FDIGEN_CACHE`` or ``~/.cache/fdigen``.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import tempfile
from pathlib import Path

from fdigen.design.fdi_design import FdiDesign, fdi_design
from fdigen.model.model import Model
from fdigen.model.model_file import model_hash


def cache_dir() -> Path:
    """The cache folder (created on demand)."""
    root = Path(os.environ.get("FDIGEN_CACHE", Path.home() / ".cache" / "fdigen"))
    return root / "designs"


def _code_digest() -> str:
    h = hashlib.sha256()
    src = Path(__file__).resolve().parents[1]
    for path in sorted(src.rglob("*.py")):
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def cached_design(model: Model) -> FdiDesign:
    """``fdi_design(model)``, from the cache when the same model was derived before."""
    key = f"{model.name}-{model_hash(model)[:24]}-{_code_digest()}.pkl"
    path = cache_dir() / key
    try:
        with open(path, "rb") as fh:
            return pickle.load(fh)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError):
        pass
    design = fdi_design(model)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            pickle.dump(design, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
    except OSError:
        pass
    return design

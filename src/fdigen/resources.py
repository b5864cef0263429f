"""Where fdigen's data files are: in a source checkout and in an installed wheel.

The top-level ``templates/`` folder of the repository is the source of truth. A wheel
ships a copy as ``fdigen/_templates`` (made by ``setup.py``'s ``build_py`` step); an
installed fdigen uses that copy, a source checkout (editable install or ``PYTHONPATH``)
the repository's folder. Built-in model files are package data (``fdigen/models``) in
both. Nothing here imports anything heavy.
"""

from __future__ import annotations

from pathlib import Path

#: The fdigen package folder.
PACKAGE_DIR = Path(__file__).resolve().parent

#: The repository root when fdigen runs from a source checkout (``src/fdigen``), else None.
SOURCE_ROOT = (PACKAGE_DIR.parents[1]
               if (PACKAGE_DIR.parents[1] / "pyproject.toml").is_file()
               and (PACKAGE_DIR.parents[1] / "templates").is_dir() else None)


def templates_dir() -> Path:
    """The templates folder: the repository's ``templates/`` in a source checkout (the
    source of truth), else the copy ``fdigen/_templates`` an installed package ships."""
    if SOURCE_ROOT is not None:
        return SOURCE_ROOT / "templates"
    return PACKAGE_DIR / "_templates"     # if missing, the jinja environment says so


#: The templates folder in use (see :func:`templates_dir`).
TEMPLATES_DIR = templates_dir()

#: The built-in model files.
MODELS_DIR = PACKAGE_DIR / "models"

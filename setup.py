"""setuptools hook: ship the top-level ``templates/`` inside the package.

``templates/`` stays the single source of truth for every generated file; building a wheel
(``pip wheel .``) copies it to ``fdigen/_templates`` in the build tree, where an installed
fdigen finds it (:mod:`fdigen.resources`). Everything else is in ``pyproject.toml``.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class build_py_with_templates(build_py):
    """``build_py`` that also copies ``templates/**/*.j2`` to ``<build>/fdigen/_templates``."""

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return            # an editable install reads the checkout's templates/
        src = ROOT / "templates"
        dst = Path(self.build_lib) / "fdigen" / "_templates"
        if not src.is_dir():
            raise FileNotFoundError(f"templates folder not found at {src}")
        shutil.rmtree(dst, ignore_errors=True)
        for path in sorted(src.rglob("*.j2")):
            target = dst / path.relative_to(src)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, target)


setup(cmdclass={"build_py": build_py_with_templates})

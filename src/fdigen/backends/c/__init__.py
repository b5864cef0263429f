"""The standalone C backend: a dependency-free C99 FDI library, an example and a Makefile.

* :func:`render_c_sources` -- the generated files as text;
* :class:`CFdi` -- the generated library compiled and loaded with ctypes, with the same
  ``core``/``run`` interface as :class:`fdigen.backends.reference.ReferenceFdi`.
"""

from fdigen.backends.c.config import FLOAT_TYPES, CBackendConfig
from fdigen.backends.c.emit import render_c_sources
from fdigen.backends.c.loader import CFdi, build_shared_library

__all__ = ["CBackendConfig", "CFdi", "FLOAT_TYPES", "build_shared_library", "render_c_sources"]

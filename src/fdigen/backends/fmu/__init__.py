"""The FMU backend: the generated C core as an FMI 2.0 co-simulation FMU.

* :func:`render_fmu_sources` -- ``modelDescription.xml`` and the FMI wrapper (templates
  under ``templates/fmu/``);
* :func:`fmu_archive` -- the wrapper compiled with the core for linux64, zipped
  deterministically.
"""

from fdigen.backends.fmu.emit import fmu_variables, render_fmu_sources
from fdigen.backends.fmu.package import fmu_archive

__all__ = ["fmu_archive", "fmu_variables", "render_fmu_sources"]

"""Settings of the standalone C backend: its templates, output files and float type."""

from __future__ import annotations

from dataclasses import dataclass

#: Floating-point types the generated C can be built for.
FLOAT_TYPES = ("double", "float")


@dataclass(frozen=True)
class CBackendConfig:
    """What the C backend renders.

    Attributes
    ----------
    name : str
        Backend name.
    template_dir : str
        Folder under ``templates/`` holding the backend's templates.
    float_type : str
        C type of every signal and parameter, ``"double"`` or ``"float"``.
    """

    name: str = "c"
    template_dir: str = "c"
    float_type: str = "double"

    def __post_init__(self):
        if self.float_type not in FLOAT_TYPES:
            raise ValueError(f"float_type must be one of {FLOAT_TYPES}, got {self.float_type!r}")

    def files(self, model_name: str) -> dict[str, tuple[str, str]]:
        """Output file name -> (template path, line-comment leader), in rendering order.

        Parameters
        ----------
        model_name : str
            The model's name (a C identifier), which prefixes the library files.

        Returns
        -------
        dict of str to (str, str)
        """
        base = f"{model_name}_fdi"
        t = self.template_dir
        return {
            f"{base}.h": (f"{t}/fdi.h.j2", "//"),
            f"{base}.c": (f"{t}/fdi.c.j2", "//"),
            "main.c": (f"{t}/main.c.j2", "//"),
            "Makefile": (f"{t}/Makefile.j2", "#"),
        }

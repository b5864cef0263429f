"""Compile the FMI 2.0 wrapper with the C core into ``binaries/linux64`` and zip the FMU.

The FMU is a zip archive; it is written byte for byte the same for the same sources and
compiler: entries sorted, every timestamp 1980-01-01, fixed permissions, and the shared
library compiled in a scratch folder from relative file names without debug information
(no path of the build machine enters it). A different compiler version gives a different
library, which is why the FMU is not among the committed ``generated/`` files.

The FMI 2.0 headers (``fmi2Functions.h``...) are those bundled with :mod:`fmpy`
(``pip install 'fdigen[fmu]'``).
"""

from __future__ import annotations

import io
import subprocess
import tempfile
import zipfile
from pathlib import Path

from fdigen.errors import BuildError

#: Flags of the FMU's shared library: those of the C backend's test library
#: (:data:`fdigen.backends.c.loader.SHARED_FLAGS`: strict IEEE, so the FMU computes the
#: same bits), warnings as errors.
FMU_CFLAGS = ("-std=c99", "-O2", "-fPIC", "-shared", "-ffp-contract=off", "-Wall", "-Wextra",
              "-Werror", "-fvisibility=hidden")

#: Timestamp of every zip entry (the earliest a zip can hold).
ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)


def fmi_headers() -> Path:
    """The folder of the FMI 2.0 headers bundled with fmpy.

    Raises
    ------
    BuildError
        If fmpy is not installed.
    """
    import importlib.util

    spec = importlib.util.find_spec("fmpy")     # only its data files are used, not its code
    if spec is None or not spec.submodule_search_locations:
        raise BuildError("the FMU needs the FMI 2.0 headers bundled with fmpy: "
                         "pip install 'fdigen[fmu]' (or pip install fmpy)")
    folder = Path(list(spec.submodule_search_locations)[0]).resolve() / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise BuildError(f"fmpy at {folder.parent} lacks c-code/fmi2Functions.h")
    return folder


def compile_binary(sources: dict[str, str], wrapper: str, identifier: str,
                   cc: str = "gcc") -> bytes:
    """The FMU's shared library ``<identifier>.so`` for linux64, compiled from ``sources``
    (file name -> text; ``wrapper`` is the translation unit, which includes the core).

    Raises
    ------
    BuildError
        If the compiler is missing or fails.
    """
    headers = fmi_headers()
    with tempfile.TemporaryDirectory(prefix="fdigen-fmu-") as tmp:
        for name, text in sources.items():
            (Path(tmp) / name).write_text(text, encoding="utf-8")
        out = f"{identifier}.so"
        cmd = [cc, *FMU_CFLAGS, "-I", str(headers), "-I", ".", wrapper, "-o", out, "-lm"]
        try:
            proc = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, timeout=300)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise BuildError(f"cannot compile the FMU with '{cc}': {exc}") from None
        if proc.returncode != 0:
            raise BuildError(f"the FMU wrapper does not compile ({' '.join(cmd)}):\n"
                             f"{proc.stderr.strip()[:4000]}")
        return (Path(tmp) / out).read_bytes()


def zip_bytes(entries: dict[str, bytes]) -> bytes:
    """A deterministic zip of ``entries`` (archive path -> content)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name in sorted(entries):
            info = zipfile.ZipInfo(name, date_time=ZIP_EPOCH)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.create_system = 3                       # unix
            info.external_attr = (0o100755 if name.endswith(".so") else 0o100644) << 16
            zf.writestr(info, entries[name], compresslevel=9)
    return buf.getvalue()


def fmu_archive(identifier: str, model_description: str, sources: dict[str, str],
                wrapper: str, cc: str = "gcc") -> bytes:
    """The FMU: ``modelDescription.xml``, ``sources/`` (the wrapper, the C core and its
    header) and ``binaries/linux64/<identifier>.so``."""
    binary = compile_binary(sources, wrapper, identifier, cc)
    entries = {"modelDescription.xml": model_description.encode("utf-8"),
               f"binaries/linux64/{identifier}.so": binary}
    for name, text in sources.items():
        entries[f"sources/{name}"] = text.encode("utf-8")
    return zip_bytes(entries)

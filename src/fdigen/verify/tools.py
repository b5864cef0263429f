"""The external tools of the assurance commands (Frama-C, cppcheck, the Arm toolchain,
QEMU): finding them, and the error naming the Debian package when one is missing."""

from __future__ import annotations

import shutil

from fdigen.errors import FdigenError

#: Tool -> the Debian package that installs it (scripts/setup installs them all).
PACKAGES = {"frama-c": "frama-c-base", "cppcheck": "cppcheck",
            "arm-none-eabi-gcc": "gcc-arm-none-eabi (and libnewlib-arm-none-eabi)",
            "arm-none-eabi-size": "binutils-arm-none-eabi",
            "qemu-system-arm": "qemu-system-arm"}


class ToolMissingError(FdigenError):
    """An external tool an assurance command needs is not installed."""


class ToolFailedError(FdigenError):
    """An external tool exited with an error (its output's tail is in the message)."""


def require_tool(name: str) -> str:
    """The path of tool ``name``; :class:`ToolMissingError` naming its package if absent."""
    path = shutil.which(name)
    if path is None:
        raise ToolMissingError(f"{name} is not installed (Debian package "
                               f"{PACKAGES.get(name, name)}; scripts/setup installs it)")
    return path


def missing_tools(*names: str) -> list[str]:
    """The tools of ``names`` that are not on PATH (for tests to skip with a reason)."""
    return [n for n in names if shutil.which(n) is None]

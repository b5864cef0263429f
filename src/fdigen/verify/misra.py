"""MISRA C:2012 report of the generated C (cppcheck's MISRA addon) against the recorded
deviations.

:func:`misra_report` runs ``cppcheck --addon=misra`` on every C file the C backend
generates for a design (``c/``: the double core, its header and the example ``main.c``;
``c_float/``: the float core; ``platform/``: the six-leg platform bank) and counts the
violations per file and rule. :func:`load_deviations` reads the deviation record
(``misra_deviations.json`` beside this module): each rule the generator deliberately
breaks, its category and why. A violation of a rule not in the record is *undeviated*.
CasADi's generated C (``casadi/``, CasADi's own code generator) is not analysed.
"""

from __future__ import annotations

import json
import re
import subprocess
import tempfile
import time
from collections import Counter
from pathlib import Path

from fdigen.backends.c.emit import render_c_sources
from fdigen.design.fdi_design import FdiDesign
from fdigen.model.model_file import model_hash
from fdigen.verify.tools import ToolFailedError, require_tool

#: The deviation record (machine-readable; docs/assurance.md has the same in words).
DEVIATIONS = Path(__file__).with_name("misra_deviations.json")
_LINE = re.compile(r"^(.+?):(\d+):(misra-c2012-[0-9.]+)$", re.M)


def generated_c_files(design: FdiDesign) -> dict[str, str]:
    """Every C file the C backend generates for ``design``: ``"<folder>/<file>"`` -> text
    (folders ``c``, ``c_float``, ``platform``)."""
    from fdigen.platform.codegen import render_platform_sources

    source, digest = Path(str(design.model.source or design.name)).name, model_hash(design.model)
    files = {}
    for folder, ft in (("c", "double"), ("c_float", "float")):
        for name, text in render_c_sources(design, float_type=ft, model_source=source,
                                           model_hash=digest).items():
            if name.endswith((".c", ".h")) and (ft == "double" or name != "main.c"):
                files[f"{folder}/{name}"] = text
    for name, text in render_platform_sources(design, model_source=source,
                                              model_hash=digest).items():
        if "platform" in name:
            files[f"platform/{name}"] = text
    return files


def load_deviations(path: Path | None = None) -> dict:
    """The deviation record: ``{"rules": {rule: {"category", "title", "reason"}}, ...}``."""
    return json.loads(Path(path or DEVIATIONS).read_text())


def run_misra(files: dict[str, str], *, timeout: float = 600.0) -> dict[str, Counter]:
    """cppcheck's MISRA addon on ``files`` (relative path -> text): rule counts per file."""
    cppcheck = require_tool("cppcheck")
    with tempfile.TemporaryDirectory(prefix="fdigen-misra-") as tmp:
        root = Path(tmp)
        for rel, text in files.items():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / rel).write_text(text)
        counts = {rel: Counter() for rel in files}
        for folder in sorted({Path(rel).parent for rel in files}):
            sources = sorted(str(root / rel) for rel in files
                             if Path(rel).parent == folder and rel.endswith(".c"))
            cmd = [cppcheck, "--addon=misra", "--std=c99", "--quiet", f"-I{root / folder}",
                   "--suppress=missingIncludeSystem", "--template={file}:{line}:{id}",
                   *sources]
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
            if proc.returncode != 0:
                raise ToolFailedError(f"cppcheck failed (exit {proc.returncode}):\n"
                                   + proc.stderr[-2000:])
            for path, _line, rule in _LINE.findall(proc.stderr + proc.stdout):
                rel = Path(path).resolve().relative_to(root.resolve()).as_posix()
                counts.setdefault(rel, Counter())[rule.removeprefix("misra-c2012-")] += 1
    return counts


def misra_report(design: FdiDesign, deviations: dict | None = None) -> dict:
    """The MISRA report of a design's generated C.

    Returns
    -------
    dict
        ``model``, ``files`` (``{file: {rule: count}}``), ``rules`` (``{rule: count}``
        over all files), ``violations`` (total), ``undeviated`` (``{rule: count}`` of
        rules not in the deviation record), ``seconds``.
    """
    deviations = load_deviations() if deviations is None else deviations
    start = time.perf_counter()
    counts = run_misra(generated_c_files(design))
    total = Counter()
    for c in counts.values():
        total.update(c)
    rules = dict(sorted(total.items(), key=lambda kv: [int(x) for x in kv[0].split(".")]))
    return {"model": design.name,
            "files": {f: dict(sorted(c.items())) for f, c in sorted(counts.items())},
            "rules": rules, "violations": sum(rules.values()),
            "undeviated": {r: n for r, n in rules.items() if r not in deviations["rules"]},
            "seconds": round(time.perf_counter() - start, 2)}

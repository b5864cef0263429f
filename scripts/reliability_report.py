#!/usr/bin/env python3
"""Run the reliability tests and render their results into docs/reliability.md.

Usage: python scripts/reliability_report.py [--no-run JSONL] [extra pytest args]

The tests (tests/test_reliability_*.py) append one JSON line per class of bad input or
fault to the file named by FDIGEN_RELIABILITY_REPORT; this script sets that variable to a
temporary file, runs pytest, aggregates the lines (same area, test, class and result are
summed) and renders templates/docs/reliability.md.j2 through fdigen's strict jinja
environment. Exits with pytest's status.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = ["tests/test_reliability_models.py", "tests/test_reliability_names.py",
         "tests/test_logs.py", "tests/test_reliability_c.py",
         "tests/test_reliability_numeric.py", "tests/test_reliability_build.py",
         "tests/test_reliability_security.py", "tests/test_state_validation.py",
         "tests/test_reliability_writes.py"]
OUTPUT = ROOT / "docs" / "reliability.md"
AREAS = ["model files", "logs", "generated C core", "build pipeline", "code execution",
         "data safety", "command line"]


def run_tests(report: Path, extra: list[str]) -> tuple[int, str]:
    env = dict(os.environ, FDIGEN_RELIABILITY_REPORT=str(report))
    cmd = [sys.executable, "-m", "pytest", "-q", "-rxs", "-p", "no:cacheprovider", *TESTS,
           *extra]
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    sys.stdout.write(proc.stdout[-4000:])
    sys.stderr.write(proc.stderr[-2000:])
    lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
    summary = lines[-1].strip("= ") if lines else "(no output)"
    return proc.returncode, summary


def aggregate(lines: list[dict]) -> list[dict]:
    rows: dict[tuple, dict] = {}
    for line in lines:
        key = (line["area"], line["test"], line["class"], line["result"])
        row = rows.setdefault(key, {"area": line["area"], "test": line["test"],
                                    "kind": line["class"], "result": line["result"],
                                    "cases": 0, "details": []})
        row["cases"] += int(line["cases"])
        if line.get("details"):
            counts = row.setdefault("counts", {})
            if line["details"] not in counts:
                row["details"].append(line["details"])
            counts[line["details"]] = counts.get(line["details"], 0) + 1
    out = []
    for row in rows.values():
        counts = row.pop("counts", {})
        # a detail repeated by several lines (one per hypothesis example) shows its count
        details = [d if counts[d] == 1 else f"{counts[d]} {d}" for d in row["details"]]
        row["details"] = "; ".join(details[:3]) + (f" (+{len(details) - 3} more)"
                                                    if len(details) > 3 else "")
        out.append(row)
    order = {a: i for i, a in enumerate(AREAS)}
    return sorted(out, key=lambda r: (order.get(r["area"], 99), r["test"], r["kind"]))


def render(rows: list[dict], summary: str) -> str:
    sys.path.insert(0, str(ROOT / "src"))
    from fdigen.backends.render import environment

    areas = []
    for name in [*AREAS, *sorted({r["area"] for r in rows} - set(AREAS))]:
        sub = [r for r in rows if r["area"] == name]
        if sub:
            areas.append({"name": name, "rows": sub})
    return environment().get_template("docs/reliability.md.j2").render(
        test_files=TESTS, summary=summary, rows=rows, areas=areas,
        total_cases=sum(r["cases"] for r in rows),
        n_pass=sum(r["result"] == "pass" for r in rows),
        n_xfail=sum(r["result"] == "FAIL (xfail)" for r in rows),
        n_fail=sum(r["result"] == "FAIL" for r in rows),
        defects=[r for r in rows if r["result"] != "pass"])


def main(argv: list[str]) -> int:
    if argv[:1] == ["--no-run"]:
        report, extra, status, summary = Path(argv[1]), argv[2:], 0, "(not run: --no-run)"
    else:
        fd, name = tempfile.mkstemp(prefix="fdigen-reliability-", suffix=".jsonl")
        os.close(fd)
        report, extra = Path(name), argv
        status, summary = run_tests(report, extra)
    lines = [json.loads(ln) for ln in report.read_text().splitlines() if ln.strip()]
    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    OUTPUT.write_text(render(aggregate(lines), summary))
    print(f"wrote {OUTPUT.relative_to(ROOT)} ({len(lines)} result lines)")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""Record the MISRA baseline of the shipped models (tests/data/misra_baseline.json).

Run after a deliberate change of the generated C (a template or the printer):
``python scripts/misra_baseline.py``; review the diff of the baseline like code. The test
``tests/test_misra.py`` fails on any violation count above it, and on any rule without a
deviation record (src/fdigen/verify/misra_deviations.json).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from fdigen.design.fdi_design import fdi_design
from fdigen.files.atomic import write_text
from fdigen.model.model_file import load_model
from fdigen.verify.misra import misra_report

SHIPPED = ("pneumatic_cylinder", "dc_motor", "three_tank", "heat_exchanger")
BASELINE = Path(__file__).resolve().parents[1] / "tests" / "data" / "misra_baseline.json"


def main() -> int:
    version = subprocess.run(["cppcheck", "--version"], capture_output=True,
                             text=True).stdout.strip()
    models = {}
    for name in SHIPPED:
        rep = misra_report(fdi_design(load_model(name)))
        models[name] = rep["files"]
        print(f"{name}: {rep['violations']} violations, undeviated {rep['undeviated']}")
    write_text(BASELINE, json.dumps({"cppcheck": version, "models": models}, indent=1,
                                    sort_keys=True) + "\n")
    print(f"wrote {BASELINE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

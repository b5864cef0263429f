#!/usr/bin/env python3
"""Write the derived residuals' keys beside thresholds that are known to be theirs.

Usage: python scripts/residual_keys.py MODEL.toml [MODEL.toml ...]

``fdigen tune --write`` writes ``[fdi.residual_keys]`` (what each derived residual is,
``fdigen.design.residual_identity``) with the thresholds it designs. A model file whose
thresholds were tuned before keys existed loads with a warning naming its unkeyed derived
residuals. When you know its thresholds were tuned for the residuals this fdigen derives
(the built-in models: their thresholds are checked by the test suite against this
design), this script records the keys, with the same code path as ``tune --write``
(``fdigen.tune.model_update.updated_model_text``), thresholds unchanged. Otherwise run
``fdigen tune --model FILE --write``. Keys already in the file are replaced (a change of
fdigen that only changes how a residual is described, not what it is, is re-keyed so).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path


def main(paths) -> int:
    from fdigen.design.cache import cached_design
    from fdigen.design.residual_identity import residual_keys
    from fdigen.files.atomic import write_text
    from fdigen.model.model_file import load_model
    from fdigen.tune.model_update import updated_model_text

    for name in paths:
        path = Path(name)
        model = load_model(path)     # the keys it has are replaced, not checked
        model = dataclasses.replace(model, fdi={k: v for k, v in model.fdi.items()
                                                if k != "residual_keys"})
        design = cached_design(model)
        keys = residual_keys(design.extra_residuals)
        thresholds = {n: design.config.thresholds[n] for n in design.residual_names
                      if n in design.config.thresholds}
        old = path.read_text()
        new = updated_model_text(old, thresholds, keys=keys)
        if new != old:
            write_text(path, new)
        print(f"{path}: " + (", ".join(f"{n} = {k!r}" for n, k in keys.items()) or
                             "no derived residual"))
    return 0


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    sys.exit(main(sys.argv[1:]))

"""The text view of an output-error discovery.

It reads :func:`fdigen.discover.output_loop.run_output_loop`'s dict: the calibration, the
effects taken, the free-run error before and after in units of the sensors' noise, the
validation log's, the verdict and the warnings.
"""

from __future__ import annotations


def text_report(r: dict) -> str:
    """Plain-text summary of an output-error discovery (``run_output_loop``'s dict)."""
    lines = [f"log {r['log']}: {r['reason']}; calibrated by output error over the whole "
             "log (free-run, initial states estimated)"]
    def pm(std):
        return "(held at its datasheet value)" if std is None else f"+- {std:.2g}"

    lines.append("calibrated (nominal model): " + ", ".join(
        f"{k} = {v:.6g} {pm(r['calibrated_std'].get(k))}" for k, v in r["calibrated"].items()))
    lines.append(r["message"])
    for k, v in r["parameters"].items():
        lines.append(f"  {k} = {v:.6g} {pm(r['uncertainty'].get(k))}")
    lines.append("free-run output error RMS (whole log): datasheet / calibrated -> with "
                 "effects (x sensor noise)")
    for k in r["error_before"]:
        lines.append(f"  {k:4s} {r['error_nominal'][k]:.4g} / {r['error_before'][k]:.4g} -> "
                     f"{r['error_after'][k]:.4g} ({r['noise_ratio_after'][k]:.3g}x noise "
                     f"{r['noise'][k]:.3g})")
    lines.extend(validation_lines(r.get("validation")))
    lines.append(r["verdict"])
    for w in r.get("warnings", []):
        lines.append(f"warning: {w}")
    for key, label in (("model_file", "augmented model"), ("build", "generated code"),
                       ("calibrated_model_file", "calibrated model"), ("plot", "plot")):
        if r.get(key):
            lines.append(f"{label}: {r[key]}")
    return "\n".join(lines)


def validation_lines(v) -> list[str]:
    """The lines of a report's second log (``--validate``): its free-run RMS before and
    after, per output; none without one."""
    if not isinstance(v, dict):
        return []
    return ([f"validation log {v['log']} (free-run RMS, initial state estimated): "
             "before -> after"]
            + [f"  {k:4s} {v['error_before'][k]:.4g} -> {v['error_after'][k]:.4g}"
               for k in v["error_before"]])

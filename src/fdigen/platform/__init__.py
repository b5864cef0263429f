"""The Stewart-Gough platform: six identical pneumatic legs, one FDI bank, a supervisor.

The FDI is designed once for one cylinder (``fdigen.models/pneumatic_cylinder.toml``); the
platform runs six copies of it, one per leg, and a supervisory layer on top:

* :mod:`~fdigen.platform.geometry` -- the 6-6 platform: joint positions, inverse (and
  forward) kinematics, the stroke check;
* :mod:`~fdigen.platform.demands` -- the paper's sequence of motions (surge, sway, heave,
  roll, pitch, yaw in turn) as smooth pose trajectories and leg demands;
* :mod:`~fdigen.platform.simulate` -- six closed-loop legs, each with its own controller,
  sensor noise and faults, with the FDI bank and the supervisor in the loop;
* :mod:`~fdigen.platform.supervisor` -- the supervisory logic (reference implementation):
  per-leg decisions, accommodation on the leg, the safety sequence to the rest pose;
* :mod:`~fdigen.platform.codegen` -- the same logic as one generated C99 step for the
  whole bank, ``<model>_platform_step``, calling the single-leg ``<model>_fdi_step``.

Nothing here runs on import.
"""

from fdigen.platform.geometry import (DOF_NAMES, PlatformGeometry, ReachabilityError,
                                      default_geometry, rotation_matrix)

__all__ = ["DOF_NAMES", "PlatformGeometry", "ReachabilityError", "default_geometry",
           "rotation_matrix"]

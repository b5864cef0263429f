"""The ``fdigen platform`` group: the six-leg Stewart-Gough platform.

Its commands ``ik``, ``simulate``, ``detect``, ``report`` and ``build``; ``simulate``,
``detect`` and ``report`` share their runners with ``fdigen simulate/detect/report
--platform`` (:mod:`fdigen.cli.platform_common`).
"""

from __future__ import annotations

import json

import click


from fdigen.cli.errors import echo
from fdigen.cli.parsing import _parse_pose
from fdigen.cli.platform_common import (_BANK_OPTION, _FORCE_OPTION, _GEOMETRY_OPTION,
                                        _PER_LEG_OPTION, _SAFETY_OPTION, _SEGMENT_OPTION,
                                        _check_safety, _platform_geometry,
                                        _run_platform_detect,
                                        _run_platform_report, _run_platform_simulate)
from fdigen.cli.types import POSITIVE_SECONDS


# -- the Stewart-Gough platform: six legs, one FDI bank, supervisory safety ------------------
@click.group()
def platform():
    """The Stewart-Gough platform: six legs, one FDI bank, supervisory safety.

    Every leg is the single-cylinder model with its own FDI; a supervisor accommodates a
    sensor fault on its leg and takes the platform to its rest pose on a pneumatic or
    actuator fault, naming the leg.
    """


@platform.command("ik")
@click.option("--pose", required=True,
              help="surge,sway,heave,roll,pitch,yaw relative to home (m, rad).")
@click.option("--degrees", is_flag=True, help="Angles of --pose in degrees.")
@_GEOMETRY_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def platform_ik(pose, degrees, geometry, as_json):
    """Inverse kinematics: leg lengths and piston positions of a pose (exit 2 if out of reach)."""
    from fdigen.platform.geometry import DOF_NAMES, ROTATION_CONVENTION

    geo = _platform_geometry(geometry)
    q = _parse_pose(pose, degrees)
    x = geo.check_reachable(q)
    lengths = geo.leg_lengths(q)
    if as_json:
        echo(json.dumps({"pose": dict(zip(DOF_NAMES, q.tolist())),
                         "geometry": geo.to_dict(),
                         "leg_lengths": lengths.tolist(),
                         "piston_positions": x.tolist(),
                         "stroke_use_percent": (x / geo.stroke * 100).tolist()},
                        indent=1))
        return
    echo(f"pose relative to home; {ROTATION_CONVENTION}")
    echo("leg  base joint a_i [m]           top joint b_i [m]            "
         "length [m]  piston [mm]")
    for i in range(6):
        a, b = geo.base[i], geo.top[i]
        echo(f"{i + 1:3d}  ({a[0]:+.4f}, {a[1]:+.4f}, {a[2]:+.4f})  "
             f"({b[0]:+.4f}, {b[1]:+.4f}, {b[2]:+.4f})  {lengths[i]:10.5f}  "
             f"{x[i] * 1e3:10.2f}")
    echo(f"stroke 0..{geo.stroke * 1e3:.0f} mm, l_min {geo.l_min} m, "
         f"home height {geo.home_height:.5f} m")


@platform.command("simulate")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              help="Folder to write leg1.csv..leg6.csv, pose_demand.csv and truth.json to.")
@click.option("--fault", "faults", multiple=True,
              help="Fault on a leg: LEG:NAME@T0=SIZE, LEG:NAME@T0=RATE/s or "
                   "LEG:NAME@T0=stuck (LEG 1..6).")
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--duration", default=None, type=POSITIVE_SECONDS,
              help="Seconds [default: one pass of the motion sequence].")
@_SEGMENT_OPTION
@click.option("--seed", default=0, show_default=True)
@click.option("--no-noise", is_flag=True, help="Noise-free sensors.")
@_BANK_OPTION
@_GEOMETRY_OPTION
@_SAFETY_OPTION
@_FORCE_OPTION
def platform_simulate(output, faults, model, duration, segment, seed, no_noise, bank,
                      geometry, safety_duration, force):
    """Simulate the six legs through the paper's motion sequence, with faults on any leg
    (the same as `fdigen simulate --platform`)."""
    _run_platform_simulate(output, faults, model, duration, segment, seed, no_noise, bank,
                           geometry, safety_duration, force)


@platform.command("detect")
@click.argument("folder", type=click.Path(file_okay=False))
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--backend", default="auto", show_default=True,
              type=click.Choice(["auto", "c", "casadi", "reference"]))
@_GEOMETRY_OPTION
@_SAFETY_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print the decision as JSON.")
def platform_detect(folder, model, backend, geometry, safety_duration, as_json):
    """Run the FDI of every leg over FOLDER's leg logs and the supervisor over them
    (the same as `fdigen detect --platform`)."""
    _run_platform_detect(folder, model, backend, geometry, safety_duration, as_json)


@platform.command("report")
@click.argument("folder", type=click.Path(file_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Overview figure (.png) of the six legs' decisions; each leg's residual "
                   "report goes beside it as <name>_leg<i>.png.")
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--backend", default="auto", show_default=True,
              type=click.Choice(["auto", "c", "casadi", "reference"]))
@_PER_LEG_OPTION
@_GEOMETRY_OPTION
@_SAFETY_OPTION
@_FORCE_OPTION
def platform_report(folder, output, model, backend, per_leg, geometry, safety_duration, force):
    """Draw the six legs' demands, positions and decisions, and each leg's residuals
    (the same as `fdigen report --platform`)."""
    _run_platform_report(folder, output, model, backend, per_leg, geometry, safety_duration,
                         force)


@platform.command("build")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              help="Folder for <model>_fdi.{h,c} and <model>_platform_fdi.{h,c}.")
@click.option("--model", "model", default=None, help="Model file or built-in model name.")
@click.option("--float-type", "float_type", default="double", show_default=True,
              type=click.Choice(["double", "float"]))
@_GEOMETRY_OPTION
@_SAFETY_OPTION
@click.option("--force", is_flag=True,
              help="Overwrite files of the same names in the folder that fdigen did not "
                   "write.")
def platform_build(output, model, float_type, geometry, safety_duration, force):
    """Generate the C99 platform bank: <model>_platform_step() over the six legs."""
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path
    from fdigen.platform.codegen import write_platform_sources

    from fdigen.files.outputs import check_output_folder

    check_output_folder(output, "-o")
    m = load_model(resolve_model_path(model))
    _check_safety(m, safety_duration, float_type)   # a normal number of the real type
    design = cached_design(m)
    files = write_platform_sources(design, output, geometry=_platform_geometry(geometry),
                                   safety_duration=safety_duration, float_type=float_type,
                                   force=force)
    echo(f"wrote {len(files)} files to {output}: " + ", ".join(f.name for f in files))

"""A platform run's folder, written whole: ``leg1.csv`` .. ``leg6.csv``,
``pose_demand.csv`` and ``truth.json``, swapped into place in one step so that a reader
(or a run killed midway) never sees two runs mixed (attack round 13)."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import stat
from pathlib import Path

from fdigen.errors import FdigenError
from fdigen.files.atomic import write_text
from fdigen.platform.geometry import DOF_NAMES, NLEGS


#: The files of a platform run folder, and nothing else: the folder is written whole.
RUN_FILES = tuple(f"leg{i}.csv" for i in range(1, NLEGS + 1)) + ("pose_demand.csv",
                                                                  "truth.json")


def is_run_folder(path) -> bool:
    """Whether ``path`` holds a complete platform run fdigen wrote: exactly
    :data:`RUN_FILES`, regular files, and fdigen's ground truth."""
    from fdigen.files.outputs import is_fdigen_truth

    try:
        entries = list(os.scandir(path))
    except OSError:
        return False
    return ({e.name for e in entries} == set(RUN_FILES)
            and all(e.is_file(follow_symlinks=False) for e in entries)
            and is_fdigen_truth(Path(path) / "truth.json"))


def check_run_folder(folder, option: str = "-o", force: bool = False) -> Path:
    """The folder a platform run replaces (symbolic links followed), checked before the
    simulation and again before the swap.

    A run is written as a whole folder, swapped into place in one step
    (:func:`write_platform_logs`), so the folder may hold nothing but a run's files:

    Raises
    ------
    OutputPathError
        If ``folder`` exists and is not a folder, holds anything but :data:`RUN_FILES`
        as regular files (a user's files, a subfolder, a link: never replaced, ``force``
        or not), holds a run's files beside a ground truth fdigen did not write (unless
        ``force``: :func:`fdigen.files.outputs.check_sidecars`), or is the current
        folder; or if its parent folder is not writable.
    """
    from fdigen.files.outputs import OutputPathError, check_output_folder, check_sidecars

    target = Path(os.path.realpath(folder))
    if os.path.lexists(target):
        if not target.is_dir():
            raise OutputPathError(f"{option} {folder}: exists and is not a folder")
        check_sidecars([target / n for n in RUN_FILES], target / "truth.json",
                       f"{option} {folder}", force)
        try:
            entries = list(os.scandir(target))
        except OSError as exc:
            raise OutputPathError(f"{option} {folder}: cannot list it "
                                  f"({exc.strerror or exc})") from None
        foreign = sorted(e.name for e in entries
                         if e.name not in RUN_FILES or not e.is_file(follow_symlinks=False))
        if foreign:
            shown = ", ".join(foreign[:4]) + (", ..." if len(foreign) > 4 else "")
            raise OutputPathError(
                f"{option} {folder}: holds {shown}, which a platform run does not write: "
                "a run replaces its whole folder in one step (a reader never sees two runs "
                "mixed), and fdigen never replaces a folder holding files it did not "
                "write; choose a new or empty folder, or move them")
        if target == Path(os.path.realpath(os.getcwd())):
            raise OutputPathError(f"{option} {folder}: is the current folder; a run "
                                  "replaces its whole folder: name it from its parent")
    check_output_folder(target.parent, option)   # the new folder is written beside it
    return target


@contextlib.contextmanager
def _folder_lock(folder: Path):
    """An exclusive ``flock`` on the folder itself (no lock file left in a user's
    folder): one run at a time replaces a folder there, and recovers the leftovers of
    one killed midway."""
    import fcntl

    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def write_platform_logs(run: PlatformRun, folder: str | Path, summary: dict | None = None,
                        *, force: bool = False, option: str = "-o") -> list[Path]:
    """Write ``leg1.csv`` .. ``leg6.csv`` (rig format), ``pose_demand.csv`` and
    ``truth.json`` as the folder ``folder`` (created if needed), in one step.

    The files are written into a hidden folder beside it (``.<name>-<random>``), which is
    then swapped with ``folder`` atomically (:func:`fdigen.files.folder_swap.
    replace_folder`): a reader, or a run killed at any moment (SIGKILL), sees the old run
    or the new one, never legs of two runs (attack round 13: new truth.json and legs 1-3
    beside old legs 4-6, which ``platform detect`` read without a word). The leftovers of
    a run killed midway are removed by the next one. ``folder`` may hold only an earlier
    run's files (:func:`check_run_folder`: never a folder with files fdigen did not
    write; run files beside a ground truth fdigen did not write only with ``force``).

    ``truth.json`` holds what a real platform's logs would not: the injected faults per
    leg, the plant parameters, the seed, the geometry and motion, the online bank's
    decision (``summary``, if given; non-finite numbers as ``null``) and the SHA-256 of
    each log (``log_sha256``). Tools must not need it.
    """
    import shutil
    import tempfile

    from fdigen.files.folder_swap import TMP_MARK, recover_folder, replace_folder
    from fdigen.platform.supervisor import finite_json
    from fdigen.sim.log import write_log

    folder = Path(folder)
    target = check_run_folder(folder, option, force)
    parent = target.parent
    parent.mkdir(parents=True, exist_ok=True)
    with _folder_lock(parent):
        recover_folder(parent, target.name, is_run_folder)   # a run killed midway
        check_run_folder(folder, option, force)             # again, under the lock
        if target.is_dir():
            mode = stat.S_IMODE(os.stat(target).st_mode)
        else:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o777 & ~umask
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}-", dir=parent))
        try:
            (tmp / TMP_MARK).write_text(f"{os.getpid()}\n")   # fdigen's: removable
            hashes = {}
            for leg in range(1, NLEGS + 1):
                name = f"leg{leg}.csv"
                write_log(tmp / name, run.leg_columns(leg))
                hashes[name] = hashlib.sha256((tmp / name).read_bytes()).hexdigest()
            pose_cols = {"t": run.t}
            pose_cols.update({name: run.pose[:, j] for j, name in enumerate(DOF_NAMES)})
            write_log(tmp / "pose_demand.csv", pose_cols)
            hashes["pose_demand.csv"] = hashlib.sha256(
                (tmp / "pose_demand.csv").read_bytes()).hexdigest()
            truth = {"case": folder.name or target.name,
                     "sample_time": float(run.t[1] - run.t[0]),
                     "model": run.model.name, "seed": run.seed, "noise": run.noise,
                     "legs": NLEGS, "geometry": run.geometry.to_dict(),
                     "motion": run.motion.to_dict(),
                     "truth": {"parameters": [dict(v) for v in run.parameters],
                               "faults": [f.to_dict() for f in run.faults]}}
            if summary is not None:
                truth["online_decision"] = summary
            truth["log_sha256"] = hashes
            write_text(tmp / "truth.json",
                       json.dumps(finite_json(truth), indent=1, allow_nan=False) + "\n")
            os.chmod(tmp, mode)
            replace_folder(tmp, target)     # one atomic exchange where the system can
        except OSError as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            raise FdigenError(f"{option} {folder}: cannot write the run "
                              f"({exc.strerror or exc}); {folder} is unchanged") from None
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return [folder / name for name in RUN_FILES]

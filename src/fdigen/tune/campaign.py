"""Executing campaigns: :class:`CampaignExecutor` runs cases on Dask or in-process.

Holds the executor (a :class:`distributed.LocalCluster`, an existing scheduler or the
synchronous in-process runner, with a rich progress bar) and :func:`_warm`, run on every
worker to compile the design's core before the timed runs. Dask is imported lazily.

Interruptions and bad addresses: the local workers ignore Ctrl-C from birth
(:func:`start_quiet_forkserver`) while this process never does, and are killed after it
(:func:`_stop_local_cluster_now`); a scheduler address is probed within a timeout
(:func:`_connect`) before Dask's client, whose handshake can wait forever.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import threading

from fdigen.errors import FdigenError
from fdigen.tune.runs import _runner, run_case


def start_quiet_forkserver() -> None:
    """Make the local workers deaf to Ctrl-C from birth, without ever ignoring it here.

    The terminal sends Ctrl-C (SIGINT) to its whole process group, the workers included;
    a worker that takes it prints a traceback. The workers are forked by
    multiprocessing's *forkserver* (``distributed.worker.multiprocessing-method``), whose
    first preload module :mod:`fdigen.worker_signals` makes it ignore SIGINT before it
    records the dispositions its children inherit: every worker ignores SIGINT, while
    this process handles it as usual during the whole campaign, cluster start included
    (ignoring SIGINT here during the start, as before, lost a Ctrl-C: the campaign ran on
    and wrote its result). The forkserver's standard error is /dev/null: a worker still
    starting when Ctrl-C stops this process would print a traceback there (task errors
    come back to this process as results, a lost worker through Dask's client;
    ``FDIGEN_DEBUG=1`` keeps it)."""
    import multiprocessing.forkserver
    import os
    import sys

    import dask

    from distributed.utils import get_mp_context

    dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"})
    ctx = get_mp_context()
    server = multiprocessing.forkserver._forkserver
    if server._forkserver_pid is not None:      # already running (an earlier campaign)
        return
    preload = [m for m in server._preload_modules if m != "__main__"]
    ctx.set_forkserver_preload(["fdigen.worker_signals", *preload])
    if os.environ.get("FDIGEN_DEBUG"):          # the workers' tracebacks wanted
        multiprocessing.forkserver.ensure_running()
        return
    err = os.dup(2)
    try:
        sys.stderr.flush()
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
        multiprocessing.forkserver.ensure_running()
    finally:
        os.dup2(err, 2)
        os.close(err)


@contextlib.contextmanager
def _ctrl_c_flag():
    """Ctrl-C raises ``KeyboardInterrupt`` as usual and also sets the yielded event. The
    interrupt can land in code where Python swallows exceptions (Dask's garbage-collector
    callback, a destructor): the campaign ran on then, and wrote its result. There the
    handler only sets the event, and the campaign loop, which checks it at every
    finished run, stops."""
    event = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield event
        return

    def handler(signum, frame):
        event.set()
        if not _in_swallowing_code(frame):
            raise KeyboardInterrupt

    old = signal.signal(signal.SIGINT, handler)
    try:
        yield event
    finally:
        signal.signal(signal.SIGINT, old)


def _in_swallowing_code(frame) -> bool:
    """Whether ``frame`` runs where Python swallows exceptions with an "Exception
    ignored" traceback: a garbage-collector callback (Dask's GC diagnosis) or a
    destructor. Ctrl-C then only sets the flag; the campaign loop stops on it."""
    for _ in range(4):
        if frame is None:
            return False
        if frame.f_code.co_name in ("_gc_callback", "__del__"):
            return True
        frame = frame.f_back
    return False


def _stop_local_cluster_now() -> None:
    """After Ctrl-C: kill the local workers (SIGKILL: a worker still starting would print
    a traceback when its parent goes away) and drop Dask's exit-time cluster shutdown
    (it asserts on a half-started cluster, also with a traceback). A campaign's results
    live in this process: nothing is lost."""
    import atexit
    import os

    try:
        from distributed.deploy import spec

        atexit.unregister(spec.close_clusters)
    except ImportError:
        pass
    import multiprocessing.forkserver

    server = getattr(getattr(multiprocessing.forkserver, "_forkserver", None),
                     "_forkserver_pid", None)
    if server is None:
        return
    for pid in _children(server):
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


def _children(parent: int) -> list[int]:
    """Process ids whose parent is ``parent`` (from ``/proc``)."""
    from pathlib import Path

    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if fields[1] == str(parent):          # field 4 of stat: the parent's id
            out.append(int(stat.parent.name))
    return out


def _quiet_distributed() -> None:
    """Silence Dask's loggers (the scheduler logs lost keys and closed comms, with
    tracebacks, when a campaign is stopped midway)."""
    import logging

    names = ["distributed"] + [n for n in logging.root.manager.loggerDict
                               if n.startswith("distributed.")]
    for name in names:
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


def _route_plugin():
    """A worker plugin running :func:`fdigen.library_log.route_library_output` on every
    worker (defined here: Dask is imported lazily)."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class RouteLibraryOutput(WorkerPlugin):
        name = "fdigen-route-library-output"

        def setup(self, worker):
            from fdigen.library_log import route_library_output

            route_library_output()

    return RouteLibraryOutput()
#: Seconds to reach a Dask scheduler (``$FDIGEN_CONNECT_TIMEOUT`` overrides).
CONNECT_TIMEOUT = 20.0


def _connect(client_class, address: str):
    """A Dask client of the scheduler at ``address``, or :class:`FdigenError` naming the
    address within :data:`CONNECT_TIMEOUT` seconds (a closed port, a listener that never
    answers or one that does not speak Dask's protocol, a bad address)."""
    import os

    timeout = float(os.environ.get("FDIGEN_CONNECT_TIMEOUT", CONNECT_TIMEOUT))
    _quiet_distributed()
    try:
        asyncio.run(asyncio.wait_for(_identity(address, timeout), timeout))
        return client_class(address, timeout=timeout)
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:   # OSError, TimeoutError, ValueError, protocol errors
        reason = str(exc).splitlines()[0][:300] if str(exc) else type(exc).__name__
        raise FdigenError(f"--scheduler {address}: cannot reach a Dask scheduler there "
                          f"within {timeout:g} s ({type(exc).__name__}: {reason})") from None


async def _identity(address: str, timeout: float) -> None:
    """Connect to ``address`` and ask who it is (Dask's ``identity``): a listener that
    accepts and never answers would block the Dask client's handshake forever."""
    from distributed.comm import connect

    comm = await connect(address, timeout=timeout)
    try:
        await comm.write({"op": "identity", "reply": True})
        who = await comm.read()
    finally:
        comm.abort()
    if not isinstance(who, dict) or who.get("type") != "Scheduler":
        raise ConnectionError(f"the peer is not a Dask scheduler ({str(who)[:80]})")


class CampaignExecutor:
    """Runs cases on Dask (a :class:`distributed.LocalCluster` or an existing scheduler)
    or in-process (``scheduler="synchronous"``), with a rich progress bar.

    Parameters
    ----------
    workers : int
        Worker processes of the local cluster (one thread each).
    scheduler : str, optional
        ``None``: start a local cluster; ``"synchronous"``: run in this process; otherwise
        the address of a running Dask scheduler (``tcp://host:8786``), whose workers need
        fdigen (same version) and a C compiler.
    progress : bool
        Show a progress bar (on stderr).
    """

    def __init__(self, workers: int = 2, scheduler: str | None = None, progress: bool = True):
        self.workers = int(workers)
        self.scheduler = scheduler
        self.progress = progress
        self.client = None
        self.cluster = None
        self._ctrl_c = None
        self.interrupted = None

    def __enter__(self):
        if self.scheduler == "synchronous":
            return self
        import logging

        from distributed import Client, LocalCluster

        from fdigen.design.stored_minmax import pickle_minmax_as_stored
        from fdigen.library_log import reroute_if_active

        pickle_minmax_as_stored()      # designs sent to the workers load without re-reducing
        routed = reroute_if_active()   # distributed adds its own stderr handler at import
        self._ctrl_c = _ctrl_c_flag()
        self.interrupted = self._ctrl_c.__enter__()
        try:
            if self.scheduler:
                self.client = _connect(Client, self.scheduler)
            else:
                start_quiet_forkserver()
                # no dashboard; the scheduler's HTTP server (health, metrics) on a free
                # loopback port: never "Port 8787 is already in use" when another
                # cluster runs, never listening beyond this machine
                self.cluster = LocalCluster(
                    n_workers=self.workers, threads_per_worker=1, processes=True,
                    host="127.0.0.1", dashboard_address=None,
                    scheduler_kwargs={"dashboard": False,
                                      "dashboard_address": "127.0.0.1:0"},
                    silence_logs=logging.ERROR)
                self.client = Client(self.cluster)
            if routed:    # the workers' (and restarted workers') warnings: to the log too
                self.client.register_plugin(_route_plugin())
            self._check_interrupt()
        except BaseException as exc:   # Ctrl-C during the start: stop what was started
            self.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self

    def _check_interrupt(self) -> None:
        """Raise ``KeyboardInterrupt`` if Ctrl-C was pressed (and swallowed on its way)."""
        if self.interrupted is not None and self.interrupted.is_set():
            raise KeyboardInterrupt

    def __exit__(self, exc_type=None, *exc):
        if self._ctrl_c is not None:
            self._ctrl_c.__exit__(None, None, None)
            self._ctrl_c = None
        interrupted = exc_type is not None and issubclass(exc_type, KeyboardInterrupt)
        if exc_type is not None:
            _quiet_distributed()   # interrupted: the teardown's complaints are no news
        if interrupted and self.scheduler is None:
            _stop_local_cluster_now()
            self.client = self.cluster = None
            return
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None

    @property
    def description(self) -> str:
        if self.client is None:
            return "synchronous (in-process)"
        if self.cluster is not None:
            return f"LocalCluster, {self.workers} worker processes x 1 thread"
        return f"scheduler {self.scheduler}"

    def warm_up(self, design):
        """Import fdigen and compile ``design``'s core on every worker (not timed)."""
        if self.client is None:
            _runner(design)
            return
        self.client.run(_warm, design)
        self._check_interrupt()

    def map(self, fn, items) -> list:
        """``[fn(*args) for args in items]``, on the workers when there are some (``fn``
        a module-level function, its arguments picklable); results in order."""
        if self.client is None:
            return [fn(*args) for args in items]
        futures = [self.client.submit(fn, *args, pure=False) for args in items]
        out = []
        for fut in futures:
            self._check_interrupt()
            out.append(fut.result())
            fut.release()
        return out

    def run(self, design, cases, settle_samples: int, label: str = "runs") -> list[dict]:
        """Run ``cases`` against ``design``; results in case order."""
        if not cases:
            return []
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                   TimeElapsedColumn, TimeRemainingColumn)

        from fdigen.console import console

        bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                       TimeElapsedColumn(), TimeRemainingColumn(),
                       console=console(stderr=True), disable=not self.progress,
                       transient=False)
        results = []
        with bar:
            task = bar.add_task(label, total=len(cases))
            if self.client is None:
                for case in cases:
                    results.append(run_case(design, case, settle_samples))
                    bar.advance(task)
            else:
                from distributed import as_completed

                dfut = self.client.scatter(design, broadcast=True, hash=False)
                futures = [self.client.submit(run_case, dfut, c, settle_samples, pure=False)
                           for c in cases]
                for fut in as_completed(futures):
                    self._check_interrupt()
                    results.append(fut.result())
                    fut.release()
                    bar.advance(task)
        errors = [r for r in results if "error" in r]
        if errors:
            e = errors[0]
            raise FdigenError(f"{len(errors)} of {len(cases)} {label} failed; first: "
                              f"{e['kind']} run {e['index']}: {e['error']}")
        results.sort(key=lambda r: r["index"])
        return results


def _warm(design, dask_worker=None):
    _runner(design)
    return True

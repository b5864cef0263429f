"""Imported first by the forkserver that forks ``fdigen tune``'s local Dask workers.

The terminal sends Ctrl-C (SIGINT) to its whole process group, the workers included: a
worker that takes it prints a traceback while the driver stops the campaign anyway.
Importing this module makes the importing process ignore SIGINT; multiprocessing's
forkserver imports it (its first preload module, see
:func:`fdigen.tune.campaign.start_quiet_forkserver`) before it records the signal
dispositions its children get, so every worker it forks ignores SIGINT from birth.
The driver itself never ignores SIGINT. A module of its own, at the top of the package,
so that the import is light and early.
"""

import signal
import threading

if threading.current_thread() is threading.main_thread():
    signal.signal(signal.SIGINT, signal.SIG_IGN)

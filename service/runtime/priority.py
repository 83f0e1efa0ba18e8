"""Scheduling priority of the service's threads: Linux niceness, best effort.

On a lab PC the emergency stop's path competes for the cores with the service's own bulk work and
with every other program. The kernel schedules a thread of lower niceness first, so each kind of
thread sets its own: the bench engine process highest, the web process's stop thread next, jobs
as any program, bulk downloads and imports last. The web event loop keeps the default: threads
inherit their creator's niceness, and the request threads it starts run long sync routes (a
diagnosis takes seconds), which must not outrank other programs.

A thread may always lower its own priority. Raising it above 0 needs CAP_SYS_NICE (or root: a
systemd unit can grant it with ``AmbientCapabilities=CAP_SYS_NICE``); without it the thread keeps
the default priority and the log says so once.
"""

from __future__ import annotations

import logging
import os
import threading

log = logging.getLogger("evcbench.priority")

#: the bench engine process (its loop, watchdog and stop thread)
ENGINE_NICE = -10
#: the web process's emergency-stop thread, which carries the stop to the engine
SAFETY_NICE = -5
#: job threads (fits, plans) and request threads: as any program
WORK_NICE = 0
#: downloads and imports (service.runtime.bulk)
BULK_NICE = 10

_refused_once = threading.Event()


def set_thread_nice(nice: int) -> bool:
    """Set the calling thread's niceness (threads created by it afterwards inherit it); False where
    the kernel refuses (raising it needs CAP_SYS_NICE) or the OS has no per-thread niceness."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)
        return True
    except (OSError, AttributeError) as exc:
        if not _refused_once.is_set():
            _refused_once.set()
            log.info("thread priority %+d refused (%s): this thread keeps its priority", nice, exc)
        return False

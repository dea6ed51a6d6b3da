"""Quiet event-loop logs when a sweep is interrupted.

When Ctrl-C or SIGTERM cuts a Dask computation short, distributed's client, its tornado event loop
and asyncio log the callbacks the interrupt cut short, with tracebacks. One of them, the clean-up
that distributed's ``sync`` schedules when the interrupt reaches it, runs on the loop's thread
before any ``except`` in the main thread does. So the loggers are silenced in the signal handler
itself, before the interrupt is raised; the command then says in one line what happened.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal

NOISY = ("distributed", "tornado", "asyncio")  # the loggers of the client and its event loop


def silence() -> None:
    """Silence the client's and its event loop's loggers, and their children, for good."""
    for name in [*NOISY, *(n for n in logging.root.manager.loggerDict if n.startswith(NOISY))]:
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)  # the scheduler logs a lost comm as critical


@contextlib.contextmanager
def quiet_on_interrupt():
    """While the block runs, SIGINT and SIGTERM first :func:`silence` the loggers and then act as
    the handler before them did (Ctrl-C's KeyboardInterrupt, the command line's SIGTERM). Outside
    the main thread, where no handler can be set, nothing changes."""
    installed = {}
    for number in (signal.SIGINT, signal.SIGTERM):
        previous = signal.getsignal(number)

        def handler(signum, frame, previous=previous):
            silence()
            if callable(previous):
                previous(signum, frame)
            else:  # the default: let it act as it would have
                signal.signal(signum, previous if previous is not None else signal.SIG_DFL)
                os.kill(os.getpid(), signum)

        try:
            installed[number] = signal.signal(number, handler)
        except ValueError:  # not the main thread
            break
    try:
        yield
    finally:
        for number, previous in installed.items():
            signal.signal(number, previous)

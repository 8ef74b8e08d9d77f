"""How a fleet process leaves once its work is closed: flush what it wrote, then exit at once.

Every ``fleet`` command (``fleet.cli.main.entry``) and every load-test worker process
(``python -m fleet.loadtest.worker``) has closed its Zenoh session, task book and files when
its ``main`` returns; what is left is the interpreter's finalization, which collects every
object and drops Zenoh's native ones. On the 2-core project machine that took 0.9-4.7 s after
Ctrl-C (longer under load), so a process whose peers had gone looked hung. :func:`exit_now`
skips it.
"""

from __future__ import annotations

import logging
import os
import sys
from typing import NoReturn


def exit_now(code: int) -> NoReturn:
    """Flush the log handlers (:func:`logging.shutdown`), stdout and stderr, then end the
    process with exit code ``code`` at once (:func:`os._exit`: no finalization, no ``atexit``
    hooks). Call it only when everything the process opened is closed. A closed pipe on
    stdout or stderr is ignored (nothing more can reach it)."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)

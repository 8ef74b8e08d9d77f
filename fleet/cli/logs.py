"""Logging of the ``fleet`` commands: ``--log-level`` (or the ``FLEET_LOG_LEVEL`` environment
variable) sets how much the project's loggers (``fleet.*``, ``nodes.*``, ``sim.*``) say.

Messages go to stderr, one line each: ``warning: <message>`` (with ``debug``: the time and
the logger's name too). They are written to whatever ``sys.stderr`` is when they are
emitted, so a live table on the terminal shows them above itself instead of being torn.
The default level is ``warning``.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Mapping

from fleet.errors import ConfigError

#: The levels ``--log-level`` accepts, quietest last.
LEVELS = ("debug", "info", "warning", "error", "critical")
#: The environment variable read when ``--log-level`` is not given.
ENV_VAR = "FLEET_LOG_LEVEL"
#: The loggers configured (the project's packages).
LOGGERS = ("fleet", "nodes", "sim")
DEFAULT_LEVEL = "warning"


def log_level(text: str) -> str:
    """argparse type of ``--log-level``: a level name, any case."""
    level = text.strip().lower()
    if level not in LEVELS:
        raise argparse.ArgumentTypeError(f"unknown level {text!r}; one of {', '.join(LEVELS)}")
    return level


def add_log_level(p: argparse.ArgumentParser, *, default: str | None = None) -> None:
    """Add ``--log-level LEVEL`` to ``p`` (``default=argparse.SUPPRESS`` on a subcommand keeps
    the value given before the command)."""
    p.add_argument(
        "--log-level",
        type=log_level,
        default=default,
        metavar="LEVEL",
        help=f"diagnostics on stderr: {', '.join(LEVELS)} (default: ${ENV_VAR} or {DEFAULT_LEVEL})",
    )


def resolve_level(arg: str | None, environ: Mapping[str, str] = os.environ) -> str:
    """The level to use: ``arg``, else ``$FLEET_LOG_LEVEL``, else ``warning``. Raises
    :class:`~fleet.errors.ConfigError` (``environment: FLEET_LOG_LEVEL: ...``) for an unknown
    level in the environment."""
    if arg is not None:
        return log_level(arg)
    env = environ.get(ENV_VAR, "").strip()
    if not env:
        return DEFAULT_LEVEL
    try:
        return log_level(env)
    except argparse.ArgumentTypeError as e:
        raise ConfigError("environment", ENV_VAR, str(e)) from None


class _StderrHandler(logging.Handler):
    """Writes each record to the current ``sys.stderr`` (looked up at every message)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(self.format(record) + "\n")
            sys.stderr.flush()
        except Exception:  # noqa: BLE001 - logging must never raise
            self.handleError(record)


class _Formatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        record.levelname_lower = record.levelname.lower()
        return super().format(record)


def configure_logging(level: str) -> None:
    """Send the project's loggers to stderr at ``level`` (one of :data:`LEVELS`); calling it
    again replaces the previous configuration."""
    lvl = getattr(logging, level.upper())
    fmt = (
        "%(asctime)s %(levelname_lower)s %(name)s: %(message)s"
        if lvl <= logging.DEBUG
        else "%(levelname_lower)s: %(message)s"
    )
    handler = _StderrHandler()
    handler.setFormatter(_Formatter(fmt))
    for name in LOGGERS:
        logger = logging.getLogger(name)
        for h in [h for h in logger.handlers if isinstance(h, _StderrHandler)]:
            logger.removeHandler(h)
        logger.addHandler(handler)
        logger.setLevel(lvl)

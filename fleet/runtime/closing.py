"""Closing many things where one failing must not keep the rest open."""

from __future__ import annotations

import logging
from collections.abc import Callable


def close_logged(close: Callable[[], None], what: str, log: logging.Logger) -> None:
    """Call ``close``; log (not raise) what goes wrong as ``"<what>: <error>"``, so the
    caller goes on closing the rest."""
    try:
        close()
    except Exception as e:  # noqa: BLE001 - keep closing the rest
        log.warning("%s: %s", what, e)

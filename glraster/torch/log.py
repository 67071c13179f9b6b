"""nvdiffrast's ``get_log_level`` / ``set_log_level`` over Python :mod:`logging`.

The level is an int with nvdiffrast's meaning: messages of this severity or higher are
printed. It is the level of the ``"glraster"`` logger (every glraster module logs to a
child of it), so ``logging`` configuration works too: 0 info (``logging.INFO``: an OpenGL
context made, a mip pyramid built), 1 warning (the default, ``logging.WARNING``: a mip
pyramid rebuilt because its texture changed), 2 error and 3 fatal (``logging.ERROR`` and
``CRITICAL``: nothing; glraster raises exceptions). A ``logging`` level in between reads
as the next int up (DEBUG reads 0, anything above CRITICAL 3).
"""

from __future__ import annotations

import logging
import numbers
import sys

LOGGER_NAME = "glraster"
LEVELS = (logging.INFO, logging.WARNING, logging.ERROR, logging.CRITICAL)


def get_log_level() -> int:
    """The current log level, 0 (info) .. 3 (fatal); see :func:`set_log_level`."""
    effective = logging.getLogger(LOGGER_NAME).getEffectiveLevel()
    return next((k for k, value in enumerate(LEVELS) if effective <= value), len(LEVELS) - 1)


def set_log_level(level: int) -> None:
    """Print glraster's messages of severity ``level`` or higher: 0 info, 1 warning (the
    default), 2 error, 3 fatal (nvdiffrast's convention): the ``"glraster"`` logger's
    level, with a handler writing to stderr (as nvdiffrast) when none would print them."""
    if isinstance(level, (bool, float)) or not isinstance(level, numbers.Integral) \
            or not 0 <= level < len(LEVELS):
        raise ValueError(f"level must be an int 0 (info), 1 (warning), 2 (error) or 3 "
                         f"(fatal), got {level!r}")
    logger = logging.getLogger(LOGGER_NAME)
    logger.setLevel(LEVELS[int(level)])
    if not logger.hasHandlers():
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(name)s %(levelname)s: %(message)s"))
        logger.addHandler(handler)

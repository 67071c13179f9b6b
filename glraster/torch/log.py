"""nvdiffrast's ``get_log_level`` / ``set_log_level``: :mod:`glraster.diff.log` (shared by
the front ends)."""

from glraster.diff.log import LOGGER_NAME, get_log_level, set_log_level

__all__ = ["LOGGER_NAME", "get_log_level", "set_log_level"]

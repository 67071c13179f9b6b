"""glraster.torch.get_log_level / set_log_level: nvdiffrast's int levels (0 info, 1 warning,
2 error, 3 fatal; default 1) as the level of the "glraster" logging logger."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

import glraster.torch as dr


@pytest.fixture
def glraster_logger():
    logger = logging.getLogger("glraster")
    level, handlers = logger.level, list(logger.handlers)
    yield logger
    logger.setLevel(level)
    logger.handlers[:] = handlers


def test_default_level_is_warning(glraster_logger):
    root = logging.getLogger()
    saved = root.level
    root.setLevel(logging.WARNING)              # logging's default
    glraster_logger.setLevel(logging.NOTSET)    # glraster's: inherit it
    try:
        assert dr.get_log_level() == 1
    finally:
        root.setLevel(saved)


@pytest.mark.parametrize("level, logging_level", [(0, logging.INFO), (1, logging.WARNING),
                                                  (2, logging.ERROR), (3, logging.CRITICAL)])
def test_set_log_level_sets_the_glraster_logger(glraster_logger, level, logging_level):
    dr.set_log_level(level)
    assert glraster_logger.level == logging_level
    assert dr.get_log_level() == level


def test_logging_levels_in_between_read_as_the_next_int(glraster_logger):
    for logging_level, level in [(logging.DEBUG, 0), (logging.INFO + 5, 1),
                                 (logging.ERROR + 1, 3), (logging.CRITICAL + 10, 3)]:
        glraster_logger.setLevel(logging_level)
        assert dr.get_log_level() == level


def test_messages_below_the_level_are_silent(glraster_logger, capsys):
    glraster_logger.handlers[:] = []
    glraster_logger.propagate = False             # no handler anywhere: set_log_level adds one
    try:
        tex = torch.rand(1, 4, 4, 1, dtype=torch.float64)
        dr.set_log_level(0)
        dr.texture_construct_mip(tex)
        err = capsys.readouterr().err
        assert "INFO: texture_construct_mip: 2 levels below the 4x4 base: 2x2, 1x1" in err
        dr.set_log_level(1)
        dr.texture_construct_mip(tex)
        assert capsys.readouterr().err == ""
        mip = dr.texture_construct_mip(tex)
        with torch.no_grad():
            tex.add_(1)
        dr.texture(tex, torch.rand(1, 2, 2, 2, dtype=torch.float64),
                   mip_level_bias=torch.ones(1, 2, 2, dtype=torch.float64), mip=mip)
        assert "WARNING: texture: mip= was built from another texture" in capsys.readouterr().err
        dr.set_log_level(2)
        with torch.no_grad():
            tex.add_(1)
        dr.texture(tex, torch.rand(1, 2, 2, 2, dtype=torch.float64),
                   mip_level_bias=torch.ones(1, 2, 2, dtype=torch.float64), mip=mip)
        assert capsys.readouterr().err == ""
        assert len(glraster_logger.handlers) == 1     # added once
    finally:
        glraster_logger.propagate = True


@pytest.mark.parametrize("level", [-1, 4, 1.0, True, "1", None, np.float32(1)])
def test_bad_level_raises_value_error_naming_the_argument(glraster_logger, level):
    with pytest.raises(ValueError, match="level must be an int 0"):
        dr.set_log_level(level)

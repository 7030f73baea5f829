"""Fixtures shared by the whole suite."""

import logging

import pytest


@pytest.fixture(autouse=True)
def _restore_lidar3d_logger():
    """``lidar3d.cli.main.main()`` installs its stderr handler on the 'lidar3d' logger and stops
    propagation; put the logger back after every test, so a later test neither writes to an earlier
    test's captured (closed) stderr nor sees its handler."""
    logger = logging.getLogger("lidar3d")
    saved = (logger.handlers[:], logger.level, logger.propagate)
    yield
    logger.handlers[:], logger.level, logger.propagate = saved

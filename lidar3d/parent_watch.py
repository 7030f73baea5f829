"""Queue calls for a child process that end when the process that started it is gone.

A child blocked in ``Queue.get`` or in ``Queue.put`` on a full queue waits forever once its parent
has died without ending it (``kill -9``, the out-of-memory killer, a crash in C code): an orphan
holding hundreds of MB. :func:`get_while_parent_lives` and :func:`put_while_parent_lives` wait in
steps of ``poll_s`` seconds and raise :class:`ParentGone` when the parent has ended, so the child can
return and exit (the prefetch and dense-map processes of a run).
"""

from __future__ import annotations

import multiprocessing
import queue as queue_module
from typing import Any

__all__ = ["ParentGone", "get_while_parent_lives", "put_while_parent_lives"]


class ParentGone(Exception):
    """The process that started this one has ended."""


def _check_parent() -> None:
    parent = multiprocessing.parent_process()  # None in a process no multiprocessing call started
    if parent is not None and not parent.is_alive():
        raise ParentGone


def get_while_parent_lives(source: Any, poll_s: float = 0.5) -> Any:
    """``source.get()`` (a multiprocessing queue), checking every ``poll_s`` s that the parent lives.

    Raises:
        ParentGone: the parent ended while this waited.
    """
    while True:
        try:
            return source.get(timeout=poll_s)
        except queue_module.Empty:
            _check_parent()


def put_while_parent_lives(target: Any, item: Any, poll_s: float = 0.5) -> None:
    """``target.put(item)`` (a bounded multiprocessing queue), checking every ``poll_s`` s while
    the queue is full that the parent lives.

    Raises:
        ParentGone: the parent ended while this waited.
    """
    while True:
        try:
            target.put(item, timeout=poll_s)
            return
        except queue_module.Full:
            _check_parent()

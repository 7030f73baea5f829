"""Ctrl-C (SIGINT) and SIGTERM around a run's child processes: held back where a stop half way
would lose work, ignored by the children, and a child that outlives its run.

A run has two children (:mod:`lidar3d.prefetch`, :mod:`lidar3d.map_process`). The run decides when
they stop, so they ignore both signals, also while they still import (:func:`start_child`: an
ignored signal stays ignored across ``exec``), and the run ends them with SIGKILL when it does not
need them any more. A child whose run has died without ending it (``kill -9``, the out-of-memory
killer) would wait on its queues for ever, holding hundreds of MB: :func:`as_child` starts a thread
that exits the child as soon as its parent is gone (``os._exit``: a queue's writer thread blocked on
a pipe nobody reads would hold up a normal exit).

In the command line's process, :func:`sigterm_as_interrupt` makes SIGTERM (``kill``, a job
scheduler, a container stopping) raise :class:`Terminated`, a ``KeyboardInterrupt``, so every
command stops on it as on Ctrl-C. In the run's process, :func:`deferred` holds both signals back
where a stop half way loses work (a map transfer cut in the middle leaves the rest in the pipe;
outputs half published), then delivers the first one caught.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
from collections.abc import Iterator, Mapping
from multiprocessing.process import BaseProcess
from typing import Any

__all__ = ["STOP_SIGNALS", "Terminated", "as_child", "deferred", "sigterm_as_interrupt", "start_child"]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


class Terminated(KeyboardInterrupt):
    """SIGTERM turned into an interrupt: a run publishes what it finished, the processes it started
    end with it, a batch marks its bags; what catches ``KeyboardInterrupt`` catches this too."""


def _raise_terminated(signum: int, frame: object) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # one is enough: a second would cut the stop short
    raise Terminated


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises :class:`Terminated` in the main thread while the block runs (elsewhere, where
    no signal handler can be set, nothing changes)."""
    if not _in_main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGTERM)
    _set_handlers({signal.SIGTERM: _raise_terminated})
    try:
        yield
    finally:
        _set_handlers({signal.SIGTERM: previous})


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold back SIGINT and SIGTERM while the block runs, then deliver the first one caught (with
    the handlers the block found). Only the main thread receives signals (and may set handlers);
    elsewhere nothing is changed. A signal ignored before stays ignored."""
    if not _in_main_thread():
        yield
        return
    caught: list[int] = []
    catch = {s: (lambda signum, frame: caught.append(signum)) for s in STOP_SIGNALS}
    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    try:
        _set_handlers(catch)
        yield
    finally:
        _set_handlers(previous)
        if caught:
            signal.raise_signal(caught[0])


def _set_handlers(handlers: Mapping[signal.Signals, Any]) -> None:
    """Install every handler of ``handlers`` ({signal: handler}; None, a handler not set from
    Python, is left as it is), even when one of the signals arrives half way and its old handler
    raises (a Ctrl-C between two settings): the rest are installed first, then that is raised."""
    pending: KeyboardInterrupt | None = None
    for signum, handler in handlers.items():
        while handler is not None:
            try:
                signal.signal(signum, handler)
                break
            except KeyboardInterrupt as err:  # raised by a handler between two bytecodes
                pending = pending or err
    if pending is not None:
        raise pending


def start_child(process: BaseProcess) -> None:
    """Start ``process`` with SIGINT and SIGTERM ignored from its first instruction (an ignored
    signal stays ignored across ``exec``; :func:`as_child` keeps them so): a Ctrl-C or a SIGTERM sent
    to the process group while the child still imports must not kill it, since the run then still
    asks it for its work. Ignoring is process-wide, so a stop sent to this process during the start
    (a few milliseconds) is lost; blocking it instead would hold it back only from this thread, and
    another thread of the process would take it in the middle of the start."""
    if not _in_main_thread():
        process.start()  # only the main thread may change handlers; the child sets its own (as_child)
        return
    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    try:
        _set_handlers(dict.fromkeys(STOP_SIGNALS, signal.SIG_IGN))
        process.start()
    finally:
        _set_handlers(previous)


def _exit_when_gone(parent: BaseProcess) -> None:
    parent.join()  # returns when the parent has ended (its end of a pipe closed)
    os._exit(1)


def as_child() -> None:
    """Called first in a child process: ignore SIGINT and SIGTERM (the parent decides when to stop)
    and exit as soon as the parent is gone."""
    for s in STOP_SIGNALS:
        signal.signal(s, signal.SIG_IGN)
    parent = multiprocessing.parent_process()
    if parent is not None:
        threading.Thread(target=_exit_when_gone, args=(parent,), name="lidar3d-parent-watch", daemon=True).start()

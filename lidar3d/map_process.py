"""The dense map built in a process of its own, off the tracking's critical path.

A settled sweep needs nothing back from the dense map (:class:`~lidar3d.mapping.dense_map.DenseMap`:
deskewing, the dynamic-object filter, the voxel maps, the pieces for loop closure), so the pipeline
sends each one to a child process and goes on tracking the next scan: on a multi-core machine the
map's work overlaps with the tracking (threads would not: the tracking's many small NumPy calls
and the map's fight over the GIL, measured 1.8x slower). The child takes the sweeps in the order
they were sent, so the map is the same, bit for bit, as when built in the pipeline's process.

:class:`DenseMapProcess` has the methods of :class:`DenseMap` that the pipeline calls (``add``,
``finish``, ``place_again``, ``clouds``, ``removes_dynamic``). ``add`` only queues the sweep (it
blocks while ``depth`` sweeps wait); the other calls wait for the child to take every sweep sent
before them. :meth:`~DenseMapProcess.end` fetches the final clouds and ends the child (the pipeline
calls it at the end of its ``finish``); a proxy dropped without it ends the child too. An error
raised in the child is raised again, unchanged, by the next call that waits; a child that dies
raises :class:`~lidar3d.errors.Lidar3dError`. The child ignores SIGINT and SIGTERM and exits when the
pipeline's process is gone (:mod:`lidar3d.stop_signals`): on Ctrl-C the pipeline's
``finish`` still gets every sweep sent into the map. With loop closure the child keeps the map's
pieces in its own :class:`~lidar3d.io.piece_spill.SpilledPieceStore`.

The map's clouds (tens of MB: 64 MB for 2 million voxels) do not go through the reply queue, which
pickles a message whole into one buffer on each side (twice the clouds' size more in each
process, at the end of the run, when both are largest); the reply names their arrays' shapes and
types and the arrays follow on a pipe of their own, written from and read into the arrays.
"""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import queue as queue_module
import time
import weakref
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from lidar3d import stop_signals
from lidar3d.config import Config
from lidar3d.errors import Lidar3dError
from lidar3d.io.piece_spill import SpilledPieceStore
from lidar3d.mapping.dense_map import DenseMap, MapClouds
from lidar3d.mapping.map_pieces import MapAnchor, MapPieces
from lidar3d.records import Scan

__all__ = ["DenseMapProcess"]

_POLL_S = 0.5


def _serve(
    config: Config,
    in_pieces: bool,
    requests: multiprocessing.Queue,
    replies: multiprocessing.Queue,
    bulk: Connection,
) -> None:
    """Child process: build the map from the requests until ``close``; every request but ``add``
    is answered with ``(kind, value, sweep milliseconds since the last answer)``; an answer of
    clouds is ``("clouds", layout, ...)`` with their arrays following on ``bulk``
    (:func:`_send_arrays`)."""
    stop_signals.as_child()
    store = SpilledPieceStore() if in_pieces else None
    dense_map = DenseMap(config, MapPieces(config.mapping.map_voxel_m, store) if in_pieces else None)
    error: BaseException | None = None  # of an add: answered at the next request
    sweep_ms: list[float] = []
    try:
        while True:
            kind, *args = requests.get()
            if kind == "add":
                if error is None:  # after an error the map stays as it was: no sweep in it is missing
                    t0 = time.perf_counter()
                    try:
                        dense_map.add(*args)
                    except Exception as err:
                        error = err
                    sweep_ms.append((time.perf_counter() - t0) * 1e3)
                continue
            if kind == "close":
                return
            answer: tuple[str, Any]
            arrays: list[np.ndarray] = []
            if error is not None:
                answer = ("error", error)
            else:
                try:
                    value = _answer(dense_map, kind, args)
                    if isinstance(value, MapClouds):
                        arrays = [np.ascontiguousarray(getattr(value, f.name)) for f in dataclasses.fields(value)]
                        answer = ("clouds", [(a.shape, a.dtype.str) for a in arrays])
                    else:
                        answer = ("ok", value)
                except Exception as err:
                    answer = ("error", err)
            replies.put((*answer, sweep_ms))
            sweep_ms = []
            try:
                _send_arrays(bulk, arrays)
            except OSError:  # the parent went away while reading the map: nothing to send to
                return
            del arrays
    finally:
        if store is not None:
            store.close()


def _send_arrays(bulk: Connection, arrays: list[np.ndarray]) -> None:
    """Write each (contiguous) array's bytes to ``bulk``, from the array itself (no copy)."""
    for array in arrays:
        bulk.send_bytes(array.data.cast("B") if array.nbytes else b"")


def _receive_arrays(bulk: Connection, layout: list[tuple[tuple[int, ...], str]]) -> list[np.ndarray]:
    """The arrays :func:`_send_arrays` wrote, read from ``bulk`` straight into new arrays of
    ``layout`` ((shape, dtype string) each)."""
    arrays = []
    for shape, dtype in layout:
        array = np.empty(shape, dtype)
        if array.nbytes:
            bulk.recv_bytes_into(array.data.cast("B"))
        else:
            bulk.recv_bytes()
        arrays.append(array)
    return arrays


def _stop(process, requests: multiprocessing.Queue) -> None:
    """End the child: ask it to stop, then terminate it if it does not."""
    if process.is_alive():
        with contextlib.suppress(queue_module.Full):
            requests.put(("close",), timeout=_POLL_S)
        process.join(timeout=5)
    if process.is_alive():
        process.kill()  # it ignores SIGTERM
        process.join(timeout=5)
    requests.close()
    requests.cancel_join_thread()


def _answer(dense_map: DenseMap, kind: str, args: list) -> MapClouds | None:
    if kind == "clouds":
        return dense_map.clouds()
    if kind == "finish":
        dense_map.finish()
    elif kind == "place_again":
        dense_map.place_again(*args)
    else:
        raise ValueError(f"unknown dense map request {kind!r}")
    return None


class DenseMapProcess:
    """A :class:`DenseMap` of ``config`` in a child process (see the module doc); ``close`` ends it.

    Args:
        config: the run's configuration.
        in_pieces: keep the map in pieces anchored to keyframes (loop closure on), spilled to disk.
        on_sweep_ms: called (in this process) with the milliseconds each sweep took in the child.
        depth: sweeps that may wait for the child; :meth:`add` blocks while that many do.
    """

    def __init__(
        self,
        config: Config,
        *,
        in_pieces: bool,
        on_sweep_ms: Callable[[float], None] | None = None,
        depth: int = 4,
    ) -> None:
        self.removes_dynamic = bool(config.dynamic.enabled)
        self._on_sweep_ms = on_sweep_ms
        context = multiprocessing.get_context("spawn")
        self._requests = context.Queue(maxsize=depth)
        self._replies = context.Queue()
        self._bulk, bulk_sender = context.Pipe(duplex=False)
        self._process = context.Process(
            target=_serve,
            args=(config, in_pieces, self._requests, self._replies, bulk_sender),
            name="lidar3d-dense-map",
            daemon=True,
        )
        stop_signals.start_child(self._process)
        bulk_sender.close()  # the child's copy is the only writer: its end reads as end of file here
        self._final: MapClouds | None = None  # the clouds of the finished map, once the child ended
        self._stopped_by: str | None = None  # why this process stopped the child itself
        self._close = weakref.finalize(self, _stop, self._process, self._requests)

    def add(self, scan: Scan, T_world_lidar: np.ndarray, twist: np.ndarray, anchor: MapAnchor | None = None) -> None:
        """Send ``DenseMap.add(scan, T_world_lidar, twist, anchor)`` to the child."""
        self._send(("add", scan, np.asarray(T_world_lidar), np.asarray(twist), anchor))

    def finish(self) -> None:
        """``DenseMap.finish`` in the child, after every sweep sent (nothing once :meth:`end` ran)."""
        if self._final is None:
            self._request("finish")

    def place_again(self, keyframe_poses: np.ndarray) -> None:
        """``DenseMap.place_again(keyframe_poses)`` in the child."""
        self._request("place_again", np.asarray(keyframe_poses))

    def clouds(self) -> MapClouds:
        """The map's clouds with every sweep sent so far in it."""
        return self._final if self._final is not None else self._request("clouds")

    def end(self) -> None:
        """Keep the map's clouds as they are now (:meth:`clouds` answers with them) and end the child."""
        if self._final is None:
            self._final = self._request("clouds")
        self.close()

    def close(self) -> None:
        """End the child (the sweeps it holds are dropped); idempotent."""
        self._close()

    def _send(self, message: tuple) -> None:
        while True:
            self._check_alive()
            try:
                self._requests.put(message, timeout=_POLL_S)
                return
            except queue_module.Full:
                continue

    def _request(self, kind: str, *args: Any) -> Any:
        """Send a request and wait for its whole answer. Ctrl-C and SIGTERM are held back until
        then (:func:`~lidar3d.stop_signals.deferred`): an answer left unread would be read as the
        next request's, and a map transfer cut half way would leave the rest in the pipe."""
        with stop_signals.deferred():
            self._send((kind, *args))
            while True:
                try:
                    answer, value, sweep_ms = self._replies.get(timeout=_POLL_S)
                    break
                except queue_module.Empty:
                    self._check_alive()
            if self._on_sweep_ms is not None:
                for ms in sweep_ms:
                    self._on_sweep_ms(ms)
            if answer == "error":
                raise value
            if answer == "clouds":
                try:
                    return MapClouds(*_receive_arrays(self._bulk, value))
                except BaseException as err:
                    # The rest of the map is still in the pipe (the child blocked writing it): the child
                    # is out of step with any later request, so it goes now rather than be waited for.
                    self._process.kill()
                    self._process.join(timeout=5)
                    self._stopped_by = f"reading the map failed ({type(err).__name__})"
                    if isinstance(err, (EOFError, OSError)):
                        raise Lidar3dError(
                            f"the dense map process ended while sending the map (exit code {self._process.exitcode})"
                        ) from err
                    raise
            return value

    def _check_alive(self) -> None:
        if self._stopped_by is not None:
            raise Lidar3dError(f"the dense map process was stopped: {self._stopped_by}")
        if not self._process.is_alive():
            raise Lidar3dError(f"the dense map process ended unexpectedly (exit code {self._process.exitcode})")

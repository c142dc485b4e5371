"""The bounded worker pool that decodes expensive inbound frames off the event loop.

``json.loads``, ``cbor2.loads`` and the PNG path's ``str``/``bytes`` work hold CPython's GIL
for as long as one call runs (only ``zlib`` releases it), so in a thread a 4 MB text holds the
event loop for tens of milliseconds: ``bench/attacks.py`` measures both. Hence a small pool of
worker *processes* (``spawn``: never a fork of a process that may hold Zenoh or threads) runs
:func:`server.rosbridge.inbound.run_decode`; the loop only hands over the payload and takes back
the decoded object, whose size the budget bounds (``DecodeBudget.max_values``).

At most ``max_pending`` frames are in the pool at once (counted until a worker is done with
one, even if the connection that sent it closed); one more is refused at once with
:class:`DecoderBusy`, carrying the request's id. A worker that dies (a crash in a C decoder)
costs the frame it held: the pool is replaced and the frame answered with an error. In a
process that may not start processes (a daemonic one) the pool is threads, with a warning.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import multiprocessing
import pickle
import threading
from collections.abc import Callable
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Literal

from server.rosbridge import errors
from server.rosbridge.budget import DecodeBudget
from server.rosbridge.errors import BridgeError, DecoderBusy, FrameError
from server.rosbridge.inbound import DecodeRequest, DecodeWork, run_decode

Backend = Literal["process", "thread"]
log = logging.getLogger(__name__)


@dataclass
class DecoderStats:
    """Counts since the decoder was made (for tests and ``bench/attacks.py``)."""

    submitted: int = 0  # requests handed to a worker
    completed: int = 0  # requests a worker finished (decoded or refused)
    refused_busy: int = 0  # refused because ``max_pending`` were in the pool
    png_inflated: int = 0  # png images a worker began to inflate (past the header's budget)


# A worker's answer: ("ok", object or its pickle, inflated) or ("error", class name, msg, id, op,
# inflated). Plain tuples, so nothing depends on pickling exception classes.
Outcome = tuple[Any, ...]


def work(request: DecodeRequest, budget: DecodeBudget, max_bytes: int, portable: bool) -> Outcome:
    """Decode in a worker; never raises. ``portable``: pickle the result here (a value that
    cannot cross to the server's process is one frame's error, not a broken pool)."""
    done = DecodeWork()
    try:
        obj = run_decode(request, budget, max_bytes, work=done)
        if portable:
            obj = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        return ("ok", obj, done.png_inflated)
    except BridgeError as err:
        return ("error", type(err).__name__, err.msg, err.id, err.op, done.png_inflated)
    except Exception as exc:  # a bug, or a value pickle refuses: one frame, not the pool
        msg = f"frame could not be handled: {type(exc).__name__}: {exc}"
        return ("error", "FrameError", msg, request.id, None, done.png_inflated)


class InboundDecoder:
    """Decodes :class:`DecodeRequest` s in a bounded pool; see the module docstring.

    Args:
        budget: what one frame may cost.
        max_frame_bytes: the frame size limit (``Settings.max_frame_bytes``).
        workers: processes (or threads) in the pool; started on first use.
        max_pending: frames in the pool at once; more are refused.
        backend: ``process`` (default) or ``thread`` (measured against each other in bench).
        work_fn: what a worker runs (:func:`work`; a fake in tests, picklable for processes).
    """

    def __init__(
        self,
        budget: DecodeBudget,
        max_frame_bytes: int,
        *,
        workers: int = 2,
        max_pending: int = 4,
        backend: Backend = "process",
        work_fn: Callable[[DecodeRequest, DecodeBudget, int, bool], Outcome] | None = None,
    ) -> None:
        if backend not in ("process", "thread"):
            raise ValueError(f"decoder backend must be process or thread, not {backend!r}")
        self.budget = budget
        self.max_frame_bytes = max_frame_bytes
        self.workers = workers
        self.max_pending = max_pending
        self.backend = backend
        self.work_fn = work_fn if work_fn is not None else work
        self.stats = DecoderStats()
        self._pool: concurrent.futures.Executor | None = None
        self._pending = 0
        self._lock = threading.Lock()  # _pending and stats change in pool callbacks too
        self._closed = False

    @property
    def pending(self) -> int:
        """Frames in the pool now."""
        return self._pending

    def _executor(self) -> concurrent.futures.Executor:
        if self._pool is None:
            if self.backend == "process":
                self._pool = concurrent.futures.ProcessPoolExecutor(
                    self.workers, mp_context=multiprocessing.get_context("spawn")
                )
            else:
                self._pool = concurrent.futures.ThreadPoolExecutor(
                    self.workers, thread_name_prefix="rosbridge-decode"
                )
        return self._pool

    async def decode(self, request: DecodeRequest) -> Any:
        """The decoded object, or the :class:`BridgeError` that refuses the frame (returned,
        not raised, as ``BridgeProtocol.receive_decoded`` takes it)."""
        with self._lock:
            if self._closed:
                return FrameError("the server is shutting down", id=request.id)
            if self._pending >= self.max_pending:
                self.stats.refused_busy += 1
                return DecoderBusy(
                    f"decoder busy: {self._pending} large frames are being decoded (at most "
                    f"{self.max_pending} at once); this one is refused, send it again later",
                    id=request.id,
                )
            self._pending += 1
            self.stats.submitted += 1
        try:
            future = self._submit(request)
        except Exception as exc:  # shut down, or a worker died as it was handed the frame
            self._finished(None)
            self._replace_pool()
            return FrameError(f"decoder unavailable: {exc}", id=request.id)
        portable = self.backend == "process"
        future.add_done_callback(self._finished)
        try:
            outcome: Outcome = await asyncio.wrap_future(future)
        except BrokenProcessPool as exc:
            self._replace_pool()
            return FrameError(f"decoding failed: a worker died ({exc})", id=request.id)
        except asyncio.CancelledError:
            task = asyncio.current_task()
            if task is not None and task.cancelling():
                raise  # the connection is closing: not this frame's business
            return FrameError("decoding cancelled: the decoder restarted", id=request.id)
        return self._result(outcome, portable)

    def _submit(self, request: DecodeRequest) -> concurrent.futures.Future[Outcome]:
        portable = self.backend == "process"
        try:
            pool = self._executor()
            return pool.submit(self.work_fn, request, self.budget, self.max_frame_bytes, portable)
        except AssertionError as exc:
            if self.backend != "process":
                raise
            # multiprocessing refuses children to a daemonic process ("daemonic processes are
            # not allowed to have children"): threads it is, and the log says so.
            log.warning("rosbridge decoder: no worker processes here (%s); using threads", exc)
            self._replace_pool()
            self.backend = "thread"
            return self._submit(request)

    def _finished(self, future: concurrent.futures.Future[Outcome] | None) -> None:
        with self._lock:
            self._pending -= 1
            self.stats.completed += 1
            done = future is not None and not future.cancelled() and future.exception() is None
            if done and future is not None and future.result()[-1]:
                self.stats.png_inflated += 1

    def _result(self, outcome: Outcome, portable: bool) -> Any:
        if outcome[0] == "ok":
            return pickle.loads(outcome[1]) if portable else outcome[1]
        _, name, msg, fid, op, _inflated = outcome
        cls = getattr(errors, name, None)
        if not (isinstance(cls, type) and issubclass(cls, BridgeError)):
            cls = FrameError
        return cls(msg, id=fid, op=op)

    def _replace_pool(self, *, wait: bool = False) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=wait, cancel_futures=True)

    def close(self) -> None:
        """Stop the workers: frames waiting are dropped, the one each worker holds is finished
        first."""
        with self._lock:
            self._closed = True
        self._replace_pool(wait=True)

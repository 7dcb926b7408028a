"""The one place every ur_rtde call goes through.

ur_rtde reports failure in three ways: an exception (``RuntimeError`` from C++), a
``False`` return, or an empty list. ``ur_call`` turns all of them into ``RobotError``
with a message naming the call. With ``timeout_s`` the call runs on a worker thread and
the caller stops waiting at the deadline (``DeviceTimeoutError``); the C++ call itself
cannot be cancelled and finishes in the background. That works because ur_rtde 1.6.5
releases the GIL in its methods. Its *constructors* do not: while one waits, no other
Python thread runs, so no deadline can be enforced on them from Python. The client
therefore probes the controller with plain sockets (with timeouts) before constructing.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TypeVar

from lasercal_hw.errors import DeviceTimeoutError, RobotError, TransportError

T = TypeVar("T")
_POLL_S = 0.05


def ur_call(what: str, fn: Callable[[], T], *, timeout_s: float | None = None,
            false_is_error: bool = True, lock: threading.Lock | None = None,
            connected: Callable[[], bool] | None = None) -> T:
    """Run ``fn`` (a ur_rtde call) and return its result.

    Raises ``RobotError`` if it raises, returns ``False`` (unless ``false_is_error`` is
    off, for calls whose ``False`` is an answer) or returns an empty list;
    ``DeviceTimeoutError`` if ``timeout_s`` passes first. With ``lock`` the call runs
    while holding it: ur_rtde's command handshake must not be entered by two threads at
    once, and a call abandoned at its deadline keeps the lock until it really returns.
    With ``timeout_s``, ``connected`` is asked every ``_POLL_S`` while waiting; once it
    says False the wait ends with ``TransportError`` (ur_rtde would spend the rest of the
    deadline reconnecting to a controller that is gone).
    """
    if lock is not None:
        unlocked = fn

        def fn() -> T:
            with lock:
                return unlocked()

    if timeout_s is None:
        result = _invoke(what, fn)
    else:
        outcome: list[T] = []
        failure: list[BaseException] = []

        def worker() -> None:
            try:
                outcome.append(fn())
            except BaseException as exc:  # re-raised on the caller's thread
                failure.append(exc)

        thread = threading.Thread(target=worker, name=f"ur-call-{what}", daemon=True)
        thread.start()
        deadline = time.monotonic() + timeout_s
        while thread.is_alive() and (remaining_s := deadline - time.monotonic()) > 0:
            thread.join(min(_POLL_S, remaining_s))
            if thread.is_alive() and connected is not None and not connected():
                raise TransportError(f"robot call {what}: the connection to the robot was lost while "
                                     "waiting for its answer; check the robot and connect again")
        if thread.is_alive():
            raise DeviceTimeoutError(f"robot call {what} did not return within {timeout_s:g} s; "
                                     "the connection is unusable, reconnect")
        if failure:
            raise _as_robot_error(what, failure[0]) from failure[0]
        result = outcome[0]
    if result is False and false_is_error:
        raise RobotError(f"robot refused {what} (ur_rtde returned False); check the robot's mode and "
                         "safety status, and the dashboard log")
    if isinstance(result, list) and not result:
        raise RobotError(f"robot call {what} returned no data; the control program may have stopped")
    return result


def _invoke(what: str, fn: Callable[[], T]) -> T:
    try:
        return fn()
    except Exception as exc:
        raise _as_robot_error(what, exc) from exc


def _as_robot_error(what: str, exc: BaseException) -> BaseException:
    if isinstance(exc, RobotError | DeviceTimeoutError):
        return exc
    if not isinstance(exc, Exception):
        return exc  # KeyboardInterrupt, SystemExit: not ours to translate
    return RobotError(f"robot call {what} failed: {exc}")

"""A stop request that no library code can lose.

``metafovea``'s commands turn SIGINT and SIGTERM into a ``KeyboardInterrupt`` raised in the main thread
(:func:`metafovea.cli.stop.install_stop_handlers`). Python runs a signal handler wherever the main thread is: inside
a callback that compiled code (XLA's compiler, a C++ extension) called, the exception can be caught and dropped there,
and the run goes on as if no one had asked it to stop. So the handler also records the request here, and the long
loops (the deep image prior's steps, :func:`metafovea.parallel.run_tasks`' results) call :func:`check`, which raises
it again once where it was lost.
"""

from __future__ import annotations

#: the signals received and not yet re-raised by :func:`check` (the handler appends, :func:`check` pops)
_PENDING: list[int] = []


def request(signum: int) -> None:
    """Record a stop request (the signal handler calls it before it raises)."""
    _PENDING.append(int(signum))


def requested() -> bool:
    """Whether a stop was requested and not yet re-raised by :func:`check`."""
    return bool(_PENDING)


def check() -> None:
    """Raise ``KeyboardInterrupt`` for a stop request that nothing has re-raised yet (once per request).

    Raises
    ------
    KeyboardInterrupt
        When a stop was requested since the last call that raised.
    """
    if _PENDING:
        signum = _PENDING.pop()
        _PENDING.clear()
        raise KeyboardInterrupt(f"signal {signum} (raised again: the first was lost in compiled code's callback)")


def clear() -> None:
    """Forget stop requests (a command that has handled the stop)."""
    _PENDING.clear()


__all__ = ["check", "clear", "request", "requested"]

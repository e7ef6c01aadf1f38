"""How ``metafovea`` stops: SIGINT and SIGTERM become a KeyboardInterrupt that every command handles (exit 130,
the resumable state kept, :func:`metafovea.cli.main`)."""

from __future__ import annotations

import sys


def _interrupt(signum: int, frame: object) -> None:
    from metafovea import stopping

    stopping.request(signum)  # raised again by the long loops if what runs now drops it (metafovea.stopping)
    raise KeyboardInterrupt(f"signal {signum}")


def _unraisable(u: sys.UnraisableHookArgs) -> None:
    """``sys.unraisablehook``: a stop signal that lands in a garbage-collector callback or a ``__del__`` (JAX's
    ``_xla_gc_callback``, seen in CI) raises where Python can only print and drop it; deliver it again, a moment
    later, instead of printing a traceback and running on."""
    if isinstance(u.exc_value, KeyboardInterrupt):
        import signal
        import threading

        # to the main thread: a signal raised in the timer's thread would only wake the main thread when its
        # current blocking call returns
        t = threading.Timer(0.05, signal.pthread_kill, (threading.main_thread().ident, signal.SIGINT))
        t.daemon = True  # never holds the exit
        t.start()
        return
    sys.__unraisablehook__(u)


def install_stop_handlers() -> None:
    """SIGINT and SIGTERM both stop the run as a KeyboardInterrupt (also when the shell started the command with
    SIGINT ignored, as a background job), and one dropped by an unraisable context is delivered again."""
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _interrupt)
    sys.unraisablehook = _unraisable

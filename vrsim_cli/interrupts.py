"""SIGINT and SIGTERM for the `vrsim` command, handled from its entry point on.

Layer 0, stdlib only: `vrsim_cli.__main__.main` installs the handlers before it imports
anything else, so a signal during start-up gives the same clean exit as one later.

Two modes:
- immediate (start-up, validation, `info`, `compare`, ...: nothing is being written): a
  signal raises `Interrupted`, which the entry point reports as `interrupted by SIGINT`
  with exit 128 + the signal number (130, 143), never a traceback;
- held (`held()`, while kernels are compiled or loaded): a signal waits for the block's
  end, then acts as in the mode around it;
- deferred (while a run writes its output, `deferred()`): the first signal only sets
  `received`, which the loop polls once per frame, so the output is finalised up to the
  last frame; a second one raises `Interrupted`, and the output is discarded (the
  previous file stays).

Only the main thread can install handlers; elsewhere (and for library callers that never
call `install`) Python's defaults stay.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

SIGNALS = (signal.SIGINT, signal.SIGTERM)

received: int | None = None  # the first signal received in deferred mode
_deferred = 0  # nesting depth of deferred()
_held = 0  # nesting depth of held()
_pending: int | None = None  # the first signal received while held


class Interrupted(BaseException):
    """A signal in immediate mode (or a second one in deferred mode). BaseException, like
    KeyboardInterrupt: `except Exception` blocks must not swallow it."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def _handle(signum, _frame) -> None:
    global received, _pending
    if _held:
        if _pending is None:
            _pending = signum
        return
    if _deferred and received is None:
        received = signum
        return
    raise Interrupted(signum)


def install() -> dict:
    """Install the handlers (main thread only). Returns the previous handlers, to restore
    with `restore` (empty when nothing was installed)."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    previous = {}
    for sig in SIGNALS:
        old = signal.signal(sig, _handle)
        if old is not _handle:
            previous[sig] = old
    return previous


def restore(previous: dict) -> None:
    for sig, handler in previous.items():
        signal.signal(sig, handler)


@contextmanager
def deferred():
    """Signals set `received` instead of raising, until the block ends (a second signal
    raises). `received` is cleared on entry."""
    global _deferred, received
    if _deferred == 0:
        received = None
    _deferred += 1
    try:
        yield
    finally:
        _deferred -= 1


@contextmanager
def held():
    """Signals wait until the block ends, then act as they would have. For code that
    Python is called back from C in (numba compiling or loading kernels from its disk
    cache): an exception the handler raised there would be printed as "Exception ignored"
    with a traceback and lost, and the run would go on."""
    global _held, _pending
    _held += 1
    try:
        yield
    finally:
        _held -= 1
        if _held == 0 and _pending is not None:
            signum, _pending = _pending, None
            _handle(signum, None)


def pending() -> int | None:
    """The signal that arrived in a `held` block (or in deferred mode), if any: for code
    that waits there and can stop early (a helper process it can kill)."""
    return _pending if _pending is not None else received


def name(signum: int) -> str:
    return signal.Signals(signum).name

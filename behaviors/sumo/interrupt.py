"""Ctrl-C that waits for the end of a step: a long loop can stop between two whole steps and keep
what it made so far, where an exception raised mid-step would leave half-updated state behind."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from types import FrameType


@contextlib.contextmanager
def sigint_between_steps() -> Iterator[Callable[[], bool]]:
    """Within the block, a first Ctrl-C only sets a flag (read it through the yielded function,
    between steps); a second one raises KeyboardInterrupt at once, for a user who will not wait.

    Signal handlers can be set only in the main thread: elsewhere Ctrl-C is left as it was and the
    flag never rises.
    """
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    asked: list[int] = []

    def handler(signum: int, frame: FrameType | None) -> None:
        if asked:
            raise KeyboardInterrupt
        asked.append(signum)

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield lambda: bool(asked)
    finally:
        signal.signal(signal.SIGINT, previous)

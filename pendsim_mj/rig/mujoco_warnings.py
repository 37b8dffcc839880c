"""MuJoCo's warnings, captured instead of printed.

MuJoCo's default warning handler prints ``WARNING: ...`` to the terminal and appends it to
``MUJOCO_LOG.TXT`` in the working directory. Importing this module (``pendsim_mj.rig.model`` does)
installs a handler that keeps the latest messages in memory instead: nothing is printed and no
log file is written; ``captured()`` hands the messages of a block to the code that turns them
into one error (``SimulationDiverged``, ``ModelError``). The handler runs on MuJoCo's worker
threads too (``mujoco.rollout``), so it only appends to a bounded deque.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import threading
from collections.abc import Iterator

import mujoco

KEPT = 64
"""Most recent messages kept (a diverging batch warns on every step of every run)."""

_messages: collections.deque[tuple[int, str]] = collections.deque(maxlen=KEPT)
_counter = itertools.count()
_lock = threading.Lock()


def _handler(message: str) -> None:
    with _lock:
        _messages.append((next(_counter), str(message).strip()))


def install() -> None:
    """Route MuJoCo's warnings to this module (idempotent; done on import)."""
    mujoco.set_mju_user_warning(_handler)


def _latest_number() -> int:
    with _lock:
        return _messages[-1][0] if _messages else -1


class Captured:
    """The warnings MuJoCo gave since the block began (``messages``), oldest first, distinct."""

    def __init__(self) -> None:
        self._after = _latest_number()

    @property
    def messages(self) -> list[str]:
        with _lock:
            new = [text for number, text in _messages if number > self._after]
        return list(dict.fromkeys(new))

    def summary(self, *, limit: int = 200) -> str:
        """The first distinct message (and how many others), on one line, at most ``limit`` chars."""
        messages = self.messages
        if not messages:
            return ""
        text = " ".join(messages[0].split())
        if len(text) > limit:
            text = text[: limit - 3] + "..."
        more = len(messages) - 1
        return text + (f" (and {more} other warning{'s' if more > 1 else ''})" if more else "")


@contextlib.contextmanager
def captured() -> Iterator[Captured]:
    """``with captured() as warnings: ...; warnings.messages``."""
    install()
    yield Captured()


install()

"""A call that may hang, run under a timeout of our own.

After a UR controller disappears, ur-rtde's next blocking call can hang forever, and a
hung call must never hang the caller: the robot must still be stopped and the user told.
Every ur-rtde call of the UR driver and the read-only reader goes through ``call_with_timeout``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from varskin.errors import RobotTimeout


def call_with_timeout(fn: Callable, args: tuple, timeout_s: float, label: str):
    """``fn(*args)`` in a daemon worker thread; its result, its exception, or ``RobotTimeout``.

    A call that outlives ``timeout_s`` is abandoned (a thread cannot be killed); its daemon
    thread ends with the call or the process.
    """
    box: dict = {}

    def work() -> None:
        try:
            box["value"] = fn(*args)
        except BaseException as e:  # handed to the caller's thread
            box["error"] = e

    worker = threading.Thread(target=work, daemon=True, name=f"ur-{label.split(':')[-1].strip()}")
    worker.start()
    worker.join(timeout_s)
    if worker.is_alive():
        raise RobotTimeout(f"{label} did not return within {timeout_s:.1f} s")
    if "error" in box:
        raise box["error"]
    return box.get("value")

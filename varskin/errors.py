"""One exception hierarchy for the whole project.

Every error a user can cause or a device can raise is a ``VarskinError`` and also the
built-in exception it most resembles, so callers can catch either. The CLI turns a
``VarskinError`` into a one-line message; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations


class VarskinError(Exception):
    """Base of every error this project raises on purpose."""


# --- user input -------------------------------------------------------------------------


class InputError(ValueError, VarskinError):
    """A file or argument the user gave is malformed. The message names the place."""


class PointLogFormatError(InputError):
    """A point-log CSV breaks the interchange format (file, line and column in the message)."""


class ConfigError(InputError):
    """A patch, launch or safety config is malformed or inconsistent."""


class LocalizationError(VarskinError):
    """Localization could not run at all (as opposed to one sensor failing, which is a status)."""


# --- Muca board -------------------------------------------------------------------------


class BoardError(OSError, VarskinError):
    """The Muca board or its serial link misbehaved."""


class BoardTimeout(TimeoutError, BoardError):
    """No complete frame arrived within the allowed time."""


class BoardDisconnected(ConnectionError, BoardError):
    """The serial device went away (unplugged, pty closed)."""


# --- robot ------------------------------------------------------------------------------


class RobotError(RuntimeError, VarskinError):
    """The arm refused or failed a command."""


class RobotTimeout(TimeoutError, RobotError):
    """A robot call did not return within its supervision timeout."""


class ConnectionLost(ConnectionError, RobotError):
    """The robot controller is unreachable or dropped the connection."""


class ProtectiveStop(RobotError):
    """The controller is protective-stopped; motion needs an unlock first."""


class ScriptNotRunning(RobotError):
    """The control script on the controller is not running."""


class ForceLimitExceeded(RobotError):
    """Measured contact force went above the configured maximum."""


class NoContact(RobotError):
    """The probe reached the floor of its bounded descent without touching anything."""


class SafetyViolation(ValueError, RobotError):
    """A plan or a measured state lies outside the safety envelope."""


# --- storage ----------------------------------------------------------------------------


class StoreError(OSError, VarskinError):
    """A session store is unreadable, corrupt or from an incompatible version."""


# --- registration -----------------------------------------------------------------------


class RegistrationError(ValueError, VarskinError):
    """The patch frame cannot be registered: degenerate touch-off points, too few markers."""

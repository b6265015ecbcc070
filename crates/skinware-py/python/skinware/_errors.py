"""The exceptions skinware raises. Each also derives from the Python
exception a user would reach for (``except TimeoutError`` catches
``Timeout``), and every message names the channel and what to do."""

from __future__ import annotations

__all__ = [
    "SkinwareError",
    "ChannelMissing",
    "WriterGone",
    "Timeout",
    "NoFrameYet",
    "LayoutChanged",
    "SchemaMismatch",
    "AccessDenied",
    "ChannelBusy",
    "InvalidArgument",
    "ReaderClosed",
    "WriterClosed",
    "ChannelError",
    "GeometryError",
]


class SkinwareError(Exception):
    """Base class of every skinware exception."""


class ChannelMissing(SkinwareError, LookupError):
    """No channel of that name: its writer (``skin run``, a driver) is not
    running, or the skin or channel name is wrong (``skin ls`` lists them)."""


class WriterGone(SkinwareError):
    """The channel's writer died or stopped, and no successor took its place
    within the timeout."""


class Timeout(SkinwareError, TimeoutError):
    """No new frame within the timeout, while the writer lives."""


class NoFrameYet(SkinwareError):
    """The writer has not published its first frame yet."""


class LayoutChanged(SkinwareError):
    """The channel was re-created with another layout (topology, records):
    this reader cannot read it; open a new one."""


class SchemaMismatch(SkinwareError):
    """The channel carries something else than the reader expects: a service
    read as a layer, or records of another schema, version or size."""


class AccessDenied(SkinwareError, PermissionError):
    """The channel's writer does not let this user read it (its ``access``)."""


class ChannelBusy(SkinwareError):
    """Another live writer already owns the channel name."""


class InvalidArgument(SkinwareError, ValueError):
    """A bad argument: a name, a rate, an array of the wrong dtype or size."""


class ReaderClosed(SkinwareError):
    """The reader was closed (possibly from another thread)."""


class WriterClosed(SkinwareError):
    """The writer was closed."""


class ChannelError(SkinwareError):
    """A channel that cannot be used: corrupt, of another skinware version,
    not answering, or an operating-system error."""


class GeometryError(SkinwareError):
    """The skin's published geometry is missing or unreadable."""

"""skinware for Python: tactile data from large robot skins, as numpy arrays.

A running skin (``skin run``, ``skin demo``) publishes each layer of sensors
and each service in shared memory. From Python:

>>> import skinware                                          # doctest: +SKIP
>>> skinware.layers("default")                               # doctest: +SKIP
>>> with skinware.Reader("default", "pressure") as reader:  # doctest: +SKIP
...     frame = reader.wait_newer(timeout=1.0)
...     frame.responses          # read-only numpy uint16, one per sensor
...     frame.seq, frame.acquired_ns, frame.skipped, frame.status

Every frame is a private copy made by skinware's lock-free reader with the
GIL released: Python never sees the live shared memory, and nothing a Python
program does (including dying mid-read) can slow or break the skin.

``Geometry.open(skin)`` gives positions, normals, the 2-D map, the neighbour
graph and the regions as arrays; ``ContactReader`` and ``MotionReader`` read
the services as structured arrays; ``Writer`` and ``ServiceWriter`` publish a
layer (a driver) or a service from Python. See docs/python.md.
"""

from __future__ import annotations

from enum import IntFlag
from typing import List, Optional

from ._errors import (
    AccessDenied,
    ChannelBusy,
    ChannelError,
    ChannelMissing,
    GeometryError,
    InvalidArgument,
    LayoutChanged,
    NoFrameYet,
    ReaderClosed,
    SchemaMismatch,
    SkinwareError,
    Timeout,
    WriterClosed,
    WriterGone,
)
from ._services import (
    CONTACT_DTYPE,
    MAX_CONTACTS,
    MOTION_DTYPE,
    REGION_CONTACTS_DTYPE,
    TAXEL_STATE_DTYPE,
    ContactFlags,
    ContactReader,
    MotionFlags,
    MotionReader,
    TaxelState,
    TaxelStateReader,
)
from ._skinware import (
    ABI_VERSION,
    ChannelInfo,
    ChannelWriter,
    Frame,
    Geometry,
    Periodic,
    Reader,
    ServiceReader,
    ServiceWriter,
    Ticks,
    Topology,
    Writer,
    __version__,
    channels,
    monotonic_ns,
    segment_dir,
)


class Status(IntFlag):
    """Flags of ``Frame.status``; 0 is a good frame."""

    OK = 0
    #: The acquisition failed: the data must not be used.
    FAULT = 1
    #: Some sensors did not answer: their responses are the previous ones.
    PARTIAL = 2
    #: (Services) an input layer or service is faulted or gone.
    INPUT_FAULTED = 4


def layers(skin: str = "default") -> List[ChannelInfo]:
    """The layers of ``skin``, with their state ("running", "paused",
    "faulted" or "gone") and sensor counts, as ``skin ls`` lists them."""
    return [c for c in channels(skin) if c.kind == "layer"]


def services(skin: str = "default") -> List[ChannelInfo]:
    """The services of ``skin``, with their state."""
    return [c for c in channels(skin) if c.kind == "service"]


def skins() -> List[str]:
    """The names of the skins that have channels on this machine."""
    return sorted({c.skin for c in channels(None)})


def layer(skin: str, name: str) -> Optional[ChannelInfo]:
    """Layer ``name`` of ``skin`` as ``layers`` lists it, or ``None``."""
    return next((c for c in layers(skin) if c.name == name), None)


__all__ = [
    "ABI_VERSION",
    "AccessDenied",
    "CONTACT_DTYPE",
    "ChannelBusy",
    "ChannelError",
    "ChannelInfo",
    "ChannelMissing",
    "ChannelWriter",
    "ContactFlags",
    "ContactReader",
    "Frame",
    "Geometry",
    "GeometryError",
    "InvalidArgument",
    "LayoutChanged",
    "MAX_CONTACTS",
    "MOTION_DTYPE",
    "MotionFlags",
    "MotionReader",
    "NoFrameYet",
    "Periodic",
    "REGION_CONTACTS_DTYPE",
    "Reader",
    "ReaderClosed",
    "SchemaMismatch",
    "ServiceReader",
    "ServiceWriter",
    "SkinwareError",
    "Status",
    "TAXEL_STATE_DTYPE",
    "TaxelState",
    "TaxelStateReader",
    "Ticks",
    "Timeout",
    "Topology",
    "Writer",
    "WriterClosed",
    "WriterGone",
    "__version__",
    "channels",
    "layer",
    "layers",
    "monotonic_ns",
    "segment_dir",
    "services",
    "skins",
]

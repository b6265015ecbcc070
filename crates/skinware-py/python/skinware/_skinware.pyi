"""Type stubs of the native module ``skinware._skinware`` (built from
``crates/skinware-py/src``). Import from ``skinware``, which re-exports it."""

from __future__ import annotations

from types import TracebackType
from typing import Any, Iterator, Literal, Optional, Sequence, Tuple, Type, TypeVar, final

import numpy as np
from typing_extensions import Self
import numpy.typing as npt

__all__ = [
    "ABI_VERSION",
    "ChannelInfo",
    "ChannelWriter",
    "Frame",
    "Geometry",
    "Periodic",
    "Reader",
    "ServiceReader",
    "ServiceWriter",
    "Ticks",
    "Topology",
    "Writer",
    "__version__",
    "channels",
    "monotonic_ns",
    "segment_dir",
]

__version__: str
ABI_VERSION: int

_State = Literal["running", "paused", "faulted", "gone"]
_WriterStateName = Literal["running", "paused", "faulted"]
_Mode = Literal["latest", "newer", "request"]
_AccessName = Literal["owner", "group", "everyone"]
_R = TypeVar("_R", bound="Reader")

def channels(skin: Optional[str] = None) -> list[ChannelInfo]:
    """The channels of ``skin`` (every skin if ``None``), sorted by skin and name."""

def segment_dir() -> str:
    """The directory of the channels' sockets (``$SKINWARE_SHM_DIR``, else ``/dev/shm``)."""

def monotonic_ns() -> int:
    """CLOCK_MONOTONIC now, ns: the clock of ``Frame.acquired_ns``."""

@final
class ChannelInfo:
    """One channel as ``skin ls`` sees it."""

    skin: str
    name: str
    kind: Optional[Literal["layer", "service"]]
    state: _State
    sensors: int
    payload_bytes: int
    frames: int
    writer_pid: int
    generation: int
    problem: Optional[str]

@final
class Frame:
    """A private, read-only copy of one frame, with its metadata."""

    @property
    def data(self) -> np.ndarray: ...
    @property
    def responses(self) -> npt.NDArray[np.uint16]:
        """A layer's responses, one per sensor in frame order (read-only)."""
    @property
    def records(self) -> np.ndarray:
        """A service's records, a read-only structured array, one per label."""
    seq: int
    acquired_ns: int
    published_ns: int
    status: int
    skipped: int
    fresh: bool
    @property
    def faulted(self) -> bool: ...
    def __array__(self, dtype: Any = None, copy: Optional[bool] = None) -> np.ndarray: ...
    def __len__(self) -> int: ...

@final
class Topology:
    """A layer's patches, modules and sensors, in frame order."""

    def __new__(
        cls,
        name: str,
        modules: Sequence[Tuple[int, int, Sequence[int]]],
        sensor_type: str = "pressure",
        rate_hz: float = 0.0,
    ) -> Self:
        """``modules``: ``(patch_id, module_id, uids)`` in frame order."""
    @staticmethod
    def uniform(
        name: str,
        patches: int,
        modules_per_patch: int,
        sensors_per_module: int,
        sensor_type: str = "pressure",
        rate_hz: float = 0.0,
    ) -> Topology: ...
    @property
    def name(self) -> str: ...
    @property
    def sensor_type(self) -> str: ...
    @property
    def rate_hz(self) -> float: ...
    @property
    def uids(self) -> npt.NDArray[np.uint32]: ...
    @property
    def module_ids(self) -> npt.NDArray[np.uint32]: ...
    @property
    def patch_ids(self) -> npt.NDArray[np.uint32]: ...
    @property
    def modules(self) -> list[Tuple[int, int, int, int]]:
        """``(module_id, patch_id, first_sensor, end_sensor)`` per module."""
    @property
    def patches(self) -> list[int]: ...
    def index_of(self, uid: int) -> Optional[int]: ...
    def __len__(self) -> int: ...
    def __eq__(self, other: object, /) -> bool: ...

@final
class Periodic(Iterator[Frame]):
    """The iterator of ``Reader.periodic`` and ``Reader.frames``."""

    def __iter__(self) -> Periodic: ...
    def __next__(self) -> Frame: ...

class Reader:
    """A reader of one layer; frames are private copies made without the GIL."""

    def __new__(
        cls, skin: str, layer: str, *, allow_gone: bool = False, anticipate: Optional[float] = None
    ) -> Self: ...
    def latest(self) -> Frame:
        """The newest complete frame, now (raises ``NoFrameYet`` before the first)."""
    def wait_newer(self, timeout: Optional[float] = 1.0) -> Frame:
        """The next frame, as soon as it is published. ``Timeout`` after
        ``timeout`` seconds if the writer lives, ``WriterGone`` if it is gone;
        ``None`` waits without limit, also for a gone writer's successor."""
    def request(self, timeout: Optional[float] = 1.0) -> Frame:
        """Asks for a frame newer than any published now and waits for it."""
    def read_into(self, out: npt.NDArray[np.uint16], mode: _Mode = "latest", timeout: Optional[float] = 1.0) -> Frame:
        """Reads into ``out`` (one uint16 per sensor) instead of a new array.
        The copy is made without the GIL: other threads must not use ``out``
        meanwhile."""
    def periodic(self, hz: float, gone_timeout: float = 2.0) -> Periodic:
        """The newest frame at ``hz``, fresh or not, on an absolute-time grid."""
    def frames(self, gone_timeout: float = 2.0) -> Periodic:
        """Every new frame, as soon as available."""
    def __iter__(self) -> Periodic: ...
    @property
    def state(self) -> _State: ...
    @property
    def topology(self) -> Topology: ...
    @property
    def skin(self) -> str: ...
    @property
    def name(self) -> str: ...
    @property
    def published_seq(self) -> int: ...
    @property
    def writer_pid(self) -> int: ...
    @property
    def generation(self) -> int: ...
    @property
    def period(self) -> Optional[float]: ...
    @property
    def stats(self) -> dict[str, int]: ...
    @property
    def writer_stats(self) -> dict[str, int]: ...
    @property
    def closed(self) -> bool: ...
    def close(self) -> None: ...
    def __len__(self) -> int: ...
    def __enter__(self: _R) -> _R: ...
    def __exit__(
        self,
        exc_type: Optional[Type[BaseException]],
        exc: Optional[BaseException],
        traceback: Optional[TracebackType],
    ) -> bool: ...

class ServiceReader(Reader):
    """A reader of a service whose records have ``dtype`` and ``schema``."""

    def __new__(
        cls,
        skin: str,
        name: str,
        dtype: npt.DTypeLike,
        schema: Tuple[str, int],
        *,
        allow_gone: bool = False,
    ) -> Self: ...
    @property
    def labels(self) -> list[str]: ...
    @property
    def dtype(self) -> np.dtype: ...
    @property
    def schema(self) -> Tuple[str, int]: ...
    @property
    def inputs(self) -> list[str]: ...
    @property
    def rate_hz(self) -> Optional[float]: ...

@final
class Ticks(Iterator[Tuple[int, int]]):
    """A writer's periods: ``(deadline_ns, missed)``."""

    def __iter__(self) -> Ticks: ...
    def __next__(self) -> Tuple[int, int]: ...

class ChannelWriter:
    """What ``Writer`` and ``ServiceWriter`` share: periods, requests, state, ``close()``."""

    def ticks(self, hz: Optional[float] = None) -> Ticks:
        """The channel's periods on an absolute-time grid: ``(deadline_ns, missed)``."""
    def wait_request(self, timeout: Optional[float] = None) -> bool:
        """A sporadic channel: waits for a reader's request; ``False`` on timeout or close."""
    state: _WriterStateName
    @property
    def label(self) -> str: ...
    @property
    def stats(self) -> dict[str, int]: ...
    def close(self) -> None: ...
    def __enter__(self) -> Self: ...
    def __exit__(
        self,
        exc_type: Optional[Type[BaseException]],
        exc: Optional[BaseException],
        traceback: Optional[TracebackType],
    ) -> bool: ...

@final
class Writer(ChannelWriter):
    """The writer of one layer: a driver written in Python."""

    def __new__(
        cls,
        skin: str,
        layer: str,
        topology: Topology,
        rate_hz: Optional[float] = None,
        *,
        slots: int = 3,
        access: _AccessName = "owner",
    ) -> Self: ...
    def publish(self, responses: npt.NDArray[np.uint16], status: int = 0, acquired_ns: Optional[int] = None) -> int:
        """Publishes one frame of one uint16 response per sensor; returns its sequence number."""
    @property
    def topology(self) -> Topology: ...
    @property
    def revived(self) -> bool: ...
    def __len__(self) -> int: ...

@final
class ServiceWriter(ChannelWriter):
    """A service published from Python (an application-based service)."""

    def __new__(
        cls,
        skin: str,
        name: str,
        dtype: npt.DTypeLike,
        schema: Tuple[str, int],
        labels: Optional[Sequence[str]] = None,
        records: Optional[int] = None,
        rate_hz: Optional[float] = None,
        inputs: Optional[Sequence[str]] = None,
        *,
        access: _AccessName = "owner",
    ) -> Self: ...
    def publish(self, records: np.ndarray, status: int = 0, acquired_ns: Optional[int] = None) -> int:
        """Publishes one frame of records of the service's dtype."""
    def empty(self) -> np.ndarray:
        """A zeroed array of one frame's records, to fill and publish."""
    @property
    def dtype(self) -> np.dtype: ...
    def __len__(self) -> int: ...

@final
class Geometry:
    """A skin's geometry as read-only numpy arrays (global sensor order)."""

    @staticmethod
    def open(skin: str = "default") -> Geometry: ...
    positions: npt.NDArray[np.float32]
    normals: npt.NDArray[np.float32]
    radii: npt.NDArray[np.float32]
    map: npt.NDArray[np.float32]
    map_pieces: npt.NDArray[np.uint32]
    link_of: npt.NDArray[np.uint16]
    neighbours: Tuple[npt.NDArray[np.uint32], npt.NDArray[np.uint32]]
    layer_starts: npt.NDArray[np.int64]
    regions: dict[str, npt.NDArray[np.uint32]]
    subregions: list[npt.NDArray[np.uint32]]
    region_subregions: dict[str, npt.NDArray[np.uint32]]
    @property
    def skin(self) -> str: ...
    @property
    def links(self) -> list[str]: ...
    @property
    def layers(self) -> list[str]: ...
    def topology(self, layer: str) -> Topology: ...
    def layer_range(self, layer: str) -> Tuple[int, int]: ...
    def global_index(self, layer: str, sensor: int) -> int: ...
    def locate(self, index: int) -> Tuple[str, int, int, int, int]: ...
    def region(self, name: str) -> npt.NDArray[np.uint32]: ...
    def __len__(self) -> int: ...

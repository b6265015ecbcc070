"""The services skinware ships, as numpy structured dtypes and typed readers.

The dtypes mirror the services' records byte for byte (little-endian, packed,
as the Rust ``#[repr(C)]`` structs of ``skinware-services``); opening a reader
checks the channel's schema, version and record size, so a mismatch is an
exception, never misread bytes.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

import numpy as np

from ._skinware import ServiceReader

__all__ = [
    "MAX_CONTACTS",
    "CONTACT_DTYPE",
    "REGION_CONTACTS_DTYPE",
    "MOTION_DTYPE",
    "TAXEL_STATE_DTYPE",
    "ContactFlags",
    "MotionFlags",
    "TaxelState",
    "ContactReader",
    "TaxelStateReader",
    "MotionReader",
]

#: Contacts reported per region and frame (more are flagged ``MORE_CONTACTS``).
MAX_CONTACTS = 8

#: One contact: a connected group of touched taxels within a region.
CONTACT_DTYPE = np.dtype(
    [
        ("taxels", "<u4"),  # touched taxels in it
        ("peak_sensor", "<u4"),  # global index of its most pressed taxel
        ("centroid", "<f4", (3,)),  # pressure-weighted centroid, metres
        ("normal", "<f4", (3,)),  # pressure-weighted mean outward normal
        ("map", "<f4", (2,)),  # centroid on the 2-D map, metres
        ("area_m2", "<f4"),  # sensing area of its taxels
        ("total", "<f4"),  # sum of responses above baseline
        ("peak", "<f4"),  # largest response above baseline
    ]
)

#: The contacts of one region in one frame (the contact service's record).
REGION_CONTACTS_DTYPE = np.dtype(
    [
        ("count", "<u4"),  # valid entries of contacts, largest total first
        ("flags", "<u4"),  # ContactFlags
        ("dead", "<u4"),  # dead taxels in the region
        ("stuck", "<u4"),  # stuck (saturated) taxels in the region
        ("contacts", CONTACT_DTYPE, (MAX_CONTACTS,)),
    ]
)

#: The motion of one region's main contact (the motion service's record).
MOTION_DTYPE = np.dtype(
    [
        ("flags", "<u4"),  # MotionFlags
        ("speed_3d", "<f4"),  # m/s along the surface
        ("speed_map", "<f4"),  # m/s on the 2-D map
        ("direction_map_rad", "<f4"),  # from the map's +x towards +y
        ("velocity_3d", "<f4", (3,)),
        ("velocity_map", "<f4", (2,)),
        ("start_3d", "<f4", (3,)),
        ("now_3d", "<f4", (3,)),
        ("start_map", "<f4", (2,)),
        ("now_map", "<f4", (2,)),
        ("duration_s", "<f4"),
    ]
)

#: One taxel's state (the contact service's ``NAME-taxels`` channel).
TAXEL_STATE_DTYPE = np.dtype("u1")


class ContactFlags(IntFlag):
    """Bits of ``REGION_CONTACTS_DTYPE['flags']``."""

    INPUT_FAULTED = 1
    MORE_CONTACTS = 2


class MotionFlags(IntFlag):
    """Bits of ``MOTION_DTYPE['flags']``."""

    SLIDING = 1
    CONTACT = 2
    INPUT_FAULTED = 4


class TaxelState(IntEnum):
    """Values of the ``NAME-taxels`` records."""

    IDLE = 0
    TOUCHED = 1
    DEAD = 2
    STUCK = 3
    NO_INPUT = 4


class ContactReader(ServiceReader):
    """The contact service: one ``REGION_CONTACTS_DTYPE`` record per region
    (``labels`` are the region names).

    >>> with ContactReader("default") as contacts:          # doctest: +SKIP
    ...     frame = contacts.wait_newer(1.0)
    ...     for region, record in zip(contacts.labels, frame.records):
    ...         for contact in record["contacts"][: record["count"]]:
    ...             print(region, contact["centroid"], contact["total"])
    """

    SCHEMA = ("skinware.contacts", 1)

    def __new__(cls, skin: str = "default", name: str = "contact", *, allow_gone: bool = False):
        return super().__new__(cls, skin, name, REGION_CONTACTS_DTYPE, cls.SCHEMA, allow_gone=allow_gone)


class TaxelStateReader(ServiceReader):
    """The contact service's per-taxel states (``TaxelState`` values, one per
    taxel of the whole skin, in global order)."""

    SCHEMA = ("skinware.taxel-state", 1)

    def __new__(cls, skin: str = "default", name: str = "contact-taxels", *, allow_gone: bool = False):
        return super().__new__(cls, skin, name, TAXEL_STATE_DTYPE, cls.SCHEMA, allow_gone=allow_gone)


class MotionReader(ServiceReader):
    """The motion service: one ``MOTION_DTYPE`` record per region."""

    SCHEMA = ("skinware.motion", 1)

    def __new__(cls, skin: str = "default", name: str = "motion", *, allow_gone: bool = False):
        return super().__new__(cls, skin, name, MOTION_DTYPE, cls.SCHEMA, allow_gone=allow_gone)

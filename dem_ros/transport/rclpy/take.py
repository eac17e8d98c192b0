"""Take a serialized sample and its writer's GID from an rcl subscription (``rcl_take_serialized_message``).

rclpy's own take (``_rclpy.Subscription.take_message``) hands over a ``MessageInfo`` dict with
time stamps and sequence numbers but drops ``rmw_message_info_t.publisher_gid``: with it a
subscription can only attribute a sample when exactly one writer is matched. rcl itself fills
the GID of every sample (rmw_fastrtps: the writer's GUID, what ``get_publishers_info_by_topic``
lists as ``endpoint_gid``), so this module calls ``rcl_take_serialized_message`` through ctypes
on the rcl subscription rclpy made (``Subscription.handle.pointer``), from the ``librcl`` and
``librcutils`` rclpy has loaded. The structs are rcl's (``rcutils_uint8_array_t``,
``rmw_message_info_t``); ``rmw_gid_t`` holds 24 bytes before Iron and 16 since.

rmw_cyclonedds_cpp fills ``publisher_gid`` with the writer's 8-byte DDS instance handle (zero-padded), not
its GUID, while ``get_publishers_info_by_topic`` lists the GUID: there each new handle is resolved once to
the writer's GUID with Cyclone's ``dds_get_matched_publication_data`` on the subscription's reader (from
the ``libddsc`` rmw_cyclonedds_cpp has loaded), so a sample's GID is the GUID on both RMWs.
"""

from __future__ import annotations

import ctypes
import os

from ..api import TransportError, gid16

__all__ = ["SerializedTake", "gid_storage_size", "publisher_gid"]

#: rcl's "no sample to take" (RCL_RET_SUBSCRIPTION_TAKE_FAILED)
TAKE_FAILED = 401
_OLD_DISTROS = ("foxy", "galactic", "humble")


def gid_storage_size() -> int:
    """``RMW_GID_STORAGE_SIZE`` of the sourced distro: 24 up to Humble, 16 from Iron (Jazzy) on."""
    return 24 if os.environ.get("ROS_DISTRO", "").lower() in _OLD_DISTROS else 16


def _loaded(name: str) -> str:
    """Path of the shared library ``name`` as this process has it mapped (rclpy loaded it)."""
    with open("/proc/self/maps") as f:
        for line in f:
            path = line.rstrip().split(" ")[-1]
            if os.path.basename(path) == name:
                return path
    return name  # not mapped yet: the loader's search path


class _Alloc(ctypes.Structure):
    _fields_ = [("allocate", ctypes.c_void_p), ("deallocate", ctypes.c_void_p), ("reallocate", ctypes.c_void_p),
                ("zero_allocate", ctypes.c_void_p), ("state", ctypes.c_void_p)]


class _Bytes(ctypes.Structure):  # rcutils_uint8_array_t = rcl_serialized_message_t
    _fields_ = [("buffer", ctypes.POINTER(ctypes.c_uint8)), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Alloc)]


def _gid_struct(gid_size: int) -> type[ctypes.Structure]:
    class Gid(ctypes.Structure):  # rmw_gid_t
        _fields_ = [("implementation_identifier", ctypes.c_char_p), ("data", ctypes.c_uint8 * gid_size)]

    return Gid


def _info_struct(gid_size: int) -> type[ctypes.Structure]:
    Gid = _gid_struct(gid_size)

    class Info(ctypes.Structure):  # rmw_message_info_t
        _fields_ = [("source_timestamp", ctypes.c_int64), ("received_timestamp", ctypes.c_int64),
                    ("publication_sequence_number", ctypes.c_uint64), ("reception_sequence_number", ctypes.c_uint64),
                    ("publisher_gid", Gid), ("from_intra_process", ctypes.c_bool)]

    return Info


#: rmw_cyclonedds_cpp's implementation identifier (in each rmw_gid_t)
CYCLONE = b"rmw_cyclonedds_cpp"


class _Endpoint(ctypes.Structure):  # the head of Cyclone's dds_builtintopic_endpoint_t
    _fields_ = [("key", ctypes.c_uint8 * 16)]


def is_handle_gid(identifier: bytes | None, gid: bytes) -> bool:
    """Whether ``gid`` (from ``rmw_message_info_t``) is rmw_cyclonedds_cpp's instance-handle form: 8 bytes
    of handle, the rest zero (a GUID's entity id is never zero)."""
    return identifier == CYCLONE and any(gid[:8]) and not any(gid[8:])


class _CycloneGuids:
    """Writer GUIDs of rmw_cyclonedds_cpp's instance handles, resolved on the reader that took the sample."""

    def __init__(self) -> None:
        rcl = ctypes.CDLL(_loaded("librcl.so"))
        ddsc = ctypes.CDLL(_loaded("libddsc.so.0"))
        self._rmw_handle = rcl.rcl_subscription_get_rmw_handle
        self._rmw_handle.argtypes = [ctypes.c_void_p]
        self._rmw_handle.restype = ctypes.c_void_p
        self._matched = ddsc.dds_get_matched_publication_data
        self._matched.argtypes = [ctypes.c_int32, ctypes.c_uint64]
        self._matched.restype = ctypes.POINTER(_Endpoint)
        self._free = ddsc.dds_builtintopic_free_endpoint
        self._free.argtypes = [ctypes.POINTER(_Endpoint)]
        self._cache: dict[bytes, bytes] = {}

    def guid(self, pointer: int, gid: bytes) -> bytes:
        """The GUID of the writer whose instance handle is ``gid[:8]``, as seen by the rcl subscription at
        ``pointer``; ``gid`` itself when Cyclone does not know it (any more)."""
        got = self._cache.get(gid)
        if got is not None:
            return got
        rmw = self._rmw_handle(pointer)  # rmw_subscription_t: implementation_identifier, data, ...
        data = ctypes.c_void_p.from_address(rmw + ctypes.sizeof(ctypes.c_void_p)).value if rmw else None
        if not data:
            return gid
        reader = ctypes.c_int32.from_address(data).value  # CddsSubscription starts with its dds_entity_t
        ep = self._matched(reader, int.from_bytes(gid[:8], "little"))
        if not ep:
            return gid
        try:
            guid = bytes(ep.contents.key)
        finally:
            self._free(ep)
        self._cache[gid] = guid
        return guid


def publisher_gid(pointer: int) -> bytes:
    """The GUID of the writer of the rcl publisher at ``pointer`` (``_rclpy.Publisher.pointer``), what the
    graph lists as its ``endpoint_gid``, known as soon as the publisher exists (the graph lists it only once
    discovery has processed it, asynchronously on rmw_cyclonedds_cpp): ``rmw_get_gid_for_publisher``,
    and where that is rmw_cyclonedds_cpp's instance handle, Cyclone's ``dds_get_guid`` of the writer."""
    try:
        rcl = ctypes.CDLL(_loaded("librcl.so"))  # its dependencies give rmw_get_gid_for_publisher
    except OSError as exc:
        raise TransportError(f"cannot load rcl for a publisher's GID: {exc}") from None
    rcl.rcl_publisher_get_rmw_handle.argtypes = [ctypes.c_void_p]
    rcl.rcl_publisher_get_rmw_handle.restype = ctypes.c_void_p
    handle = rcl.rcl_publisher_get_rmw_handle(pointer)
    gid = _gid_struct(gid_storage_size())()
    rcl.rmw_get_gid_for_publisher.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    if not handle or rcl.rmw_get_gid_for_publisher(handle, ctypes.byref(gid)) != 0:
        raise TransportError("rmw_get_gid_for_publisher failed")
    data = gid16(bytes(gid.data))
    if not is_handle_gid(gid.implementation_identifier, data):
        return data
    # rmw_cyclonedds_cpp gives the instance handle here too: the GUID of its writer entity
    # (rmw_publisher_t: implementation_identifier, data -> CddsPublisher, which starts with its dds_entity_t)
    pub = ctypes.c_void_p.from_address(handle + ctypes.sizeof(ctypes.c_void_p)).value
    guid = (ctypes.c_uint8 * 16)()
    if not pub or ctypes.CDLL(_loaded("libddsc.so.0")).dds_get_guid(ctypes.c_int32.from_address(pub).value,
                                                                    ctypes.byref(guid)) != 0:
        raise TransportError("dds_get_guid failed for a publisher's writer")
    return bytes(guid)


class SerializedTake:
    """One reusable buffer and message info: :meth:`take` a subscription's next sample (one thread only)."""

    def __init__(self, capacity: int = 4096) -> None:
        try:
            rcl = ctypes.CDLL(_loaded("librcl.so"))
            rcutils = ctypes.CDLL(_loaded("librcutils.so"))
        except OSError as exc:
            raise TransportError(f"cannot load rcl for serialized takes: {exc}") from None
        rcutils.rcutils_get_default_allocator.restype = _Alloc
        rcutils.rcutils_uint8_array_init.argtypes = [ctypes.POINTER(_Bytes), ctypes.c_size_t, ctypes.POINTER(_Alloc)]
        self._alloc = rcutils.rcutils_get_default_allocator()
        self._buf = _Bytes()
        if rcutils.rcutils_uint8_array_init(ctypes.byref(self._buf), capacity, ctypes.byref(self._alloc)) != 0:
            raise TransportError("cannot allocate the serialized-message buffer")
        self._fini = rcutils.rcutils_uint8_array_fini
        self._fini.argtypes = [ctypes.POINTER(_Bytes)]
        self._info = _info_struct(gid_storage_size())()
        self._fn = rcl.rcl_take_serialized_message
        self._fn.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Bytes), ctypes.c_void_p, ctypes.c_void_p]
        self._fn.restype = ctypes.c_int
        self._buf_ref = ctypes.byref(self._buf)
        self._info_ref = ctypes.byref(self._info)
        self._gid = self._info.publisher_gid
        self._cyclone: _CycloneGuids | None = None

    def take(self, pointer: int) -> tuple[bytes, bytes] | None:
        """``(cdr, writer_gid)`` of the next sample of the rcl subscription at ``pointer``
        (``_rclpy.Subscription.pointer``), or None when there is none."""
        rc = self._fn(pointer, self._buf_ref, self._info_ref, None)
        if rc != 0:
            if rc == TAKE_FAILED:
                return None
            raise TransportError(f"rcl_take_serialized_message failed (code {rc})")
        buf = self._buf
        gid = gid16(bytes(self._gid.data))
        if is_handle_gid(self._gid.implementation_identifier, gid):
            if self._cyclone is None:
                self._cyclone = _CycloneGuids()
            gid = self._cyclone.guid(pointer, gid)
        return ctypes.string_at(buf.buffer, buf.buffer_length), gid

    def close(self) -> None:
        if self._buf.buffer:
            self._fini(self._buf_ref)

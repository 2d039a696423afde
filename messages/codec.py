"""msgpack wire form of messages: numpy arrays travel as an ext type that keeps dtype and shape."""
from __future__ import annotations

import math
import struct
import threading
from functools import lru_cache

import msgpack
import numpy as np

NDARRAY_EXT = 1
_ALLOWED_KINDS = "biuf"  # bool, signed, unsigned, float: never object arrays from the wire
# ext payload: dtype string length (u8), dtype string (e.g. '<f8'), ndim (u8), ndim x u32 shape, raw bytes
_DTYPES: dict[bytes, np.dtype] = {}


class CodecError(ValueError):
    """The bytes are not a msgpack payload of ours."""


@lru_cache(maxsize=256)
def _header(dtype_str: str, shape: tuple[int, ...]) -> bytes:
    dt = dtype_str.encode()
    return struct.pack(f"<B{len(dt)}sB{len(shape)}I", len(dt), dt, len(shape), *shape)


@lru_cache(maxsize=16)
def _shape_struct(ndim: int) -> struct.Struct:
    return struct.Struct(f"<{ndim}I")


def _default(obj):
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in _ALLOWED_KINDS:
            raise TypeError(f"cannot send a numpy array of dtype {obj.dtype}")
        return msgpack.ExtType(NDARRAY_EXT, _header(obj.dtype.str, obj.shape) + obj.tobytes())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (tuple, set, frozenset)):
        return list(obj)
    raise TypeError(f"cannot encode {type(obj).__name__}")


def _ext_hook(code: int, data: bytes):
    if code != NDARRAY_EXT:
        raise CodecError(f"unknown msgpack ext type {code}")
    try:
        n = data[0]
        dt = data[1 : 1 + n]
        dtype = _DTYPES.get(dt)
        if dtype is None:
            dtype = np.dtype(dt.decode())
            if dtype.kind not in _ALLOWED_KINDS:
                raise CodecError(f"array dtype {dtype} is not allowed")
            _DTYPES[dt] = dtype
        ndim = data[1 + n]
        offset = 2 + n + 4 * ndim
        shape = _shape_struct(ndim).unpack_from(data, 2 + n)
    except CodecError:
        raise
    except Exception as exc:  # noqa: BLE001 - any garbage inside the ext is a codec error
        raise CodecError(f"malformed array: {exc}") from None
    need = math.prod(shape) * dtype.itemsize
    if len(data) - offset != need:
        raise CodecError(f"array of shape {shape} and dtype {dtype} needs {need} bytes, got {len(data) - offset}")
    return np.frombuffer(data, dtype=dtype, offset=offset).reshape(shape).copy()


_local = threading.local()  # a Packer per thread: building one per message costs more than packing


def pack(obj) -> bytes:
    """Encode plain data (dicts, lists, numbers, strings, numpy arrays) to msgpack bytes."""
    packer = getattr(_local, "packer", None)
    if packer is None:
        packer = _local.packer = msgpack.Packer(default=_default, use_bin_type=True)
    try:
        return packer.pack(obj)
    except BaseException:
        packer.reset()  # a failed pack may leave partial bytes in the packer's buffer
        raise


def unpack(data: bytes):
    """Decode msgpack bytes made by `pack`; raises CodecError on anything else."""
    try:
        return msgpack.unpackb(data, ext_hook=_ext_hook, raw=False, strict_map_key=True)
    except CodecError:
        raise
    except Exception as exc:  # noqa: BLE001 - msgpack raises many types for garbage
        raise CodecError(f"not a msgpack payload: {exc}") from None

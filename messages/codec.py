"""msgpack wire form of messages: numpy arrays travel as an ext type that keeps dtype and shape."""
from __future__ import annotations

import math
import struct

import msgpack
import numpy as np

NDARRAY_EXT = 1
_ALLOWED_KINDS = "biuf"  # bool, signed, unsigned, float: never object arrays from the wire
# ext payload: dtype string length (u8), dtype string (e.g. '<f8'), ndim (u8), ndim x u32 shape, raw bytes
_DTYPES: dict[bytes, np.dtype] = {}


class CodecError(ValueError):
    """The bytes are not a msgpack payload of ours."""


def _default(obj):
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in _ALLOWED_KINDS:
            raise TypeError(f"cannot send a numpy array of dtype {obj.dtype}")
        arr = np.ascontiguousarray(obj)
        dt = arr.dtype.str.encode()
        header = struct.pack(f"<B{len(dt)}sB{arr.ndim}I", len(dt), dt, arr.ndim, *arr.shape)
        return msgpack.ExtType(NDARRAY_EXT, header + arr.tobytes())
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
        shape = struct.unpack_from(f"<{ndim}I", data, 2 + n)
    except CodecError:
        raise
    except Exception as exc:  # noqa: BLE001 - any garbage inside the ext is a codec error
        raise CodecError(f"malformed array: {exc}") from None
    need = math.prod(shape) * dtype.itemsize
    if len(data) - offset != need:
        raise CodecError(f"array of shape {shape} and dtype {dtype} needs {need} bytes, got {len(data) - offset}")
    return np.frombuffer(data, dtype=dtype, offset=offset).reshape(shape).copy()


def pack(obj) -> bytes:
    """Encode plain data (dicts, lists, numbers, strings, numpy arrays) to msgpack bytes."""
    return msgpack.packb(obj, default=_default, use_bin_type=True)


def unpack(data: bytes):
    """Decode msgpack bytes made by `pack`; raises CodecError on anything else."""
    try:
        return msgpack.unpackb(data, ext_hook=_ext_hook, raw=False, strict_map_key=True)
    except CodecError:
        raise
    except Exception as exc:  # noqa: BLE001 - msgpack raises many types for garbage
        raise CodecError(f"not a msgpack payload: {exc}") from None

"""msgpack wire form of messages: numpy arrays travel as an ext type that keeps dtype and shape.

msgspec's C encoder and decoder do the msgpack; this module adds the array ext type. Decoded arrays
are read-only views into the payload (no copy); an encoded array is copied once, into the payload.
"""
from __future__ import annotations

import math
import struct
from functools import lru_cache

import msgspec
import numpy as np

NDARRAY_EXT = 1
_ALLOWED_KINDS = "biuf"  # bool, signed, unsigned, float: never object arrays from the wire
# ext payload: dtype string length (u8), dtype string (e.g. '<f8'), ndim (u8), ndim x u32 shape, raw bytes
_LAYOUTS: dict[bytes, tuple] = {}   # array header -> (dtype, shape, count, nbytes), for the decoder
_MAX_LAYOUTS = 1024                 # varying shapes (e.g. batches) must not grow it without bound


class CodecError(ValueError):
    """The bytes are not a msgpack payload of ours."""


@lru_cache(maxsize=256)
def _header(dtype_str: str, shape: tuple[int, ...]) -> bytes:
    dt = dtype_str.encode()
    return struct.pack(f"<B{len(dt)}sB{len(shape)}I", len(dt), dt, len(shape), *shape)


def ext_prefix(code: int, size: int) -> bytes:
    """The msgpack bytes that start an ext value of `size` bytes (the smallest form, as encoders write)."""
    fixed = {1: 0xD4, 2: 0xD5, 4: 0xD6, 8: 0xD7, 16: 0xD8}.get(size)
    if fixed is not None:
        return bytes((fixed, code))
    if size <= 0xFF:
        return bytes((0xC7, size, code))
    if size <= 0xFFFF:
        return struct.pack(">BHB", 0xC8, size, code)
    return struct.pack(">BIB", 0xC9, size, code)


@lru_cache(maxsize=256)
def _array_prefix(dtype: np.dtype, shape: tuple[int, ...]) -> bytes:
    header = _header(dtype.str, shape)
    return ext_prefix(NDARRAY_EXT, len(header) + math.prod(shape) * dtype.itemsize) + header


def _raw(arr: np.ndarray):
    """The array's bytes as a buffer: the array's own memory when C-contiguous (no copy)."""
    if arr.dtype.kind not in _ALLOWED_KINDS:
        raise TypeError(f"cannot send a numpy array of dtype {arr.dtype}")
    return arr.data if arr.flags.c_contiguous else arr.tobytes()


def array_parts(arr: np.ndarray) -> tuple[bytes, object]:
    """An array as msgpack in two pieces to join into a payload: the ext prefix with the array
    header, and the raw bytes (see `_raw`), so the data is copied once, into the payload."""
    raw = _raw(arr)
    return _array_prefix(arr.dtype, arr.shape), raw


def _default(obj):
    if isinstance(obj, np.ndarray):
        return msgspec.msgpack.Ext(NDARRAY_EXT, b"".join((_header(obj.dtype.str, obj.shape), _raw(obj))))
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot encode {type(obj).__name__}")


def _layout(header: bytes) -> tuple:
    n = header[0]
    dtype = np.dtype(header[1 : 1 + n].decode())
    if dtype.kind not in _ALLOWED_KINDS:
        raise CodecError(f"array dtype {dtype} is not allowed")
    shape = struct.unpack_from(f"<{header[1 + n]}I", header, 2 + n)
    count = math.prod(shape)
    return dtype, shape, count, count * dtype.itemsize


def _ext_hook(code: int, data: memoryview):
    if code != NDARRAY_EXT:
        raise CodecError(f"unknown msgpack ext type {code}")
    try:
        n = data[0]
        offset = 2 + n + 4 * data[1 + n]
        header = bytes(data[:offset])
        layout = _LAYOUTS.get(header)
        if layout is None:
            if len(header) != offset:
                raise CodecError(f"malformed array: a header of {offset} bytes, got {len(header)}")
            layout = _layout(header)
            if len(_LAYOUTS) >= _MAX_LAYOUTS:
                _LAYOUTS.clear()
            _LAYOUTS[header] = layout
    except CodecError:
        raise
    except Exception as exc:  # noqa: BLE001 - any garbage inside the ext is a codec error
        raise CodecError(f"malformed array: {exc}") from None
    dtype, shape, count, need = layout
    if len(data) - offset != need:
        raise CodecError(f"array of shape {shape} and dtype {dtype} needs {need} bytes, got {len(data) - offset}")
    arr = np.frombuffer(data, dtype, count, offset)   # a view: the payload's bytes stay alive with it
    return arr if len(shape) == 1 else arr.reshape(shape)


# msgspec's Encoder and Decoder hold no state between calls: one of each serves every thread.
encode_plain = msgspec.msgpack.Encoder(enc_hook=_default).encode
_decode = msgspec.msgpack.Decoder(ext_hook=_ext_hook).decode


def pack(obj) -> bytes:
    """Encode plain data (dicts, lists, numbers, strings, numpy arrays) to msgpack bytes."""
    return encode_plain(obj)


def unpack(data: bytes):
    """Decode msgpack bytes made by `pack`; raises CodecError on anything else.

    Arrays are read-only views into `data` (writable only when `data` is a bytearray)."""
    try:
        return _decode(data)
    except CodecError:
        raise
    except Exception as exc:  # noqa: BLE001 - msgspec raises DecodeError, hooks may raise others
        raise CodecError(f"not a msgpack payload: {exc}") from None

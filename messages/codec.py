"""msgpack wire form of messages: numpy arrays travel as an ext type that keeps dtype and shape.

msgspec's C encoder and decoder do the msgpack; this module adds the array ext type. Decoded arrays
are read-only views into the payload (no copy).
"""
from __future__ import annotations

import math
import struct

import msgspec
import numpy as np

from touch4d.errors import Touch4dError

NDARRAY_EXT = 1
_ALLOWED_KINDS = "biuf"  # bool, signed, unsigned, float: never object arrays from the wire
# ext payload: dtype string length (u8), dtype string (e.g. '<f8'), ndim (u8), ndim x u32 shape, raw bytes
_LAYOUTS: dict[bytes, tuple] = {}   # array header -> (dtype, shape, count, nbytes), for the decoder
_MAX_LAYOUTS = 1024                 # varying shapes (e.g. batches) must not grow it without bound


class CodecError(Touch4dError, ValueError):
    """The bytes are not a msgpack payload of ours."""


def _header(dtype: np.dtype, shape: tuple[int, ...]) -> bytes:
    dt = dtype.str.encode()
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


_PREFIXES: dict[tuple, bytes] = {}   # (dtype, shape) -> msgpack ext prefix and array header
_SMALL = 512                         # bytes: a smaller array is copied by tobytes(), quicker than a view


def _default(obj):
    """msgspec's hook for what it cannot encode itself: a numpy array becomes the ext value, written
    as it is (msgspec.Raw)."""
    if obj.__class__ is np.ndarray:
        prefix = _PREFIXES.get((obj.dtype, obj.shape))
        if prefix is None:
            prefix = _prefix(obj)
        # tobytes: C order whatever the strides; a large C-contiguous array's own memory, not copied twice
        return msgspec.Raw(prefix + (obj.data if obj.nbytes > _SMALL and obj.flags.c_contiguous else obj.tobytes()))
    if isinstance(obj, np.ndarray):
        return _default(np.asarray(obj))
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot encode {type(obj).__name__}")


def _prefix(obj: np.ndarray) -> bytes:
    """The ext value's start for an array of this dtype and shape: msgpack's ext prefix, our array header."""
    if obj.dtype.kind not in _ALLOWED_KINDS:
        raise TypeError(f"cannot send a numpy array of dtype {obj.dtype}")
    header = _header(obj.dtype, obj.shape)
    prefix = ext_prefix(NDARRAY_EXT, len(header) + obj.nbytes) + header
    if len(_PREFIXES) >= _MAX_LAYOUTS:
        _PREFIXES.clear()
    _PREFIXES[(obj.dtype, obj.shape)] = prefix
    return prefix


def _layout(header: bytes) -> tuple:
    n = header[0]
    dtype = np.dtype(header[1 : 1 + n].decode())
    if dtype.kind not in _ALLOWED_KINDS:
        raise CodecError(f"array dtype {dtype} is not allowed")
    shape = struct.unpack_from(f"<{header[1 + n]}I", header, 2 + n)
    count = math.prod(shape)
    return dtype, None if len(shape) == 1 else shape, count, count * dtype.itemsize   # None: 1-D, no reshape


def _ext_hook(code: int, data: memoryview):
    if code != NDARRAY_EXT:
        raise CodecError(f"unknown msgpack ext type {code}")
    try:
        n = data[0]
        offset = 2 + n + 4 * data[1 + n]
        header = data[:offset].tobytes()
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
        raise CodecError(f"array of shape {shape or (count,)} and dtype {dtype} needs {need} bytes, "
                         f"got {len(data) - offset}")
    arr = np.frombuffer(data, dtype, count, offset)   # a view: the payload's bytes stay alive with it
    return arr if shape is None else arr.reshape(shape)


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

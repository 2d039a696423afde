"""JSON schemas for message types, and the JSON form of decoded messages (NaN -> null, arrays -> lists).

One schema per message type goes into every log, so `mcap info` and Foxglove can show the fields;
exports fill in the optional header fields a payload leaves out, so every row has the same columns.
Known types (`touch4d.messages.TYPES`) get a schema from their fields (each field's JSON schema is made
where its type is read, touch4d.messages.base, with its doc); anything else gets one inferred from a
sample message.
"""
from __future__ import annotations

import base64
import math
from typing import Any

import numpy as np

from touch4d.messages import TYPES
from touch4d.messages.base import array_schema

JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
MSGPACK_NOTE = "msgpack map; numpy arrays are msgpack ext type 1 holding [dtype.str, shape, raw bytes]"
_HEADER = {"type": {"type": "string", "description": "message type name"}}


def value_schema(value: Any) -> dict:
    """A JSON schema inferred from one decoded value (for types this build does not know)."""
    if isinstance(value, np.ndarray):
        return array_schema(value.ndim, value.dtype)
    if isinstance(value, bool):
        return {"type": "boolean"}
    if isinstance(value, int):
        return {"type": "integer"}
    if isinstance(value, float):
        return {"type": ["number", "null"]}
    if isinstance(value, str):
        return {"type": "string"}
    if isinstance(value, bytes):
        return {"type": "string", "contentEncoding": "base64"}
    if isinstance(value, dict):
        return {"type": "object", "properties": {str(k): value_schema(v) for k, v in value.items()}}
    if isinstance(value, (list, tuple)):
        return {"type": "array", "items": value_schema(value[0]) if value else {}}
    return {}


def message_schema(type_name: str, sample: dict | None = None) -> dict:
    """The JSON schema of a message type: from its class when known, else inferred from `sample`."""
    cls = TYPES.get(type_name)
    schema: dict = {"$schema": JSON_SCHEMA_DIALECT, "title": type_name or "unknown", "type": "object"}
    if cls is not None:
        if cls.__doc__:
            schema["description"] = cls.__doc__.strip().splitlines()[0]
        props = dict(_HEADER)
        for f in cls.FIELDS:
            props[f.name] = {**f.schema, "description": f.doc}
        schema["properties"] = props
        optional = {f.name for f in cls.FIELDS if f.optional}
        schema["required"] = [name for name in props if name not in optional]
    elif isinstance(sample, dict):
        schema["properties"] = {str(k): value_schema(v) for k, v in sample.items()}
    return schema


def with_optional_fields(data: Any) -> Any:
    """A decoded message map with the optional fields of its type filled in where absent (their default:
    recorded_stamp 0 for a live message), each in its declared place, so exported rows share columns."""
    cls = TYPES.get(data.get("type")) if isinstance(data, dict) and isinstance(data.get("type"), str) else None
    missing = {f.name: f.default for f in cls.FIELDS if f.optional and f.name not in data} if cls else None
    if not missing:
        return data
    names = [f.name for f in cls.FIELDS]
    out = {}
    for key, value in data.items():
        out[key] = value
        at = names.index(key) + 1 if key in names else len(names)
        while at < len(names) and names[at] in missing:
            out[names[at]] = missing.pop(names[at])
            at += 1
    out.update(missing)
    return out


def to_jsonable(value: Any) -> Any:
    """A decoded message value as plain JSON data: arrays to lists, NaN and infinities to null."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "f" and not np.isfinite(value).all():
            return to_jsonable(value.tolist())
        return value.tolist()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, bytes):
        return base64.b64encode(value).decode("ascii")
    return value

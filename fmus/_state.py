"""The byte format of a serialised seafmu FMU state: nothing in it can execute code.

    offset  size  field
    0       8     magic  b"SEAFMUST"
    8       2     format version, big-endian (FORMAT_VERSION)
    10      1     n = length of the GUID
    11      n     the FMU's GUID (ASCII), as in its modelDescription.xml
    11+n    8     payload length in bytes, big-endian
    19+n    32    SHA-256 of every byte before it and of the payload
    51+n    ...   payload: UTF-8 JSON of the plain-data tree (``components.state``), with arrays
                  and NumPy scalars as {"$t": "nd"/"sc", "dtype", "shape", "order", "data": base64}

Decoding checks, in this order: length, magic, version, GUID, payload length, checksum, JSON,
then every array's dtype (numeric only), shape and byte count. The checksum catches corruption;
it is no signature: a state file is trusted data in the sense that it decides the model's
numbers, but it never decides which code runs (no pickle, no class or function names looked up
to be called).
"""

from __future__ import annotations

import base64
import hashlib
import json
import math
import re
import struct
from typing import Any

import numpy as np

MAGIC = b"SEAFMUST"
FORMAT_VERSION = 1
_HEAD = struct.Struct(">8sHB")
_LEN = struct.Struct(">Q")
_DIGEST = 32
_DTYPE = re.compile(r"^[<>|=]?[biufc][1-9][0-9]?$")


class StateFormatError(ValueError):
    """Bytes that are not a state of this FMU; the message says why, in one line."""


def encode(tree: Any, guid: str) -> bytes:
    payload = json.dumps(_to_json(tree), separators=(",", ":"), allow_nan=True).encode("utf-8")
    g = guid.encode("ascii")
    head = _HEAD.pack(MAGIC, FORMAT_VERSION, len(g)) + g + _LEN.pack(len(payload))
    return head + hashlib.sha256(head + payload).digest() + payload


def decode(data: bytes, guid: str) -> Any:
    data = bytes(data)
    if len(data) < _HEAD.size:
        raise StateFormatError(f"not a seafmu FMU state: {len(data)} bytes, shorter than the header")
    magic, version, n = _HEAD.unpack_from(data)
    if magic != MAGIC:
        raise StateFormatError("not a seafmu FMU state (no SEAFMUST header)")
    if version != FORMAT_VERSION:
        raise StateFormatError(f"state format version {version}, this FMU reads version {FORMAT_VERSION}")
    start = _HEAD.size + n + _LEN.size + _DIGEST
    if len(data) < start:
        raise StateFormatError("truncated state header")
    theirs = data[_HEAD.size : _HEAD.size + n].decode("ascii", "replace")
    if theirs != guid:
        raise StateFormatError(f"state of another FMU (GUID {theirs}; this FMU has GUID {guid})")
    (length,) = _LEN.unpack_from(data, _HEAD.size + n)
    if len(data) - start != length:
        raise StateFormatError(f"state payload of {len(data) - start} bytes, the header says {length}")
    digest = data[start - _DIGEST : start]
    if hashlib.sha256(data[: start - _DIGEST] + data[start:]).digest() != digest:
        raise StateFormatError("corrupt state (SHA-256 checksum mismatch)")
    try:
        raw = json.loads(data[start:].decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise StateFormatError(f"corrupt state payload ({type(exc).__name__})") from None
    try:
        return _from_json(raw)
    except RecursionError:
        raise StateFormatError("corrupt state payload (nested too deeply)") from None


def _to_json(v: Any) -> Any:
    if isinstance(v, dict):
        kind = v.get("$t")
        if kind == "nd":
            a = v["value"]
            order = "F" if a.flags.f_contiguous and not a.flags.c_contiguous else "C"
            return {"$t": "nd", "id": v["id"], "dtype": a.dtype.str, "shape": list(a.shape), "order": order,
                    "data": base64.b64encode(a.tobytes(order=order)).decode("ascii")}
        if kind == "sc":
            s = v["value"]
            return {"$t": "sc", "dtype": s.dtype.str, "data": base64.b64encode(s.tobytes()).decode("ascii")}
        return {k: _to_json(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_to_json(x) for x in v]
    if type(v) is float and not math.isfinite(v):
        return v  # json writes NaN / Infinity / -Infinity and reads them back
    return v


def _dtype(s: Any) -> np.dtype:
    if not isinstance(s, str) or not _DTYPE.match(s):
        raise StateFormatError(f"corrupt state payload (dtype {s!r})")
    try:
        dt = np.dtype(s)
    except TypeError:
        raise StateFormatError(f"corrupt state payload (dtype {s!r})") from None
    if dt.kind not in "biufc":
        raise StateFormatError(f"corrupt state payload (dtype {s!r})")
    return dt


def _bytes(s: Any) -> bytes:
    if not isinstance(s, str):
        raise StateFormatError("corrupt state payload (array data)")
    try:
        return base64.b64decode(s.encode("ascii"), validate=True)
    except (ValueError, UnicodeEncodeError):
        raise StateFormatError("corrupt state payload (array data)") from None


def _from_json(v: Any) -> Any:
    if isinstance(v, dict):
        kind = v.get("$t")
        if kind == "nd":
            dt = _dtype(v.get("dtype"))
            shape = v.get("shape")
            order = v.get("order")
            good_shape = isinstance(shape, list) and all(type(d) is int and d >= 0 for d in shape)
            if not good_shape or order not in ("C", "F"):
                raise StateFormatError("corrupt state payload (array shape)")
            raw = _bytes(v.get("data"))
            if len(raw) != math.prod(shape) * dt.itemsize:
                raise StateFormatError("corrupt state payload (array size)")
            a = np.frombuffer(raw, dtype=dt).reshape(shape, order=order).copy(order=order)
            return {"$t": "nd", "id": v.get("id"), "value": a}
        if kind == "sc":
            dt = _dtype(v.get("dtype"))
            raw = _bytes(v.get("data"))
            if len(raw) != dt.itemsize:
                raise StateFormatError("corrupt state payload (scalar size)")
            return {"$t": "sc", "value": np.frombuffer(raw, dtype=dt)[0]}
        return {k: _from_json(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_from_json(x) for x in v]
    return v

"""Lossless JSON form of NumPy arrays, for result files and stored campaign and sweep outputs."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["encode_array", "decode_array", "COMPACT_ABOVE"]

#: float arrays of more elements than this are stored as base64 of their little-endian bytes
COMPACT_ABOVE = 64


def encode_array(a: np.ndarray) -> dict:
    """Lossless JSON form of an array: shape plus values, non-finite values as strings; a float
    array of more than ``COMPACT_ABOVE`` elements as base64 of its little-endian float64 bytes
    (about 11 characters a value instead of 20-25, the bits kept)."""
    a = np.asarray(a)
    if a.dtype.kind == "f" and a.size > COMPACT_ABOVE:
        import base64

        raw = np.ascontiguousarray(a, dtype="<f8").tobytes()
        return {"shape": list(a.shape), "dtype": "<f8", "base64": base64.b64encode(raw).decode("ascii")}
    flat = []
    for v in a.reshape(-1).tolist():
        if isinstance(v, float) and not math.isfinite(v):
            flat.append("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
        else:
            flat.append(v)
    return {"shape": list(a.shape), "values": flat}


def decode_array(d: dict, dtype=float) -> np.ndarray:
    """Inverse of :func:`encode_array`."""
    if "base64" in d:
        import base64
        import binascii

        try:
            raw = base64.b64decode(d["base64"], validate=True)
        except (binascii.Error, TypeError) as err:
            raise ValueError(f"an array's base64 text is damaged ({err})") from None
        if d.get("dtype") != "<f8" or len(raw) != 8 * math.prod(d["shape"]):
            raise ValueError(f"an array's bytes do not match its shape {d['shape']} and dtype {d.get('dtype')!r}")
        return np.frombuffer(raw, dtype="<f8").astype(dtype).reshape(d["shape"])
    values = [float(v) if isinstance(v, str) else v for v in d["values"]]
    return np.array(values, dtype=dtype).reshape(d["shape"])

"""CDR blocks (format 3): a block topic's message as plain little-endian CDR, encoded and decoded with numpy.

The layout of each block topic is a ROS 2 message definition
(:class:`~.cdr_layouts.CdrBlock`): one sequence per field, element ``i`` (row
``i``, row-major) of every sequence is sample ``i``. Plain CDR, as ROS 2 and
Foxglove read it: the 4-byte encapsulation header ``00 01 00 00``, then each
sequence as a ``uint32`` count aligned to 4 and its elements aligned to their
size (8 for ``int64``/``float64``; no padding for an empty sequence), alignment
counted from the end of the header; a ``string`` is a ``uint32`` byte count
(with the terminating NUL) aligned to 4, the UTF-8 bytes and a NUL; a ``bool``
is one byte. Every field is written (an absent one as an empty sequence), so
the message is valid for its definition whatever the block holds.

Encoding is one ``tobytes`` per field (the paddings and counts cached per block
size), no per-value Python work; decoding is
one ``np.frombuffer`` per field.
"""

from __future__ import annotations

import operator
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from hapticlab.sessions.recording.cdr_layouts import CDR_HEADER, CdrBlock, CdrColumn

_U32 = struct.Struct("<I")
_I64 = np.dtype("<i8")
_F64 = np.dtype("<f8")
_NO_ARRAY = np.empty(0, dtype=_F64)


class CdrBlockError(ValueError):
    """A CDR block message that does not fit its definition (the reader makes it a RecordingError)."""


_I64_MAX = (1 << 63) - 1


def _times(topic: str, t_ns: Any) -> tuple[np.ndarray, int]:
    """``t_ns`` as a non-empty int64 array of non-negative times, and its last; ``ValueError`` naming ``topic``."""
    bad = f"{topic}: a block needs t_ns, a non-empty list of integer times (ns)"
    if type(t_ns) is np.ndarray and t_ns.dtype == _I64 and t_ns.ndim == 1 and t_ns.size:
        values = t_ns.tolist()  # the bounds checked on a few Python ints: cheaper than numpy's reductions
        arr = t_ns
    elif type(t_ns) is list and t_ns and all(type(t) is int for t in t_ns):
        values, arr = t_ns, None
    else:
        try:
            values = [operator.index(t) for t in t_ns]  # numpy integers too; floats raise TypeError
        except TypeError:
            raise ValueError(bad) from None
        if not values:
            raise ValueError(bad)
        arr = None
    first, last = min(values), max(values)
    if first < 0 or last > _I64_MAX:
        raise ValueError(f"{topic}: t_ns must be non-negative 64-bit integers (ns), got {first}..{last}")
    return (np.array(values, dtype=_I64) if arr is None else arr), values[-1]


def _column(topic: str, column: CdrColumn, value: Any, n: int) -> np.ndarray:
    """``value`` as ``column``'s array of ``n`` samples (shape (n,) or (n, width)); TypeError/ValueError if not."""
    shape = (n,) if column.width == 1 else (n, column.width)
    if type(value) is np.ndarray and value.dtype == column.dtype and value.shape == shape:
        return value  # the fast path: what the live loop hands over
    try:
        arr = np.asarray(value, dtype=_F64) if column.ros_type == "float64" else np.asarray(value)
    except (TypeError, ValueError) as exc:  # ragged lists, strings in a float field, ...
        raise ValueError(
            f"{topic}: field {column.name!r} is not {n} samples of {column.width} {column.ros_type} ({exc})"
        ) from None
    if arr.shape != shape:
        raise ValueError(
            f"{topic}: field {column.name!r} does not hold one value for each of its {n} samples "
            f"(shape {arr.shape}, expected {shape})"
        )
    if column.ros_type == "int64":
        if arr.dtype.kind not in "iub" or (arr.dtype.kind == "u" and arr.size and arr.max() > _I64_MAX):
            raise TypeError(f"{topic}: field {column.name!r} must hold 64-bit integers, got {arr.dtype}")
    elif column.ros_type == "bool" and arr.dtype.kind not in "biu":
        raise TypeError(f"{topic}: field {column.name!r} must hold flags (bool), got {arr.dtype}")
    return arr.astype(column.dtype, copy=False)


_layouts: dict[tuple[str, int, tuple[bool, ...]], tuple[list[bytes], int]] = {}


def _layout(block: CdrBlock, n: int, present: tuple[bool, ...]) -> tuple[list[bytes], int]:
    """The bytes before each column's elements (padding, uint32 count, padding) for ``n`` samples with the
    columns ``present``, and the offset after the last column (from the end of the header); cached."""
    key = (block.name, n, present)
    layout = _layouts.get(key)
    if layout is None:
        prefixes: list[bytes] = []
        offset = 0
        for column, here in zip(block.columns, present):
            count = n * column.width if here else 0
            pad = -offset % 4
            offset += pad + 4
            align = -offset % column.dtype.itemsize if count else 0
            offset += align + count * column.dtype.itemsize
            prefixes.append(bytes(pad) + _U32.pack(count) + bytes(align))
        if len(_layouts) > 4096:  # block sizes vary little in a session; never grow without bound
            _layouts.clear()
        layout = _layouts[key] = (prefixes, offset)
    return layout


def encode_block(
    block: CdrBlock, topic: str, message: Mapping[str, Any], encode_json: Callable[[Any], bytes]
) -> tuple[bytes, int]:
    """``message`` (``t_ns`` and the block's fields, lists or numpy arrays) as CDR bytes, and its log time.

    A missing field is written as an empty sequence (read back as absent);
    ``params`` (estimator blocks) is encoded with ``encode_json`` (to UTF-8 JSON bytes). Raises
    ``ValueError`` for bad times, a field of the wrong length or a field the
    block does not have, ``TypeError`` for values of the wrong type.
    """
    if not block.field_names.issuperset(message):
        unknown = sorted(set(message) - block.field_names)
        raise ValueError(
            f"{topic}: {block.name} has no field {unknown[0]!r}; "
            f"fields: {', '.join(c.name for c in block.columns)}" + (", params, cov_diag" if block.report else "")
        )
    t, t_last = _times(topic, message.get("t_ns"))
    n = t.size
    arrays: list[np.ndarray | None] = [t]
    for column in block.columns[1:]:
        value = message.get(column.name)
        arrays.append(None if value is None else _column(topic, column, value, n))
    prefixes, offset = _layout(block, n, tuple(a is not None for a in arrays))
    parts = [CDR_HEADER]
    for prefix, arr in zip(prefixes, arrays):
        parts.append(prefix)
        if arr is not None:
            parts.append(arr.tobytes())
    if block.report:
        params = message.get("params")
        text = b"" if params is None else encode_json(params)
        pad = -offset % 4
        parts.append(bytes(pad) + _U32.pack(len(text) + 1) + text + b"\x00")
        offset += pad + 4 + len(text) + 1
        cov_diag = message.get("cov_diag")
        try:
            cov = _NO_ARRAY if cov_diag is None else np.asarray(cov_diag, dtype=_F64)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"{topic}: cov_diag must be a list of floats ({exc})") from None
        if cov.ndim != 1:
            raise TypeError(f"{topic}: cov_diag must be a flat list of floats, got shape {cov.shape}")
        pad = -offset % 4
        offset += pad + 4
        align = -offset % 8 if cov.size else 0
        parts.append(bytes(pad) + _U32.pack(cov.size) + bytes(align) + cov.tobytes())
        parts.append(b"\x01" if cov_diag is not None else b"\x00")
    return b"".join(parts), t_last


@dataclass(frozen=True)
class BlockLayout:
    """Where each field of one CDR block message lies (:func:`block_layout`); every block of the same
    topic with the same sequence counts has the same layout.

    Attributes:
        n: the block's samples.
        fields: ``(name, start, nbytes, dtype, width)`` of every field present, ``start`` counted from the
            message's first byte (the encapsulation header included).
        count_positions: where each sequence's ``uint32`` count lies (to check another message has the same).
        params: ``(start, count)`` of the params string (estimator blocks), else None.
        cov_diag: ``(start, count)`` of the cov_diag sequence, else None.
        has_cov_diag: the flag byte after it is set.
    """

    n: int
    fields: tuple[tuple[str, int, int, np.dtype, int], ...]
    count_positions: tuple[int, ...]
    params: tuple[int, int] | None = None
    cov_diag: tuple[int, int] | None = None
    has_cov_diag: bool = False

    @property
    def reports(self) -> bool:
        """The block carries its estimator's params or cov_diag (a block in a hundred)."""
        return bool(self.params and self.params[1] > 1) or self.has_cov_diag


def block_layout(block: CdrBlock, data: bytes) -> BlockLayout:
    """The layout of a CDR block message; :class:`CdrBlockError` when the bytes do not fit the definition."""
    size = len(data)
    if size < 4 or data[:2] != CDR_HEADER[:2]:
        raise CdrBlockError(f"not little-endian plain CDR (header {data[:4].hex(' ')})")
    offset = 4
    counts: list[int] = []

    def sequence(itemsize: int, what: str) -> tuple[int, int]:
        nonlocal offset
        offset += -(offset - 4) % 4
        if offset + 4 > size:
            raise CdrBlockError(f"ends before {what} ({size} bytes)")
        counts.append(offset)
        (count,) = _U32.unpack_from(data, offset)
        offset += 4
        if count:
            offset += -(offset - 4) % itemsize
        start, offset = offset, offset + count * itemsize
        if offset > size:
            raise CdrBlockError(f"{what} runs past the end ({count} values, {size} bytes)")
        return start, count

    fields = []
    n = 0
    for column in block.columns:
        dtype = column.dtype
        start, count = sequence(dtype.itemsize, column.name)
        if column is block.columns[0]:
            if not count:
                raise CdrBlockError("t_ns is not a non-empty list of integer times")
            n = count
        elif not count:
            continue  # not recorded with this block
        if count != n * column.width:
            raise CdrBlockError(f"field {column.name!r} does not hold one value for each of its {n} samples")
        fields.append((column.name, start, count * dtype.itemsize, dtype, column.width))
    if not block.report:
        return BlockLayout(n, tuple(fields), tuple(counts))
    params = sequence(1, "params")
    if params[1] and data[offset - 1] != 0:
        raise CdrBlockError("params is not a NUL-terminated string")
    cov = sequence(8, "cov_diag")
    if offset + 1 > size:
        raise CdrBlockError(f"ends before has_cov_diag ({size} bytes)")
    return BlockLayout(n, tuple(fields), tuple(counts), params, cov, bool(data[offset]))


def decode_block(block: CdrBlock, data: bytes, decode_json: Callable[[str], Any]) -> dict[str, Any]:
    """A CDR block message as ``{field: array}`` (``(n,)`` or ``(n, width)``; an empty sequence: absent).

    Estimator blocks add ``params`` (decoded with ``decode_json``) and
    ``cov_diag`` (a list) when reported with the block. Raises
    :class:`CdrBlockError` when the bytes do not fit the definition.
    """
    layout = block_layout(block, data)
    out: dict[str, Any] = {}
    for name, start, nbytes, dtype, width in layout.fields:
        arr = np.frombuffer(data, dtype=dtype, count=nbytes // dtype.itemsize, offset=start)
        out[name] = arr if width == 1 else arr.reshape(layout.n, width)
    if layout.params is not None:
        start, count = layout.params
        if count > 1:
            out["params"] = decode_json(data[start : start + count - 1].decode("utf-8"))
        if layout.has_cov_diag:
            assert layout.cov_diag is not None  # block_layout reads the flag after the sequence
            start, count = layout.cov_diag
            out["cov_diag"] = listed(np.frombuffer(data, dtype=_F64, count=count, offset=start))
    return out


def listed(arr: np.ndarray) -> list[Any]:
    """``arr.tolist()`` with non-finite floats as None (as formats 1 and 2 read their JSON null)."""
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        # numpy's stubs take no None as a value; np.where broadcasts it as an object
        return np.where(np.isfinite(arr), arr.astype(object), None).tolist()  # type: ignore[call-overload]
    return arr.tolist()

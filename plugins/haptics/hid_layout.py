"""RawHID report layouts: where each field of the ``hid`` plugin's OUT and IN reports sits, and how it is encoded.

Every firmware lays its reports out differently, so the layout is config
(``[haptic.layout]``, or a preset's name): the report id, and for the OUT
report (host → device) and the IN report (device → host) each field's byte
offset, type and scale (SI units per count). :meth:`RawHidLayout.from_config`
checks a layout once, naming the key of anything wrong;
:meth:`RawHidLayout.out_report` writes an OUT report, its force quantised by
:func:`encode_force` without ever exceeding the limit.

Types: ``u8 i8 u16le i16le u32le i32le f32le f64le`` and the big-endian
``u16be i16be u32be i32be f32be f64be``. Fields (offsets are into the report's
data, after the report id when reports are numbered)::

    OUT  force_x force_y force_z   required, N per count
         seq                       optional, unsigned, wraps at the type's width
         flags                     optional, unsigned; bit 0 = force enabled
    IN   position_x/_y/_z          required, m per count
         velocity_x/_y/_z          optional (all three or none), m/s per count
         buttons                   optional, unsigned bit mask
         echo                      optional, unsigned: the seq of the OUT report answered (needs OUT seq)
         status                    optional, unsigned: bit 0 watchdog, 1 clamped, 2 fault (as ``framing``)

The preset ``layout = "teensy-rawhid"``: a Teensy (Teensyduino "Raw HID" USB
type: vendor 0x16C0, product 0x0486, usage page 0xFFAB, usage 0x0200; it also
shows a serial-emulation interface under the same ids, hence the usage page)
or any board running the same sketch layout. Unnumbered 64-byte reports::

    OUT  bytes 0-3 force_x f32le N, 4-7 force_y, 8-11 force_z,
         12-13 seq u16le, 14 flags u8 (bit 0: enable), 15-63 zero
    IN   bytes 0-3 position_x i32le µm (1e-6 m per count), 4-7 position_y, 8-11 position_z,
         12-13 velocity_x i16le mm/s (1e-3 m/s per count, ±32.767 m/s), 14-15 velocity_y, 16-17 velocity_z,
         18 buttons u8, 19 status u8, 20-21 echo u16le, 22-63 zero
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from hapticlab.core.host.options import OptionError, choice, integer, is_number

MAX_REPORT_SIZE = 64
"""Bytes of data in one report: the full-speed interrupt packet."""

FLAG_ENABLE = 1 << 0
"""OUT ``flags`` bit: the device may render the force (clear: zero, whatever the force fields say)."""


@dataclass(frozen=True, slots=True)
class FieldType:
    """A field's encoding: struct format, size in bytes, and the range of its counts."""

    name: str
    fmt: struct.Struct
    is_float: bool
    lo: float
    hi: float

    @property
    def size(self) -> int:
        return self.fmt.size


def _int_type(name: str, code: str, bits: int, signed: bool) -> FieldType:
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    return FieldType(name, struct.Struct(code), False, lo, hi)


F32_MAX = float(np.finfo(np.float32).max)
F64_MAX = float(np.finfo(np.float64).max)
TYPES: dict[str, FieldType] = {
    t.name: t
    for t in (
        _int_type("u8", "<B", 8, False),
        _int_type("i8", "<b", 8, True),
        _int_type("u16le", "<H", 16, False),
        _int_type("i16le", "<h", 16, True),
        _int_type("u32le", "<I", 32, False),
        _int_type("i32le", "<i", 32, True),
        _int_type("u16be", ">H", 16, False),
        _int_type("i16be", ">h", 16, True),
        _int_type("u32be", ">I", 32, False),
        _int_type("i32be", ">i", 32, True),
        FieldType("f32le", struct.Struct("<f"), True, -F32_MAX, F32_MAX),
        FieldType("f32be", struct.Struct(">f"), True, -F32_MAX, F32_MAX),
        FieldType("f64le", struct.Struct("<d"), True, -F64_MAX, F64_MAX),
        FieldType("f64be", struct.Struct(">d"), True, -F64_MAX, F64_MAX),
    )
}

UNSIGNED_TYPES = tuple(name for name, t in TYPES.items() if not t.is_float and t.lo == 0)
"""The types a counter (seq, flags, buttons, echo, status) may have."""

FORCE_FIELDS = ("force_x", "force_y", "force_z")
POSITION_FIELDS = ("position_x", "position_y", "position_z")
VELOCITY_FIELDS = ("velocity_x", "velocity_y", "velocity_z")
COUNTER_FIELDS = ("seq", "flags", "buttons", "echo", "status")
OUT_FIELDS = (*FORCE_FIELDS, "seq", "flags")
IN_FIELDS = (*POSITION_FIELDS, *VELOCITY_FIELDS, "buttons", "echo", "status")


@dataclass(frozen=True, slots=True)
class Field:
    """One field of a report.

    Attributes:
        name: what it carries (``force_x``, ``position_y``, ``seq``, ...).
        offset: its first byte in the report's data (after a report id), bytes.
        type: its encoding.
        scale: SI units per count (N, m or m/s per count; 1 for counters).
    """

    name: str
    offset: int
    type: FieldType
    scale: float = 1.0

    @property
    def end(self) -> int:
        """One past its last byte."""
        return self.offset + self.type.size

    def counts(self, value: float, toward_zero: bool = False) -> int | float:
        """``value`` (SI) as this field's counts: non-finite → 0; saturated at the type's range, never wrapped.

        Integers round to the nearest count (``toward_zero``: truncate, so the
        magnitude never grows); floats round to the type's precision when packed.
        """
        x = value / self.scale if math.isfinite(value) else 0.0
        if self.type.is_float:
            if not math.isfinite(x):  # value/scale overflowed
                x = math.copysign(self.type.hi, x)
            return min(max(x, self.type.lo), self.type.hi)
        if not math.isfinite(x):
            x = math.copysign(self.type.hi, x)
        n = math.trunc(x) if toward_zero else round(x)
        return min(max(n, int(self.type.lo)), int(self.type.hi))

    def pack_into(self, buffer: bytearray, value: float, toward_zero: bool = False) -> None:
        self.type.fmt.pack_into(buffer, self.offset, self.counts(value, toward_zero))

    def unpack(self, data: bytes | bytearray) -> float:
        """The field's value in SI units (an int for counters)."""
        (n,) = self.type.fmt.unpack_from(data, self.offset)
        return n if self.name in COUNTER_FIELDS else n * self.scale


@dataclass(frozen=True, slots=True)
class ReportLayout:
    """One direction's report: its id (0: unnumbered), its data size (bytes), its fields by name."""

    report_id: int
    size: int
    fields: dict[str, Field]

    def encode(self, values: dict[str, float]) -> bytes:
        """The report's data (without the report id): every field of the layout found in ``values``, the rest zero."""
        buffer = bytearray(self.size)
        for name, f in self.fields.items():
            if name in values:
                f.pack_into(buffer, values[name])
        return bytes(buffer)

    def decode(self, data: bytes) -> dict[str, float]:
        """Every field's value from the report's data (without the report id), SI units."""
        return {name: f.unpack(data) for name, f in self.fields.items()}


@dataclass(frozen=True, slots=True)
class RawHidLayout:
    """Both reports of a device: ``out`` (host → device) and ``inp`` (device → host)."""

    out: ReportLayout
    inp: ReportLayout

    @classmethod
    def from_config(cls, spec: str | dict, where: str = "layout") -> RawHidLayout:
        """From a preset name or a table ``{report_id, size, out = {field = {offset, type, scale}}, in = {...}}``.

        Raises OptionError naming the key on anything wrong (``layout.out.force_y: ...``; the session
        puts its table in front: ``haptic.layout.out.force_y``).
        """
        if isinstance(spec, str):
            choice(where, spec, tuple(PRESETS), hint=" (a preset) or a table describing the reports")
            return cls.from_config(PRESETS[spec]["layout"], f"{where} (preset {spec})")
        if not isinstance(spec, dict):
            raise OptionError(where, f"must be a preset name or a table, got {spec!r}")
        unknown = set(spec) - {"report_id", "size", "out", "in"}
        if unknown:
            raise OptionError(f"{where}.{sorted(unknown)[0]}", "unknown key; keys: report_id, size, out, in")
        report_id = integer(
            f"{where}.report_id", spec.get("report_id", 0), minimum=0, maximum=255, hint=" (0: unnumbered reports)"
        )
        size = integer(
            f"{where}.size",
            spec.get("size", MAX_REPORT_SIZE),
            minimum=1,
            maximum=MAX_REPORT_SIZE,
            hint=" (bytes of report data)",
        )
        out = _report(spec.get("out"), f"{where}.out", report_id, size, OUT_FIELDS, FORCE_FIELDS)
        inp = _report(spec.get("in"), f"{where}.in", report_id, size, IN_FIELDS, POSITION_FIELDS)
        velocity = [n for n in VELOCITY_FIELDS if n in inp.fields]
        if velocity and len(velocity) < 3:
            missing = next(n for n in VELOCITY_FIELDS if n not in inp.fields)
            raise OptionError(f"{where}.in.{missing}", f"required with {velocity[0]} (velocity is all three or none)")
        if "echo" in inp.fields and "seq" not in out.fields:
            raise OptionError(f"{where}.in.echo", "needs a seq field in the OUT report to echo")
        return cls(out, inp)

    def check_reach(self, max_force: float) -> None:
        """OptionError unless every force field holds ``max_force`` N: saturating below it would turn the force."""
        for name in FORCE_FIELDS:
            f = self.out.fields[name]
            reach = f.type.hi * abs(f.scale)
            if reach < max_force:
                raise OptionError(
                    f"layout.out.{name}",
                    f"{f.type.name} at {f.scale:g} N per count reaches only {reach:g} N, "
                    f"below device_max_force {max_force:g} N",
                )

    def out_report(self, force_D: np.ndarray, max_force: float, seq: int, enabled: bool) -> bytes:
        """One OUT report as hidapi writes it, report id first (0 when unnumbered): the force (already clamped
        to ``max_force`` N) quantised by :func:`encode_force`, ``seq`` wrapped to its field, the enable flag."""
        data = bytearray(encode_force(self.out, force_D, max_force))
        seq_field = self.out.fields.get("seq")
        if seq_field is not None:
            seq_field.type.fmt.pack_into(data, seq_field.offset, seq & int(seq_field.type.hi))
        flags_field = self.out.fields.get("flags")
        if flags_field is not None:
            flags_field.pack_into(data, FLAG_ENABLE if enabled else 0)
        return bytes([self.out.report_id]) + bytes(data)

    def echo_mask(self) -> int | None:
        """The bits of an OUT seq that the IN echo carries (the narrower of the two fields); None without echo."""
        echo = self.inp.fields.get("echo")
        if echo is None:
            return None
        width = min(f.type.size for f in (self.out.fields.get("seq"), echo) if f is not None)
        return (1 << (8 * width)) - 1

    def in_read_size(self) -> int:
        """Bytes one IN report takes in hidapi's ``read``: its data, after the report id when numbered."""
        return self.inp.size + (1 if self.inp.report_id else 0)


def _report(
    table: Any, where: str, report_id: int, size: int, allowed: tuple[str, ...], required: tuple[str, ...]
) -> ReportLayout:
    if not isinstance(table, dict):
        raise OptionError(where, f"must be a table of fields ({', '.join(allowed)}), got {table!r}")
    fields: dict[str, Field] = {}
    for name, spec in table.items():
        key = f"{where}.{name}"
        if name not in allowed:
            raise OptionError(key, f"unknown field; fields: {', '.join(allowed)}")
        if not isinstance(spec, dict):
            raise OptionError(key, f"must be a table {{offset = ..., type = ..., scale = ...}}, got {spec!r}")
        extra = set(spec) - {"offset", "type", "scale"}
        if extra:
            raise OptionError(f"{key}.{sorted(extra)[0]}", "unknown key; keys: offset, type, scale")
        type_name = choice(f"{key}.type", spec.get("type"), tuple(TYPES))
        ftype = TYPES[type_name]
        offset = integer(f"{key}.offset", spec.get("offset"), minimum=0, hint=" (bytes)")
        if offset + ftype.size > size:
            raise OptionError(
                f"{key}.offset", f"bytes {offset}..{offset + ftype.size - 1} end past the {size}-byte report"
            )
        scale = spec.get("scale", 1.0)
        if name in COUNTER_FIELDS:
            choice(f"{key}.type", type_name, UNSIGNED_TYPES, hint=f" ({name} is a count)")
            if scale != 1:
                raise OptionError(f"{key}.scale", f"must be 1 ({name} is a count), got {scale!r}")
        if not (is_number(scale) and math.isfinite(scale) and scale != 0):
            raise OptionError(f"{key}.scale", f"must be a finite non-zero number (SI units per count), got {scale!r}")
        field_ = Field(name, offset, ftype, float(scale))
        for other in fields.values():
            if field_.offset < other.end and other.offset < field_.end:
                raise OptionError(
                    key,
                    f"bytes {field_.offset}..{field_.end - 1} overlap {other.name} "
                    f"(bytes {other.offset}..{other.end - 1})",
                )
        fields[name] = field_
    for name in required:
        if name not in fields:
            raise OptionError(f"{where}.{name}", f"required (fields {', '.join(required)} must be described)")
    return ReportLayout(report_id, size, fields)


def _f(offset: int, type_: str, scale: float = 1.0) -> dict[str, Any]:
    return {"offset": offset, "type": type_, "scale": scale}


PRESETS: dict[str, dict[str, Any]] = {
    "teensy-rawhid": {
        "vendor_id": 0x16C0,
        "product_id": 0x0486,
        "usage_page": 0xFFAB,
        "usage": 0x0200,
        "layout": {
            "report_id": 0,
            "size": 64,
            "out": {
                "force_x": _f(0, "f32le"),
                "force_y": _f(4, "f32le"),
                "force_z": _f(8, "f32le"),
                "seq": _f(12, "u16le"),
                "flags": _f(14, "u8"),
            },
            "in": {
                "position_x": _f(0, "i32le", 1e-6),
                "position_y": _f(4, "i32le", 1e-6),
                "position_z": _f(8, "i32le", 1e-6),
                "velocity_x": _f(12, "i16le", 1e-3),
                "velocity_y": _f(14, "i16le", 1e-3),
                "velocity_z": _f(16, "i16le", 1e-3),
                "buttons": _f(18, "u8"),
                "status": _f(19, "u8"),
                "echo": _f(20, "u16le"),
            },
        },
    }
}
"""Documented example devices: their USB selection and report layout (the module docstring draws it)."""


def encode_force(layout: ReportLayout, force_D: np.ndarray, max_force: float) -> bytes:
    """The OUT report's force fields for a force already clamped to ``max_force`` (N), other fields zero.

    Rounds each component to its field's nearest count; when that would take
    the force the device decodes above ``max_force``, truncates toward zero
    instead (each component's magnitude then never grows).
    """
    fx, fy, fz = (layout.fields[n] for n in FORCE_FIELDS)
    buffer = bytearray(layout.size)
    values = [float(v) for v in force_D]
    for f, v in zip((fx, fy, fz), values):
        f.pack_into(buffer, v)
    decoded = [f.unpack(buffer) for f in (fx, fy, fz)]
    if math.hypot(*decoded) > max_force:
        for f, v in zip((fx, fy, fz), values):
            f.pack_into(buffer, v, toward_zero=True)
            if f.type.is_float:  # a float's nearest representable may still be a hair larger: step toward 0
                while abs(f.unpack(buffer)) > abs(v):
                    x = f.type.fmt.unpack_from(buffer, f.offset)[0]
                    f.type.fmt.pack_into(
                        buffer,
                        f.offset,
                        float(np.nextafter(np.float32(x), np.float32(0)))
                        if f.type.size == 4
                        else float(np.nextafter(x, 0.0)),
                    )
    return bytes(buffer)

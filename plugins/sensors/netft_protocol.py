"""The ATI Net F/T's wire: RDT records and requests, the status word, the units and ``netftapi2.xml``.

Shared by the ``netft`` sensor's receivers (``rdt.py``, pynetft's) and the
emulator (``netft_emulator.py``), from the ATI Net F/T manual (RDT and XML
interfaces):

* **RDT over UDP** (port 49152): 8-byte big-endian requests (``uint16 0x1234,
  uint16 command, uint32 sample_count``; :data:`REQUEST`): start (0x0002,
  real-time: one record per datagram, 0 samples meaning "until stopped"; 0x0003
  is ATI's "buffered" mode, ``comrdtbsiz`` records per datagram), stop (0x0000),
  bias (0x0042: the software bias takes the current reading). Each record is
  36 bytes big-endian (:data:`RECORD`, :data:`RECORD_DTYPE`): ``uint32
  rdt_sequence, uint32 ft_sequence, uint32 status, int32 Fx Fy Fz Tx Ty Tz`` in
  counts. ``rdt_sequence`` starts at 1 with every start request;
  ``ft_sequence`` counts the device's internal samples at 7000/s since
  power-on (decimated with the RDT rate).
* **The status word**: what each bit says (:data:`ATI_STATUS_BITS`) and the
  stream's status bits it maps to (:func:`stream_status`).
* **HTTP**: ``GET /netftapi2.xml``, the active configuration; the calibration
  (``cfgcpf``, ``cfgcpt``, ``scfgfu``, ``scfgtu``) read by
  :func:`fetch_configuration`, in the units of :data:`FORCE_UNITS` and
  :data:`TORQUE_UNITS`; written by :func:`configuration_xml` and served by
  :func:`configuration_handler` (the emulator's side).
"""

from __future__ import annotations

import struct
import urllib.request
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler
from xml.sax.saxutils import escape

import numpy as np

from hapticlab.core.host.options import choice, number
from hapticlab.core.types import STATUS_DEVICE_ERROR, STATUS_OK, STATUS_SATURATED

FT_RATE_HZ = 7000.0
"""The Net F/T's internal sample rate: ``ft_sequence`` counts at this rate, Hz."""
RDT_PORT = 49152
"""The RDT protocol's UDP port."""
RDT_HEADER = 0x1234
CMD_STOP, CMD_START, CMD_START_BUFFERED, CMD_BIAS = 0x0000, 0x0002, 0x0003, 0x0042
RECORD_DTYPE = np.dtype([("rdt_sequence", ">u4"), ("ft_sequence", ">u4"), ("status", ">u4"), ("counts", ">i4", (6,))])
"""One RDT record as on the wire (36 bytes, big-endian): Fx Fy Fz Tx Ty Tz in counts."""
RECORD_SIZE = RECORD_DTYPE.itemsize

REQUEST = struct.Struct(">HHI")
"""An RDT request: header 0x1234, command, sample count."""
RECORD = struct.Struct(">III6i")
"""An RDT record: rdt_sequence, ft_sequence, status, six counts (:data:`RECORD_DTYPE` as a struct)."""

FORCE_UNITS: dict[str, float] = {
    "N": 1.0,
    "kN": 1000.0,
    "lbf": 4.4482216152605,
    "klbf": 4448.2216152605,
    "kgf": 9.80665,
}
"""N per force unit, by the spelling ``scfgfu`` uses."""
TORQUE_UNITS: dict[str, float] = {
    "N-m": 1.0,
    "Nm": 1.0,
    "N-mm": 1e-3,
    "Nmm": 1e-3,
    "kN-m": 1000.0,
    "lbf-in": 0.1129848290276167,
    "lbf-ft": 1.3558179483314004,
    "kgf-cm": 0.0980665,
    "kg-cm": 0.0980665,
}
"""N·m per torque unit, by the spellings ``scfgtu`` uses."""
TORQUE_SPELLING = {"Nm": "N-m", "Nmm": "N-mm", "kg-cm": "kgf-cm"}
"""Other spellings of a torque unit -> the one recorded (pynetft's)."""

# The ATI status word (Net F/T manual, "System Status Code"). Bit 31 summarises every error bit.
ATI_ERROR_SUMMARY = 0x8000_0000
ATI_SATURATION = 0x0002_0000
"""Transducer saturation or A/D error: the reading is clipped or no number at all."""
ATI_MONITOR_LATCHED = 0x0001_0000
"""A threshold monitor condition latched (the user's own thresholds; the reading itself is good)."""
ATI_STATUS_BITS: dict[int, str] = {
    30: "CPU or RAM error",
    29: "digital board error",
    28: "analog board error",
    27: "serial link error",
    26: "program memory check failed",
    25: "halted on configuration errors",
    24: "settings validation error",
    23: "configuration does not fit the calibration",
    22: "network communication failure",
    21: "CAN error",
    20: "RDT communication error",
    19: "EtherNet/IP failure",
    18: "DeviceNet failure",
    17: "transducer saturation or A/D error",
    16: "monitor condition latched",
    14: "watchdog timeout",
    13: "stack check error",
    12: "serial EEPROM failure",
    11: "serial flash failure",
    10: "analog board watchdog timeout",
    9: "strain gage excitation current too high",
    8: "strain gage excitation current too low",
    7: "artificial analog ground out of range",
    6: "analog supply too high",
    5: "analog supply too low",
    4: "serial link data unavailable",
    3: "reference voltage or power monitor error",
    2: "internal temperature error",
    1: "HTTP failure",
}
"""What each bit of the status word says (bit 31 is the error summary)."""
_OTHER_ERRORS = 0xFFFF_FFFF & ~(ATI_ERROR_SUMMARY | ATI_SATURATION | ATI_MONITOR_LATCHED)


def stream_status(word: int) -> int:
    """The stream's status bits (``core.types``) for an ATI status word.

    Saturation (bit 17) is ``STATUS_SATURATED``; any other error bit, or the
    summary bit alone, is ``STATUS_DEVICE_ERROR``. A latched threshold monitor
    (bit 16) with the summary is a warning about the user's thresholds, not a
    bad reading: ``STATUS_OK``.
    """
    bits = STATUS_SATURATED if word & ATI_SATURATION else STATUS_OK
    if word & _OTHER_ERRORS or word == ATI_ERROR_SUMMARY:
        bits |= STATUS_DEVICE_ERROR
    return bits


def stream_status_array(words: np.ndarray) -> np.ndarray:
    """:func:`stream_status` of many status words at once: (n,) int64."""
    words = np.asarray(words, dtype=np.int64)
    bits = np.where(words & ATI_SATURATION, STATUS_SATURATED, STATUS_OK)
    return bits | np.where((words & _OTHER_ERRORS != 0) | (words == ATI_ERROR_SUMMARY), STATUS_DEVICE_ERROR, 0)


def describe_status(word: int) -> str:
    """The status word in words ("healthy" when 0)."""
    if word == 0:
        return "healthy"
    names = [name for bit, name in ATI_STATUS_BITS.items() if word & (1 << bit)]
    if word & ATI_ERROR_SUMMARY and not names:
        names = ["error summary"]
    return ", ".join(names) or f"unknown bits 0x{word:08x}"


@dataclass(frozen=True, slots=True)
class Calibration:
    """A Net F/T calibration: counts per force unit and per torque unit, and the units (``N``, ``N-m``, ...)."""

    counts_per_force: float
    counts_per_torque: float
    force_unit: str
    torque_unit: str

    @classmethod
    def checked(
        cls, counts_per_force: float, counts_per_torque: float, force_unit: str, torque_unit: str
    ) -> Calibration:
        """A calibration from option values (OptionError naming the option); the torque unit in the spelling
        recorded (:data:`TORQUE_SPELLING`)."""
        return cls(
            number("counts_per_force", counts_per_force, above=0, hint=" (counts per force unit)"),
            number("counts_per_torque", counts_per_torque, above=0, hint=" (counts per torque unit)"),
            choice("force_unit", force_unit, list(FORCE_UNITS)),
            TORQUE_SPELLING.get(torque_unit, choice("torque_unit", torque_unit, list(TORQUE_UNITS))),
        )

    def si_per_count(self) -> np.ndarray:
        """(6,) N per count (×3) and N·m per count (×3)."""
        return np.repeat(
            [
                FORCE_UNITS[self.force_unit] / self.counts_per_force,
                TORQUE_UNITS[self.torque_unit] / self.counts_per_torque,
            ],
            3,
        )

    def fields(self) -> dict[str, str]:
        """As the ``calibration`` strings (HasCalibration)."""
        return {
            "counts_per_force": f"{self.counts_per_force:g}",
            "counts_per_torque": f"{self.counts_per_torque:g}",
            "force_unit": self.force_unit,
            "torque_unit": self.torque_unit,
        }


def fetch_configuration(address: str, http_port: int, timeout: float) -> tuple[str, Calibration]:
    """The product name and active calibration from the sensor's ``netftapi2.xml``.

    Raises OSError (no answer within ``timeout`` s) or ValueError (a page without a usable
    ``cfgcpf``, ``cfgcpt``, ``scfgfu``, ``scfgtu``). No proxy: the sensor is on the lab's network.
    """
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    with opener.open(f"http://{address}:{http_port}/netftapi2.xml", timeout=timeout) as response:
        root = ET.fromstring(response.read())
    fields = {child.tag: (child.text or "").strip() for child in root}
    try:
        cpf, cpt = float(fields["cfgcpf"]), float(fields["cfgcpt"])
        force_unit, torque_unit = fields["scfgfu"], TORQUE_SPELLING.get(fields["scfgtu"], fields["scfgtu"])
    except (KeyError, ValueError) as exc:
        raise ValueError(f"netftapi2.xml: no usable calibration ({exc})") from None
    if force_unit not in FORCE_UNITS or torque_unit not in TORQUE_UNITS or not (cpf > 0 and cpt > 0):
        raise ValueError(
            f"netftapi2.xml: unusable calibration {cpf:g} counts/{force_unit}, {cpt:g} counts/{torque_unit}"
        )
    return fields.get("prodname", "ATI Net F/T"), Calibration(cpf, cpt, force_unit, torque_unit)


def configuration_xml(fields: Mapping[str, str]) -> bytes:
    """The ``netftapi2.xml`` page of these fields (``prodname``, ``cfgcpf``, ...): what :func:`fetch_configuration`
    reads."""
    body = "".join(f"<{k}>{escape(v)}</{k}>" for k, v in fields.items())
    return f'<?xml version="1.0" encoding="ISO-8859-1"?>\n<netft>{body}</netft>\n'.encode("ascii")


def configuration_handler(page: Callable[[], bytes]) -> type[BaseHTTPRequestHandler]:
    """An ``http.server`` handler serving ``GET /netftapi2.xml`` from ``page()``; everything else is 404."""

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # http.server's name
            if self.path.split("?")[0] != "/netftapi2.xml":
                self.send_error(404)
                return
            body = page()
            self.send_response(200)
            self.send_header("Content-Type", "text/xml")
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Connection", "close")
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format, *args) -> None:  # quiet: the operator watches the RDT stream
            pass

    return Handler

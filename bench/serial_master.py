"""Round trip of the ``serial`` haptic output over a pseudo-terminal, both protocols.

    .venv/bin/python bench/serial_master.py [--n 5000] [--rate 1000]

Starts ``hapticlab emulate master`` (the module's ``run``) in a process of its
own, opens the printed pty with the ``serial`` plugin and times each ``send``:
one force written, the device's state read back (what a session's tick pays
for its haptic device), and with ``wait_for_reply = false`` the pipelined
send (write, take the replies already there). Paced at ``--rate`` Hz like a
session, then back to back. Numbers vary with the machine and its load: quote them, never assert
them. A pty has no baud rate; over a real UART add the bytes' time on the
wire (our protocol: 19 + 35 bytes, 0.54 ms at 1 Mbit/s; Inverse3: 13 + 25
bytes over USB full speed).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

import numpy as np

from hapticlab.core.types import HapticCommand
from hapticlab.plugins.haptics.serial import SerialHaptic

EMULATOR = (
    "import argparse, sys; from hapticlab.plugins.haptics import master_emulator_cli as m; "
    "p = argparse.ArgumentParser(); m.add_arguments(p); sys.exit(m.run(p.parse_args(sys.argv[1:])))"
)


def measure(protocol: str, n: int, rate_hz: float | None, wait_for_reply: bool = True) -> np.ndarray:
    """Times of ``n`` sends, µs (paced at ``rate_hz``, or back to back when None)."""
    proc = subprocess.Popen([sys.executable, "-c", EMULATOR, "--protocol", protocol], stdout=subprocess.PIPE, text=True)
    try:
        port = proc.stdout.readline().strip()
        # a long read timeout: this measures latency; a loaded machine that stalls the emulator is not a loss here
        device = SerialHaptic(port, protocol, wait_for_reply=wait_for_reply, read_timeout=1.0)
        device.open()
        rng = np.random.default_rng(0)
        times = np.empty(n)
        period = 1.0 / rate_hz if rate_hz else 0.0
        next_t = time.perf_counter()
        for k in range(n):
            if period:
                next_t += period
                while time.perf_counter() < next_t:
                    pass
            command = HapticCommand(k, rng.uniform(-2, 2, 3), True)
            t0 = time.perf_counter_ns()
            device.send(command)
            times[k] = (time.perf_counter_ns() - t0) * 1e-3
        device.close()
        return times
    finally:
        proc.terminate()
        proc.wait()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=5000, help="sends per case (default 5000)")
    parser.add_argument("--rate", type=float, default=1000.0, help="paced rate, Hz (default 1000)")
    args = parser.parse_args()
    print(f"{'protocol':10} {'send':>16} {'pacing':>12} {'p50 µs':>8} {'p99 µs':>8} {'max µs':>8}")
    for protocol, wait in (("hapticlab", True), ("hapticlab", False), ("inverse3", True)):
        for rate in (args.rate, None):
            t = measure(protocol, args.n, rate, wait)
            pacing = f"{rate:g} Hz" if rate else "back to back"
            mode = "waits for reply" if wait else "pipelined"
            print(
                f"{protocol:10} {mode:>16} {pacing:>12} {np.median(t):8.0f} {np.percentile(t, 99):8.0f} {t.max():8.0f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())

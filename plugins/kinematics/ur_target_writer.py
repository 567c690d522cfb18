"""The process that writes teleoperation's targets to a UR controller (run as a script by ``ur_follow.TargetWriter``).

ur-rtde's ``RTDEIOInterface`` holds Python's interpreter lock while it writes
a register (seven per target): in the session's process that starves the
thread receiving the arm's poses (packages are missed; docs/teleoperation.md).
Here it runs in a
process of its own, needing nothing but ur-rtde: it connects, prints ``ready``
(or ``error: ...``) on stdout, then reads targets from stdin, each
``RECORD`` (x, y, z in m as doubles, rx, ry, rz in µrad as int32,
little-endian), and writes the newest one: three doubles, three integers, then
the next sequence number. End of file (the session ended, or died) ends it;
the arm's script stops the arm when targets stop.
"""

import contextlib
import os
import select
import struct
import sys

RECORD = struct.Struct("<3d3i")
POSITION_REGISTERS = (18, 19, 20)
ROTATION_REGISTERS = (18, 19, 20)
SEQUENCE_REGISTER = 21
INT32_MAX = 2**31 - 1


def serve(address: str, source_fd: int, reply) -> int:
    try:
        import rtde_io

        io = rtde_io.RTDEIOInterface(address)
    except Exception as exc:  # no ur-rtde, or the controller refused: say so in one line
        reply.write(f"error: {exc}\n")
        reply.flush()
        return 1
    reply.write("ready\n")
    reply.flush()
    sequence, pending = 0, b""
    try:
        while True:
            select.select([source_fd], [], [])
            data = os.read(source_fd, 1 << 16)
            if not data:
                return 0
            pending += data
            whole = len(pending) - len(pending) % RECORD.size
            if whole == 0:
                continue
            x, y, z, rx, ry, rz = RECORD.unpack_from(pending, whole - RECORD.size)  # the newest target only
            pending = pending[whole:]
            sequence = sequence % INT32_MAX + 1
            ok = all(
                [
                    io.setInputDoubleRegister(POSITION_REGISTERS[0], x),
                    io.setInputDoubleRegister(POSITION_REGISTERS[1], y),
                    io.setInputDoubleRegister(POSITION_REGISTERS[2], z),
                    io.setInputIntRegister(ROTATION_REGISTERS[0], rx),
                    io.setInputIntRegister(ROTATION_REGISTERS[1], ry),
                    io.setInputIntRegister(ROTATION_REGISTERS[2], rz),
                    io.setInputIntRegister(SEQUENCE_REGISTER, sequence),
                ]
            )
            if not ok:
                reply.write("error: the controller did not take the target's input registers\n")
                reply.flush()
                return 1
    finally:
        with contextlib.suppress(RuntimeError):
            io.disconnect()


if __name__ == "__main__":
    import signal

    for name in ("SIGINT", "SIGTERM", "SIGHUP"):  # the session ends us by closing our stdin
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
    sys.exit(serve(sys.argv[1], sys.stdin.fileno(), sys.stdout))

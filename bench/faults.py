"""Fault injection through the real run loop: made-up force on the device, detection and zero times, events.

Run: ``.venv/bin/python bench/faults.py`` (about 3 minutes here; the same as ``hapticlab bench faults``).
Every fault of ``plugins/simworld/faults.py`` is injected into the demo session at 4 s and compared with the
same session without it (same seeds), for ``rls`` and ``kalman``; see ``sessions/bench/faults.py``.
"""

from hapticlab.sessions.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["bench", "faults"]))

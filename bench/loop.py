"""Where a tick of the run loop goes, per stage, and what each estimator costs per sample.

Run: ``.venv/bin/python bench/loop.py`` (about a minute here; the same as ``hapticlab bench loop``).
See ``sessions/bench/loop.py`` for what is timed and how.
"""

from hapticlab.sessions.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["bench", "loop"]))

"""A paced session at the Net F/T's full rate: samples dropped, overruns, sample-to-command latency, memory.

Run: ``.venv/bin/python bench/realtime.py [SECONDS] [SENSOR_RATE_HZ] [process|inline]`` (default 600 s at
7000 Hz, the MCAP writer in its own process: ten minutes of wall time). Prints one JSON object; see
``sessions/bench/realtime.py`` (``realtime_run``).
"""

import json
import sys

from hapticlab.sessions.bench.realtime import realtime_run

if __name__ == "__main__":
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 600.0
    rate = float(sys.argv[2]) if len(sys.argv) > 2 else 7000.0
    writer = sys.argv[3] if len(sys.argv) > 3 else "process"
    print(
        json.dumps(
            realtime_run(seconds, rate, progress=lambda m: print(m, file=sys.stderr, flush=True), writer=writer),
            indent=1,
        )
    )

"""The live session: build the plugins from config (``build``), run the loop (``loop``, paced by ``pacing``),
gate the haptic force (``gate``, ``watch``, ``safety``) and send it (``command``), record every stage
(``taps``), report (``status``), end the same way whatever ends it (``ending``)."""

from hapticlab.sessions.live.build import EstimatorSlot, Session, build_session, calibration_path
from hapticlab.sessions.live.loop import run_session
from hapticlab.sessions.live.status import SessionError, SessionResult, SessionStatus

__all__ = [
    "EstimatorSlot",
    "Session",
    "SessionError",
    "SessionResult",
    "SessionStatus",
    "build_session",
    "calibration_path",
    "run_session",
]

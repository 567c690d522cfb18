"""How every session ends the same way, whatever ended it: its duration, Ctrl-C, SIGTERM or SIGHUP, a part that raised.

The final zero command is sent *and recorded*, the devices are closed (what they
say while closing is recorded too), the estimator's state is saved, an
``error`` event names what failed, the summary says ``interrupted`` and
``error``, and the MCAP file is finished. A failure then raises
``SessionError`` (its ``result.path`` is the complete recording). A shadow
estimator that raises is dropped with an event and the session goes on.

Python turns only SIGINT into ``KeyboardInterrupt``: :func:`signals_end_the_session`
makes SIGTERM (a service manager) and SIGHUP (a closed terminal) do the same,
and :func:`signals_noted` notes and ignores all three while the session ends, so
the file is always finished. Only the main thread can install handlers: in any
other thread both do nothing.
"""

from __future__ import annotations

import json
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from hapticlab.core.types import Event
from hapticlab.sessions.live.build import EstimatorSlot, Session, calibration_path
from hapticlab.sessions.recording import Recorder
from hapticlab.sessions.tools import ToolPlan
from hapticlab.sessions.tools import save as save_tool_record


class PartFailedError(Exception):
    """A device, the primary estimator or the recording raised inside the loop; ``part`` names it."""

    def __init__(self, part: str, exc: BaseException):
        super().__init__(f"{part} raised {type(exc).__name__}: {exc}")
        self.part = part


STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


@contextmanager
def signals_end_the_session(stopped_by: Callable[[str], None]) -> Iterator[None]:
    """SIGTERM and SIGHUP raise ``KeyboardInterrupt``, as Ctrl-C does, after telling ``stopped_by`` their name."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        stopped_by(signal.Signals(signum).name)
        raise KeyboardInterrupt

    previous = {s: signal.signal(s, stop) for s in STOP_SIGNALS if s != signal.SIGINT}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


@contextmanager
def signals_noted(noted: list[str]) -> Iterator[None]:
    """Ctrl-C, SIGTERM and SIGHUP are appended to ``noted`` by name and otherwise ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {
        s: signal.signal(s, lambda signum, frame: noted.append(signal.Signals(signum).name)) for s in STOP_SIGNALS
    }
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def close_devices(
    session: Session, end_ns: int, on_event: Callable[[Event], None], on_events: Callable[[list[Event], str], object]
) -> None:
    """Close the haptic device, the sensor and the kinematics, then record what the devices said while closing
    (``on_events(events, label)``: their final health counters); what fails is an ``error`` event."""
    for label, device in (("haptic", session.haptic), ("sensor", session.sensor), ("kinematics", session.kinematics)):
        try:
            device.close()
        except Exception as exc:
            on_event(Event(end_ns, "error", f"{label} did not close: {type(exc).__name__}: {exc}"))
    for label, emitter in session.device_events:
        try:
            on_events(emitter.drain_events(), label)
        except Exception as exc:
            on_event(Event(end_ns, "error", f"{label} events lost: {type(exc).__name__}: {exc}"))


def save_estimator_state(
    primary: EstimatorSlot, recorder: Recorder, path: Path, end_ns: int, on_event: Callable[[Event], None]
) -> str | None:
    """The primary estimator's state in the recording's metadata and beside it (:func:`~.build.calibration_path`),
    for the next session to start from; the path written, or None (an ``estimator_state_not_saved`` event:
    a failing save never costs the recording)."""
    assert primary.saves is not None
    try:
        state = primary.saves.state()
        recorder.add_metadata("hapticlab.estimator_state", state)
        state_path = calibration_path(path)
        with state_path.open("x") as f:  # never over an existing file (the loop refused one at its start)
            f.write(json.dumps(state, indent=1))
        return str(state_path)
    except Exception as exc:
        on_event(Event(end_ns, "estimator_state_not_saved", f"estimator state not saved: {exc}"))
        return None


def final_params(primary: EstimatorSlot, samples: int, end_ns: int, on_event: Callable[[Event], None]) -> dict:
    """The primary's parameters at the end ({} before any sample, or when it fails again: an ``error`` event)."""
    try:
        return (primary.params() or {}) if samples else {}
    except Exception as exc:  # the estimator that just failed may fail again
        on_event(Event(end_ns, "error", f"estimator parameters unavailable: {exc}"))
        return {}


def save_for_next(
    session: Session,
    recorder: Recorder,
    path: Path,
    params: dict,
    held: str,
    end_ns: int,
    on_event: Callable,
    changed_from: Sequence[ToolSnapshot] = (),
    tared: bool = False,
) -> str | None:
    """What later sessions start from, once the session ended without a failure: the primary's state beside the
    recording (:func:`save_estimator_state`: its path, or None) and the tool in its library (:func:`save_tool`,
    unless the gate ``held`` the force at the end: why, "" it did not: a latch, a doubt, a weight off); first
    each tool the session was told it changed from, as it was at the change (``changed_from``). ``tared``: a
    tare moved the zero (``params`` are given in the sensor's own readings): no estimator state is saved, its
    biases are against the tared zero, and a warm start from it would put the zero on the hand."""
    saved = None
    if tared and session.primary.saves:
        why = "a tare moved the sensor's zero: its state is against it, not the sensor's own readings"
        on_event(Event(end_ns, "estimator_state_not_saved", f"estimator state not saved: {why}"))
    elif session.primary.saves:
        saved = save_estimator_state(session.primary, recorder, path, end_ns, on_event)
    recording = str(Path(path).resolve())
    for old in changed_from:
        save_tool(old, session.primary.label, recording, end_ns, on_event)
    if session.tool.name:
        save_tool(snapshot(session, params, held, tared=tared), session.primary.label, recording, end_ns, on_event)
    return saved


@dataclass(frozen=True)
class ToolSnapshot:
    """A named tool as the session knew it at a moment: what :func:`save_tool` writes to its library.

    Attributes:
        plan: the tool (its name, library and earlier record).
        params: the primary's parameters then (``gravity_force_B``, ``cog_S``, biases).
        state: the primary's saved state then (None: it saves none).
        held: why the gate held the force then ("" it did not: only then is the tool saved).
        when: the moment, for the messages ("at the end", "at the change").
    """

    plan: ToolPlan
    params: dict
    state: dict | None
    held: str
    when: str = "at the end"


def snapshot(session: Session, params: dict, held: str, when: str = "at the end", tared: bool = False) -> ToolSnapshot:
    """The session's tool now, with the primary's ``params`` (its state taken only when ``held`` is "" and no
    ``tared`` zero stands: the state's biases are against it, the record's ``params`` the sensor's own)."""
    primary, state = session.primary, None
    if primary.saves is not None and not held and not tared:
        try:
            state = primary.saves.state()
        except Exception as exc:  # (a failing save never costs the session nor the recording: not saved, said why)
            held = f"its estimator's state could not be taken: {type(exc).__name__}: {exc}"
    return ToolSnapshot(session.tool, params, state, held, when)


def save_tool(tool: ToolSnapshot, label: str, recording: str, end_ns: int, on_event: Callable[[Event], None]) -> None:
    """A tool written back to its library (``sessions.tools.save``) when nothing held the force at its moment
    (``tool.held``): a ``tool_saved`` event, or ``tool_not_saved`` saying why. A failing save never costs the
    recording."""
    why = f"the force was held {tool.when} ({tool.held})" if tool.held else ""
    if not why:
        try:
            message = save_tool_record(tool.plan, tool.params, tool.state, label, recording)
            why = "" if message else f"{label} reports no weight and centre of gravity"
        except Exception as exc:  # (as the estimator's state: the recording comes first)
            why = f"{type(exc).__name__}: {exc}"
    if why:
        on_event(Event(end_ns, "tool_not_saved", f"tool {tool.plan.name!r} not saved to its library: {why}"))
    else:
        on_event(Event(end_ns, "tool_saved", message))


def ending_message(interrupted: bool, stopped_by: str, failed: bool) -> str:
    """The ``session_end`` event's message."""
    if interrupted:
        return f"interrupted ({stopped_by})"
    return "ended by an error" if failed else "session finished"

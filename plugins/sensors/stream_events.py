"""The events a real sensor's stream makes, alike for every plugin (Net F/T, Robotiq FT 300, Bota).

* ``status_event``: the sensor's status word changed: ``sensor_status_ok`` (0), ``sensor_saturated``,
  ``sensor_error`` (a bit the stream reports as a fault) or ``sensor_warning`` (a bit it does not).
* ``health_event``: a fault counter moved (or the stream closed): ``sensor_health`` with every counter.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping

from hapticlab.core.types import STATUS_SATURATED, Event


def status_event(t_ns: int, who: str, word: int, previous: int, bits: int, description: str) -> Event:
    """The event of a status word ``word`` (``previous`` before it) that the stream reports as ``bits``
    (``STATUS_*``); ``who`` names the sensor, ``description`` is the word in words."""
    kind = (
        "sensor_status_ok"
        if word == 0
        else "sensor_saturated"
        if bits & STATUS_SATURATED
        else "sensor_error"
        if bits
        else "sensor_warning"
    )
    data = {"status_word": word, "previous_status_word": previous, "stream_status": bits}
    return Event(t_ns, kind, f"{who} status {description}", data)


def health_event(
    t_ns: int,
    who: str,
    counters: Mapping[str, int],
    recorded: Mapping[str, int],
    faults: Collection[str],
    final: bool = False,
) -> Event | None:
    """``sensor_health`` when a counter in ``faults`` moved since ``recorded`` (or ``final``: the stream closed),
    naming what moved and carrying every counter; None otherwise."""
    changed = {k: v - recorded[k] for k, v in counters.items() if k in faults and v != recorded[k]}
    if not changed and not final:
        return None
    what = ", ".join(f"{k} +{v}" for k, v in changed.items()) or "no faults"
    return Event(t_ns, "sensor_health", f"{who}: {what}" + (" (stream closed)" if final else ""), dict(counters))

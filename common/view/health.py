"""The health panel: every stage alive or not with its rates, drops and errors, the
capture → obstacle latency percentiles (none for a replay: its stamps are not now's),
the stream's state with its reason (the pose stage's, "unknown" once its health
messages stop), how current the frames and obstacles are, and the last calibration
(DIPE px and mm, eq. 14; held-out error; age)."""

from __future__ import annotations

import collections
import time
from collections.abc import Iterable, Mapping
from datetime import datetime

import msgspec
import numpy as np

from ovis.common.calibration.file import Calibration
from ovis.common.messages import ServiceStatus, StreamHealth
from ovis.common.view.freshness import Freshness

__all__ = [
    "HEALTH_STALE_S",
    "STAGES",
    "CalibrationSummary",
    "HealthSummary",
    "LatencyWindow",
    "StageHealth",
    "listed",
    "summarize",
    "summarize_calibration",
]

#: The stages of an arena, in frame order, then the calibrator: always listed, so that
#: one that is not running shows as such.
STAGES = ("capture", "preprocess", "label", "pose", "calibrator")


def listed(alive: Iterable[str], answered: Iterable[str]) -> list[str]:
    """The services a health listing shows: the :data:`STAGES` always, then every other
    service alive or answering, by name (the optional ones, the fusion or the ROS 2
    bridge, only while they run: one not started is not missing)."""
    return list(STAGES) + sorted((set(alive) | set(answered)) - set(STAGES))


#: Seconds after which the pose stage's last health message (it sends one every status
#: period) no longer tells the stream's state: it is then "unknown".
HEALTH_STALE_S = 3.0


class StageHealth(msgspec.Struct, kw_only=True):
    """One stage: alive (its liveliness token is up) and its last status, if any."""

    name: str
    alive: bool
    state: str = "not running"
    fps: float | None = None
    frames_in: int | None = None
    frames_out: int | None = None
    dropped: int | None = None
    errors: int = 0
    errors_by_kind: dict[str, int] = {}
    last_error: str = ""
    calibration_version: int | None = None
    where: str = ""
    restarts: int = 0


class CalibrationSummary(msgspec.Struct, kw_only=True):
    """The calibration in use: version, DIPE, held-out error and age."""

    version: int
    dipe_px: float
    dipe_mm: float
    dipe_max_px: float
    held_out_px: float | None = None
    held_out_cm: float | None = None
    held_out_method: str = ""
    created: str = ""
    age_s: float | None = None
    source: str = ""


class HealthSummary(msgspec.Struct, kw_only=True):
    """What the health panel shows for one arena."""

    arena: str
    stages: list[StageHealth]
    #: the pose stage's "waiting", "ok", "stalled", "source lost", "degraded", "failing";
    #: "no pose service" (no health message yet) or "unknown" (they stopped coming)
    stream: str
    latency_p50_ms: float | None = None
    latency_p99_ms: float | None = None
    latency_samples: int = 0
    calibration: CalibrationSummary | None = None
    stream_reason: str = ""
    #: how current the newest camera frame, binarised frame and obstacle message are
    fresh: dict[str, Freshness] = {}
    #: the recording the frames are replayed from ("": live); no latency is measured then
    replay: str = ""
    #: messages dropped for lack of their signer's proof of origin, by kind (obstacles,
    #: health: the pose stage's; calibration: the calibrator's)
    unproven: dict[str, int] = {}


class LatencyWindow:
    """Capture → obstacle latencies of the last ``window_s`` seconds (at most ``limit``
    kept: bounded memory at any frame rate)."""

    def __init__(self, window_s: float = 10.0, limit: int = 4096) -> None:
        self.window_s = window_s
        self._items: collections.deque[tuple[float, float]] = collections.deque(maxlen=limit)

    def add(self, latency_ms: float, now_s: float | None = None) -> None:
        if np.isfinite(latency_ms):
            self._items.append((time.monotonic() if now_s is None else now_s, latency_ms))

    def percentiles(self, now_s: float | None = None) -> tuple[float | None, float | None, int]:
        """(p50, p99, samples) over the window; Nones when it is empty."""
        now = time.monotonic() if now_s is None else now_s
        while self._items and now - self._items[0][0] > self.window_s:
            self._items.popleft()
        if not self._items:
            return None, None, 0
        lat = np.fromiter((v for _, v in self._items), float, len(self._items))
        p50, p99 = np.percentile(lat, [50, 99])
        return float(p50), float(p99), int(lat.size)


def _age_s(created: str, now: datetime | None) -> float | None:
    try:
        made = datetime.fromisoformat(created)
    except ValueError:
        return None
    if made.tzinfo is None:
        return None
    now = now or datetime.now(made.tzinfo)
    return max(0.0, (now - made).total_seconds())


def summarize_calibration(calib: Calibration, now: datetime | None = None) -> CalibrationSummary:
    """The calibration's quality for the panel: DIPE, the held-out error (check points
    if it has them, else leave-one-out) and how long ago it was made."""
    held = None
    if calib.accuracy is not None:
        held = calib.accuracy.check or calib.accuracy.leave_one_out
    return CalibrationSummary(
        version=calib.version,
        dipe_px=calib.dipe_px,
        dipe_mm=calib.dipe_mm,
        dipe_max_px=calib.dipe_max_px,
        held_out_px=held.mean_px if held else None,
        held_out_cm=held.mean_cm if held else None,
        held_out_method=held.method if held else "",
        created=calib.created,
        age_s=_age_s(calib.created, now) if calib.created else None,
        source=calib.source_image,
    )


def _stage(name: str, alive: bool, st: ServiceStatus | None) -> StageHealth:
    if not alive or st is None:
        return StageHealth(name=name, alive=alive, state="starting" if alive else "not running")
    return StageHealth(
        name=name,
        alive=True,
        state=st.state,
        fps=st.fps,
        frames_in=st.frames_in,
        frames_out=st.frames_out,
        dropped=st.dropped,
        errors=sum(st.errors.values()),
        errors_by_kind=dict(st.errors),
        last_error=st.last_error,
        calibration_version=st.calibration_version,
        where=f"{st.pid}@{st.host}",
        restarts=st.restarts,
    )


def _stream(stream: StreamHealth | None, age_s: float | None) -> tuple[str, str]:
    """The stream's state and reason from the pose stage's last health message, received
    ``age_s`` ago."""
    if stream is None:
        return "no pose service", ""
    if age_s is not None and age_s > HEALTH_STALE_S:
        return "unknown", f"no health message from the pose stage for {age_s:.0f} s"
    return stream.state, stream.reason


def summarize(
    arena: str,
    alive: Iterable[str],
    statuses: Mapping[str, ServiceStatus],
    latency: LatencyWindow,
    stream: StreamHealth | None,
    calibration: Calibration | None,
    *,
    stream_age_s: float | None = None,
    fresh: Mapping[str, Freshness] | None = None,
    unproven: Mapping[str, int] | None = None,
) -> HealthSummary:
    """The health of one arena: the five stages (and any other service that is alive
    or answered), latency over the window (none while the frames are a replay), the
    stream's state (received ``stream_age_s`` ago), how current each kind of item is,
    and the calibration. A stage that is not alive shows no status, even if an old one
    is known."""
    alive = set(alive)
    fresh = dict(fresh or {})
    replay = next((f.recording for f in fresh.values() if f.recording), "")
    names = listed(alive, statuses)
    p50, p99, n = (None, None, 0) if replay else latency.percentiles()
    state, reason = _stream(stream, stream_age_s)
    return HealthSummary(
        arena=arena,
        stages=[_stage(n_, n_ in alive, statuses.get(n_)) for n_ in names],
        stream=state,
        stream_reason=reason,
        latency_p50_ms=p50,
        latency_p99_ms=p99,
        latency_samples=n,
        calibration=(
            summarize_calibration(calibration)
            if calibration is not None and calibration.version > 0
            else None
        ),
        fresh=fresh,
        replay=replay,
        unproven=dict(unproven or {}),
    )

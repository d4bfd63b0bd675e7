"""A source that fails mid-run, the logic: the retry schedule, the record of the losses
(what the capture's status and ``source`` messages say), the stream's health that folds
the capture's word in, and what the summary of a run shows."""

from __future__ import annotations

import io

import msgspec
import pytest
from rich.console import Console

from ovis.common.analysis.live import LiveScore
from ovis.common.capture.backoff import FIRST_S, LONGEST_S, Backoff
from ovis.common.messages import ServiceStatus, SourceState, StreamHealth, decode, encode
from ovis.common.pipeline.gaps import SourceGaps
from ovis.common.pipeline.health import SOURCE_FRESH_S, SourceWatch, StreamWatch
from ovis.services.cli.watching import format_gaps, format_health, summary_table

S = 1_000_000_000  # ns


def test_backoff_doubles_from_half_a_second_to_a_cap_and_resets_after_a_success() -> None:
    b = Backoff()
    assert (FIRST_S, LONGEST_S) == (0.5, 4.0)
    assert [b.next_wait() for _ in range(6)] == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    b.reset()
    assert [b.next_wait() for _ in range(2)] == [0.5, 1.0]
    assert [Backoff(0.3, 1.0).next_wait() for _ in range(1)] == [0.3]
    capped = Backoff(0.3, 1.0)
    assert [capped.next_wait() for _ in range(4)] == [0.3, 0.6, 1.0, 1.0]
    for first, longest in ((0.0, 1.0), (2.0, 1.0), (-1.0, 1.0)):
        with pytest.raises(ValueError, match="first_s <= longest_s"):
            Backoff(first, longest)


def status(state: str = "ok", reason: str = "") -> ServiceStatus:
    return ServiceStatus(
        service="capture", pid=1, host="h", started_ns=0, state=state, reason=reason
    )


def test_a_loss_counts_from_the_last_frame_to_the_next_with_its_first_reason() -> None:
    gaps = SourceGaps()
    assert gaps.delivered(100 * S) is None and not gaps.lost
    assert gaps.delivered(101 * S) is None
    assert gaps.lose("camera 0 delivered no frame", 102 * S)
    assert not gaps.lose("cannot open camera 0", 103 * S)  # the same loss, retried
    assert gaps.lost and gaps.count == 1 and gaps.reason == "cannot open camera 0"
    ongoing = gaps.gaps(104 * S)
    assert [(g.start_ns, g.seconds, g.ongoing) for g in ongoing] == [(101 * S, 3.0, True)]
    assert ongoing[0].reason == "camera 0 delivered no frame"  # why it was lost
    assert gaps.total_s(104 * S) == 3.0

    lost = gaps.amend(status(), 104 * S)
    assert (lost.state, lost.reason) == ("source lost", "cannot open camera 0")
    assert (lost.source_gaps, lost.source_gap_s, lost.gaps) == (1, 3.0, ongoing)
    said = gaps.message(104 * S)
    assert (said.state, said.reason, said.lost_ns, said.ended, said.gaps) == (
        "source lost",
        "cannot open camera 0",
        101 * S,
        False,
        1,
    )

    back = gaps.delivered(106_500_000_000)
    assert back is not None and (back.seconds, back.ongoing) == (5.5, False)
    assert back.reason == "camera 0 delivered no frame" and not gaps.lost
    assert gaps.delivered(107 * S) is None
    ok = gaps.amend(status("ok"), 200 * S)
    assert (ok.state, ok.reason, ok.source_gaps, ok.source_gap_s) == ("ok", "", 1, 5.5)
    assert ok.gaps == [back]
    assert gaps.message(200 * S) == SourceState(state="ok", published_ns=200 * S, gaps=1)

    assert gaps.lose("again", 210 * S)  # a second loss, from the frame at 107 s
    assert gaps.count == 2 and gaps.total_s(210 * S) == 5.5 + 103.0
    assert [g.ongoing for g in gaps.gaps(210 * S)] == [False, True]


def test_a_source_that_never_delivered_is_lost_from_its_first_failure() -> None:
    gaps = SourceGaps()
    assert gaps.lose("cannot open camera 7", 50 * S)
    assert gaps.gaps(52 * S)[0].start_ns == 50 * S and gaps.total_s(52 * S) == 2.0
    # a stage's own verdict stays when the source is fine; "source lost" wins otherwise
    assert gaps.amend(status("failing", "no output"), 52 * S).state == "source lost"


def test_an_ended_source_says_so_and_the_list_keeps_the_latest_losses() -> None:
    gaps = SourceGaps(keep=3)
    for i in range(5):
        gaps.delivered(10 * i * S)
        gaps.lose(f"loss {i}", (10 * i + 1) * S)
    gaps.delivered(45 * S)
    assert gaps.count == 5 and gaps.total_s(45 * S) == 4 * 10.0 + 5.0
    assert [g.reason for g in gaps.gaps(45 * S)] == ["loss 2", "loss 3", "loss 4"]
    gaps.lose("ended: folder f (2 images): all images sent (loop is off)", 46 * S, ended=True)
    said = gaps.message(47 * S)
    assert said.ended and said.reason.startswith("ended") and said.gaps == 6
    assert decode(encode(said), SourceState) == said


def lost_msg(reason: str = "stream x delivered no frame") -> SourceState:
    return SourceState(state="source lost", published_ns=1, reason=reason)


def test_the_source_watch_believes_a_fresh_word_only() -> None:
    w = SourceWatch()
    assert w.lost(0.0) is None
    assert w.hear(lost_msg(), 10.0)  # a change: the health goes out at once
    assert w.lost(10.5) == "stream x delivered no frame"
    assert not w.hear(lost_msg(), 10.5)  # repeated: no change
    assert w.hear(lost_msg("cannot open stream x"), 11.0)  # a new reason is news
    assert w.lost(11.0 + SOURCE_FRESH_S) == "cannot open stream x"
    assert w.lost(11.0 + SOURCE_FRESH_S + 0.01) is None  # the capture went quiet
    assert w.hear(SourceState(state="ok", published_ns=2), 12.0)
    assert w.lost(12.0) is None
    assert w.hear(SourceState(state="source lost", published_ns=3), 13.0)
    assert w.lost(13.0) == "the capture gave no reason"


def health(watch: StreamWatch, verdict: tuple[str, str] = ("ok", "")) -> StreamHealth:
    return watch.message(
        last_seq=7,
        seconds_since_frame=0.1,
        last_frame_age_ms=None,
        frames_dropped=0,
        calibration_version=1,
        verdict=verdict,
    )


def test_the_stream_health_says_source_lost_with_the_reason_over_the_frames_state() -> None:
    watch = StreamWatch(timeout_s=2.0)
    assert watch.update(0.1) and health(watch).state == "ok"
    assert watch.update(0.1, "stream x delivered no frame")  # frames were recent
    h = health(watch, ("failing", "no output"))
    assert (h.state, h.reason) == ("source lost", "stream x delivered no frame")
    assert not watch.update(5.0, "stream x delivered no frame")
    assert watch.update(5.0, "cannot open stream x")  # the reason changed
    assert watch.update(5.0) and (health(watch).state, health(watch).reason) == ("stalled", "")
    assert watch.update(None, "cannot open camera 0") and watch.state == "source lost"
    assert watch.update(0.2) and health(watch, ("degraded", "1 of 4")).state == "degraded"
    line = format_health(h)
    assert line.startswith("NO DATA: source lost (stream x delivered no frame);")


def test_the_summary_reports_the_losses_and_a_source_still_lost() -> None:
    gaps = SourceGaps()
    gaps.delivered(0)
    gaps.lose("stream x delivered no frame", 1 * S)
    gaps.delivered(4 * S)
    gaps.lose("ended: video v: all frames sent (loop is off)", 5 * S, ended=True)
    capture = gaps.amend(status(), 7 * S)
    summary = LiveScore().summary({"capture": capture}, {"capture": 0}, 9.0)
    assert (summary.source_gaps, summary.source_gap_s) == (2, 7.0)
    assert summary.gaps == capture.gaps
    assert summary.health == {
        "capture": "source lost: ended: video v: all frames sent (loop is off)"
    }
    text = format_gaps(summary)
    assert text.splitlines() == [
        "[red]2 times, 7.0 s in total[/]",
        "4.0 s: stream x delivered no frame",
        "3.0 s (still lost): ended: video v: all frames sent (loop is off)",
    ]
    console = Console(file=io.StringIO(), width=160)
    console.print(summary_table(summary))
    assert "2 times, 7.0 s in total" in console.file.getvalue()

    quiet = LiveScore().summary({"capture": status()}, {}, 1.0)
    assert format_gaps(quiet) == "never" and quiet.source_gaps == 0
    many = msgspec.structs.replace(summary, source_gaps=9)
    assert format_gaps(many).splitlines()[1] == "… 4 earlier"

"""Health that tells the truth and counters no one can blow up (common/pipeline/health.py,
counters.py, totals.py; the summary's flag in common/analysis/live.py)."""

from __future__ import annotations

import socket

import msgspec

from ovis.common.analysis.live import LiveScore, position_error_flag
from ovis.common.messages import ObstacleFrame, ServiceStatus
from ovis.common.pipeline.counters import MAX_PLAUSIBLE_GAP, StageCounters
from ovis.common.pipeline.health import HEALTH_WINDOW_S, StreamWatch, stage_verdict
from ovis.common.pipeline.totals import CounterTotals, claimed_once, least


def _outcomes(pattern: str, now: float = 100.0) -> list[tuple[float, bool]]:
    """'+' an input with an output, '-' one without, spread over half the window."""
    step = HEALTH_WINDOW_S / 2 / max(len(pattern), 1)
    return [(now - i * step, c == "+") for i, c in enumerate(pattern)]


def test_a_stage_with_input_and_no_output_is_failing() -> None:
    assert stage_verdict(_outcomes("-----"), 100.0, "TypeError: x") == (
        "failing",
        f"5 inputs in {HEALTH_WINDOW_S:g} s, no output (last error: TypeError: x)",
    )


def test_most_inputs_failing_is_failing_some_is_degraded_few_is_ok() -> None:
    assert stage_verdict(_outcomes("+---"), 100.0) == ("failing", "3 of 4 inputs failed")
    assert stage_verdict(_outcomes("+++-+"), 100.0) == ("degraded", "1 of 5 inputs failed")
    assert stage_verdict(_outcomes("+" * 20 + "-"), 100.0) == ("ok", "")
    # too few inputs to judge, and old ones forgotten
    assert stage_verdict(_outcomes("--"), 100.0) == ("ok", "")
    assert stage_verdict(_outcomes("-----"), 100.0 + HEALTH_WINDOW_S + 1) == ("ok", "")


def test_the_stage_verdict_reaches_its_status_and_the_health_topic() -> None:
    counters = StageCounters()
    for _ in range(5):
        counters.saw_frame(1, 0)
        counters.error("processing", "TypeError: boom")
        counters.outcome(False)
    st = counters.status("pose", started_ns=0, state="ok", dropped_here=0, calibration_version=3)
    assert st.state == "failing" and "no output (last error: TypeError: boom)" in st.reason
    watch = StreamWatch(2.0)
    watch.update(0.1)  # frames flow …
    msg = watch.message(
        last_seq=1,
        seconds_since_frame=0.1,
        last_frame_age_ms=1.0,
        frames_dropped=0,
        calibration_version=3,
        verdict=(st.state, st.reason),
    )
    assert (msg.state, msg.reason) == ("failing", st.reason)  # … but nothing comes out
    # a refused calibration makes an otherwise working stage "degraded"
    ok = StageCounters()
    st = ok.status(
        "label", started_ns=0, state="ok", dropped_here=0, calibration_version=3, problem="why"
    )
    assert (st.state, st.reason) == ("degraded", "why")


def test_a_forged_sequence_number_is_a_jump_not_a_billion_drops() -> None:
    c = StageCounters()
    for seq in range(10):
        c.saw_frame(seq, 0, "stream-a")
    c.saw_frame(10**9, 0, "stream-a")  # the attack
    for seq in range(10, 20):
        c.saw_frame(seq, 0, "stream-a")
    assert (c.seq_gaps, c.seq_jumps) == (0, 2)  # there and back
    # within the bound: frames lost, confirmed one by one as the sequence goes on after it
    for seq in range(19 + MAX_PLAUSIBLE_GAP, 19 + 2 * MAX_PLAUSIBLE_GAP):
        c.saw_frame(seq, 0, "stream-a")
    assert c.seq_gaps == MAX_PLAUSIBLE_GAP - 1
    # a capture that restarts begins at 0 again, with a new stream identity
    for seq in (0, 2, 3):
        c.saw_frame(seq, 0, "stream-b")
    assert (c.stream_restarts, c.seq_gaps) == (1, MAX_PLAUSIBLE_GAP - 1 + 1)
    st = c.status("label", started_ns=0, state="ok", dropped_here=0, calibration_version=0)
    assert (st.dropped, st.seq_jumps, st.stream_restarts) == (MAX_PLAUSIBLE_GAP, 2, 1)


def test_a_forged_frame_pair_ahead_moves_the_drops_by_at_most_one() -> None:
    c = StageCounters()
    for seq in range(10):
        c.saw_frame(seq, 0, "s")
    for pair in range(5):
        ahead = 10 + pair + MAX_PLAUSIBLE_GAP - 1  # the largest gap still plausible
        c.saw_frame(ahead, 0, "s")  # the forger's pair, between two genuine frames
        c.saw_frame(ahead + 1, 0, "s")
        c.saw_frame(10 + pair, 0, "s")  # the genuine sequence goes on
        assert (c.seq_gaps, c.seq_jumps) == (pair + 1, pair + 1)
    # a single forged frame ahead moves nothing but the jumps
    c.saw_frame(500, 0, "s")
    c.saw_frame(15, 0, "s")
    assert (c.seq_gaps, c.seq_jumps, c.last_seq) == (5, 6, 15)


def _status(pid: int, started_ns: int, **counts) -> ServiceStatus:
    return ServiceStatus(
        service="pose",
        pid=pid,
        host=socket.gethostname(),
        started_ns=started_ns,
        state="ok",
        **counts,
    )


def test_totals_survive_restarts() -> None:
    totals = CounterTotals()
    totals.record(_status(10, 1, frames_in=5, frames_out=4, errors={"processing": 1}))
    totals.record(_status(10, 1, frames_in=50, frames_out=40, errors={"processing": 7}))
    # restarted: the new process counts from zero
    totals.record(_status(11, 2, frames_in=3, frames_out=3, dropped=2, errors={"bad": 1}))
    t = totals.totals()["pose"]
    assert (t.frames_in, t.frames_out, t.dropped, t.processes) == (53, 43, 2, 2)
    assert t.errors == {"processing": 7, "bad": 1}


def test_forged_statuses_in_a_process_name_cannot_raise_its_totals() -> None:
    genuine = _status(10, 1, frames_in=50, frames_out=40, dropped=1, errors={"bad": 2})
    forged = _status(10, 1, frames_in=10**9, frames_out=10**9, dropped=10**9, errors={"x": 9})
    # both answer one poll: each counter is the smaller, whichever came first
    assert least(forged, genuine).frames_in == least(genuine, forged).frames_in == 50
    assert least(forged, genuine).errors == {} and least(genuine, genuine).errors == {"bad": 2}
    totals = CounterTotals()
    totals.record(least(genuine, forged))
    # another start time for the same pid and host is the same process: the genuine
    # counts are never "finished" and added twice
    totals.record(least(msgspec.structs.replace(forged, started_ns=2), genuine))
    totals.record(genuine)
    t = totals.totals()["pose"]
    assert (t.frames_in, t.frames_out, t.dropped, t.processes) == (50, 40, 1, 1)


def test_a_forged_copy_from_before_the_first_frame_keeps_the_stream_its_frames_count_under() -> (
    None
):
    """A forger that copied a capture's status before its first frame (no stream yet)
    and answers with a billion frames: whichever reply comes first, the merged status
    names the genuine stream (ovis up counts the run's frames by it, issue 28's forged
    replies made it count none)."""
    genuine = msgspec.structs.replace(_status(10, 1, frames_in=50), stream="9a76e24d")
    forged = _status(10, 1, frames_in=10**9)
    for first, second in ((forged, genuine), (genuine, forged)):
        got = claimed_once(first, second)
        assert (got.stream, got.frames_in, got.state) == ("9a76e24d", 50, "degraded")


def test_a_forged_ok_in_a_process_name_never_hides_its_trouble() -> None:
    """Two different replies for one process: which is genuine cannot be told, so the
    state is the worse and at least "degraded", said; one reply twice is just that."""
    genuine = _status(10, 1, frames_in=50, frames_out=40)
    assert claimed_once(genuine, genuine) is genuine
    failing = msgspec.structs.replace(genuine, state="failing", reason="pose: 9 errors")
    forged_ok = msgspec.structs.replace(genuine, frames_in=10**9)
    for first, second in ((failing, forged_ok), (forged_ok, failing)):
        got = claimed_once(first, second)
        assert (got.state, got.frames_in) == ("failing", 50)
        assert got.reason.startswith("two different status answers in its name")
        assert "failing (pose: 9 errors)" in got.reason
    lost = msgspec.structs.replace(genuine, service="capture", state="source lost")
    assert claimed_once(forged_ok, lost).state == "source lost"  # ovis up still exits 3
    both_ok = claimed_once(genuine, forged_ok)  # both "ok", counts differ: a forger
    assert (both_ok.state, both_ok.frames_in) == ("degraded", 50)
    waiting = msgspec.structs.replace(genuine, state="waiting for input")
    assert claimed_once(waiting, forged_ok).state == "degraded"


def test_the_summary_flags_an_error_over_matched_objects_only() -> None:
    assert position_error_flag(100, 0, 2) == ""
    assert position_error_flag(120, 5782, 11523) == (
        "over 120 matched objects only: 5782 missed and 11523 spurious are not in it"
    )
    assert position_error_flag(0, 10, 0) != ""
    summary = LiveScore().summary({}, {}, 1.0)
    assert summary.position_error_flag == "" and summary.health == {}


def test_the_health_message_takes_only_a_verdict_not_a_service_state() -> None:
    """A stage's own state ("waiting for input", "no frames") is not a verdict: the
    stream health message keeps to its schema's states (a subscriber refused it)."""
    watch = StreamWatch(1.0)
    watch.update(0.1)
    common = dict(
        last_seq=3, seconds_since_frame=0.1, last_frame_age_ms=2.0, frames_dropped=0,
        calibration_version=1,
    )  # fmt: skip
    for state in ("waiting for input", "no frames", "ok"):
        assert watch.message(**common, verdict=(state, "")).state == "ok"
    failing = watch.message(**common, verdict=("failing", "3 of 4 inputs failed"))
    assert (failing.state, failing.reason) == ("failing", "3 of 4 inputs failed")


def _stage(name: str, state: str, frames_out: int = 0, **fields) -> ServiceStatus:
    return ServiceStatus(
        service=name, pid=1, host="h", started_ns=0, state=state, frames_out=frames_out, **fields
    )


def test_the_summary_health_names_faults_not_stages_idle_after_their_work() -> None:
    statuses = [
        _stage("capture", "recording ended", 30),  # its recording read to the end
        _stage("preprocess", "waiting for input", 30),  # done with the frames it had
        _stage("label", "starting"),  # never handled a frame: a fault
        _stage("pose", "failing", 3, reason="1 of 4 inputs failed:"),  # said as it is
        _stage("calibrator", "waiting for input", last_error="frame 3: no board"),
        _stage("fusion", "no calibration"),
    ]
    summary = LiveScore().summary({s.service: s for s in statuses}, {}, 1.0)
    assert summary.health == {
        "label": "starting",
        "pose": "failing: 1 of 4 inputs failed:",
        "calibrator": "waiting for input: frame 3: no board",
        "fusion": "no calibration",
    }


def test_the_summary_counts_the_frames_of_the_runs_streams_none_if_it_has_none() -> None:
    live = LiveScore()
    for stream in ("ours", "ours", "theirs"):
        msg = ObstacleFrame(
            seq=0, stamp_ns=10**9, published_ns=10**9, frame_age_ms=1.0,
            calibration_version=1, robot=None, obstacles=[], planner=[], stream=stream,
        )  # fmt: skip
        live.add_obstacles(msg, 10**9 + 1_000_000)
    counted = [
        live.summary({}, {}, 1.0, streams=streams).frames_processed
        for streams in (None, {"ours"}, set())
    ]
    assert counted == [3, 2, 0]  # every stream, the run's own, none

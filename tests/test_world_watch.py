"""`ovis up --cameras`'s counts of a run's window (common/analysis/multicam.WorldWatch):
the world frames stamped from the scored window's start on, each camera's frames in
them, and the late frames fusion counted meanwhile (not before)."""

from __future__ import annotations

from ovis.common.analysis.multicam import WorldWatch
from ovis.common.config import load_config
from ovis.common.messages import WorldFrame

MS = 1_000_000


def _world(seq: int, stamp_ms: int, cameras: list[str], late: dict[str, int]) -> WorldFrame:
    return WorldFrame(
        seq=seq,
        stamp_ns=stamp_ms * MS,
        published_ns=stamp_ms * MS + 12 * MS,
        arena="a",
        objects=[],
        cameras=cameras,
        late_frames=late,
    )


def test_counts_from_the_window_start_leave_the_start_up_out() -> None:
    cam = load_config().camera
    watch = WorldWatch({"n": cam, "s": cam})
    frames = [
        (0, ["n"], {"n": 0, "s": 1}),  # start-up: s late once, then missing
        (33, ["n"], {"n": 0, "s": 2}),
        (67, ["n", "s"], {"n": 0, "s": 2}),
        (100, ["n", "s"], {"n": 0, "s": 2}),
        (133, ["n"], {"n": 0, "s": 3}),  # in the window: s late once
    ]
    for seq, (stamp, cams, late) in enumerate(frames):
        watch.add_world(_world(seq, stamp, cams, late), (stamp + 15) * MS)
    assert watch.fused() == {"n": 5, "s": 2}
    assert watch.fused(60 * MS) == {"n": 3, "s": 2}
    assert watch.late() == {"n": 0, "s": 3}
    assert watch.late(60 * MS) == {"n": 0, "s": 1}
    # fusion restarted (its counts begin again): never a negative count
    watch.add_world(_world(9, 167, ["n", "s"], {"n": 0, "s": 0}), 182 * MS)
    assert watch.late(60 * MS) == {"n": 0, "s": 0}

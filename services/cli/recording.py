"""Recording commands: ``ovis record`` (the bus into an MCAP session file, or
``--recover`` a cut one) and ``ovis replay`` (a session back onto the bus)."""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from ovis.services.cli.errors import UserError
from ovis.services.cli.options import (
    ArenaOpt,
    ConfigOpt,
    ConnectOpt,
    arena_topics,
    config_with_options,
    stop_on_signals,
)

__all__ = ["prepare_recorded_source", "register"]

PROGRESS_S = 1.0


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


class _Progress:
    """One status line on stderr: rewritten in place on a terminal, else a line every
    few seconds (logs stay readable)."""

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()
        self.last = 0.0
        self.every = PROGRESS_S if self.tty else 5.0

    def show(self, text: str, *, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self.last < self.every:
            return
        self.last = now
        if self.tty:
            sys.stderr.write("\r\x1b[2K" + text)
        else:
            sys.stderr.write(text + "\n")
        sys.stderr.flush()

    def done(self) -> None:
        if self.tty:
            sys.stderr.write("\n")


def _recover(source: Path, target: Path | None, compression: str) -> None:
    from ovis.common.recording.session import RecordingError, recover

    if target is None:
        raise UserError("--recover needs where to write: ovis record --recover CUT.mcap FIXED.mcap")
    if target.resolve() == source.resolve():
        raise UserError("--recover writes a new file: give another name than the cut one")
    try:
        report = recover(source, target, compression=compression)
    except RecordingError as exc:
        raise UserError(str(exc)) from None
    topics = ", ".join(f"{t} {n}" for t, n in sorted(report.topics.items()))
    print(f"{report.note}\nwrote {target}: {report.messages} messages ({topics}), indexed")


def record(
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Session file to write (.mcap).")
    ] = None,
    target: Annotated[
        Path | None, typer.Argument(help="With --recover: the repaired file to write.")
    ] = None,
    connect: ConnectOpt = None,
    config: ConfigOpt = None,
    arena: ArenaOpt = None,
    topics: Annotated[
        list[str] | None,
        typer.Option(
            help="Topics to record (repeatable): a key under ovis/<arena>/ such as "
            "'obstacles' or 'status/*', or a full key expression starting with 'ovis/'. "
            "Default: everything of the arena."
        ),
    ] = None,
    duration: Annotated[
        float | None, typer.Option(min=0.0, help="Stop after this many seconds (default: Ctrl-C).")
    ] = None,
    frames: Annotated[
        str,
        typer.Option(help="Frames to keep: 'every', 'none' or at most N a second, e.g. '5/s'."),
    ] = "every",
    views: Annotated[
        bool,
        typer.Option(
            help="Also write the Foxglove views: the camera (JPEG, /ovis/<arena>/image) "
            "and the arena (/ovis/<arena>/scene)."
        ),
    ] = True,
    compression: Annotated[
        str, typer.Option(help="Chunk compression: lz4 (fast), zstd (smaller) or none.")
    ] = "lz4",
    ros2: Annotated[
        bool,
        typer.Option(
            "--ros2",
            help="Also write the data as ROS 2 messages into a rosbag2 bag beside the "
            "session (S.mcap -> S.ros2/, MCAP storage) that `ros2 bag play` and rosbags "
            "read: /ovis/obstacles (PoseArray), /ovis/markers, /ovis/robots/robot_<id>/odom, "
            "/ovis/camera/camera_info, /tf_static, /ovis/camera/image/compressed (JPEG of "
            "each recorded frame, with its camera_info). Obstacles are converted from the "
            "first calibration on. The [ros2] namespace, frame_id and topics apply; its "
            "rates do not (every message is recorded). See docs/recording.md.",
        ),
    ] = False,
    force: Annotated[bool, typer.Option(help="Overwrite --out if it exists.")] = False,
    recover_file: Annotated[
        Path | None,
        typer.Option(
            "--recover",
            help="Repair CUT.mcap (a recorder killed outright) into TARGET: every message up "
            "to its last complete chunk, with the index it lacks. Records nothing.",
            dir_okay=False,
        ),
    ] = None,
) -> None:
    """Record the bus into an MCAP session file that Foxglove opens.

    Every message of the chosen topics is written as it travelled (msgpack, with its
    JSON Schema), stamped with its receipt time (and publication time when Zenoh gives
    one); frames' pixels are compressed losslessly and replay rebuilds them bit-exact.
    The file is written in chunks and indexed when recording stops (Ctrl-C, SIGTERM or
    --duration); a recorder killed outright leaves a file readable up to its last
    chunk (replay reads it; --recover repairs it). See docs/recording.md.
    """
    from ovis.common.recording.pacing import FrameGate
    from ovis.common.recording.session import COMPRESSIONS, RecordingError, SessionWriter
    from ovis.services.bus import open_session
    from ovis.services.recorder import Recorder, topic_keys

    if compression not in COMPRESSIONS:
        raise UserError(f"--compression {compression!r}: choose {', '.join(COMPRESSIONS)}")
    if recover_file is not None:
        _recover(recover_file, target or out, compression)
        return
    if out is None:
        raise UserError("say where to record: ovis record --out SESSION.mcap")
    if target is not None:
        raise UserError(f"unexpected argument {target}: the session file is given with --out")
    if out.exists() and not force:
        raise UserError(f"{out} exists; give another --out or add --force to overwrite it")
    try:
        gate = FrameGate(frames)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    cfg = config_with_options(config, connect=connect, arena=arena)
    bus = arena_topics(cfg)
    keys = topic_keys(bus, topics)
    stream = bag = None
    if ros2:
        from ovis.common.ros2.bag import BagError, RosBag, bag_path
        from ovis.common.ros2.stream import RosStream

        stream = RosStream(cfg.ros2, paced=False)  # a record: every message
        bag_dir = bag_path(out)
        _clear_bag(bag_dir, force)
    import zenoh

    try:
        for k in keys:
            zenoh.KeyExpr(k)
    except zenoh.ZError as exc:
        raise UserError(f"--topics: not a Zenoh key expression: {exc}") from None
    stop = stop_on_signals()
    meta = {"arena": bus.arena, "topics": " ".join(keys), "frames": gate.spec}
    with open_session(cfg.zenoh, wait=False) as session:
        try:
            writer = SessionWriter(out, compression=compression, metadata=meta)
        except RecordingError as exc:
            raise UserError(str(exc)) from None
        if stream is not None:
            try:
                bag = RosBag(bag_dir)
            except BagError as exc:
                writer.close()
                raise UserError(str(exc)) from None
        rec = Recorder(session, writer, bus, keys, frames=gate, views=views, ros2=stream, bag=bag)
        wants_calibration = any(
            zenoh.KeyExpr(k).intersects(zenoh.KeyExpr(bus.calibration)) for k in keys
        )
        print(
            f"recording {', '.join(keys)} into {out}"
            + (f" and the ROS 2 bag {bag.path}/" if bag is not None else "")
            + f" (frames: {gate.spec}); "
            + ("Ctrl-C stops" if duration is None else f"for {duration:g} s"),
            file=sys.stderr,
        )
        if wants_calibration:
            rec.follow_calibration()
        # Alive once it listens: `ovis up --record` starts the capture after that.
        alive = session.liveliness().declare_token(bus.alive("recorder"))
        t0 = time.monotonic()
        progress = _Progress()
        try:
            while not stop.wait(0.2):
                if duration is not None and time.monotonic() - t0 >= duration:
                    break
                progress.show(_status_line(rec, time.monotonic() - t0))
        finally:
            alive.undeclare()
            rec.close()
            progress.show(_status_line(rec, time.monotonic() - t0), force=True)
            progress.done()
    c = rec.counts
    notes = []
    if c.frames_missed:
        notes.append(f"{c.frames_missed} frames never reached the recorder (sequence gaps)")
    if wants_calibration and not rec.calibration_recorded:
        notes.append("no calibrator answered: the session carries no calibration")
    if c.view_errors:
        notes.append(f"{c.view_errors} messages had no Foxglove view ({c.last_error})")
    if stream is not None and stream.waiting:
        notes.append(f"{stream.waiting} obstacle frames before any calibration: not in ROS 2")
    if c.ros2_errors:
        notes.append(f"{c.ros2_errors} messages had no ROS 2 conversion ({c.last_error})")
    print(
        f"wrote {out}: {sum(s.messages for s in writer.stats.values())} messages, "
        f"{_mb(out.stat().st_size)}"
        + ("; " + "; ".join(notes) if notes else "")
        + ". Open it in Foxglove, or `ovis replay` it."
    )
    if bag is not None:
        print(
            f"wrote the ROS 2 bag {bag.path}/: {sum(bag.counts.values())} messages on "
            f"{len(bag.counts)} topics. Play it with `ros2 bag play {bag.path}`."
        )


def _clear_bag(path: Path, force: bool) -> None:
    """Make room for the ROS 2 bag at ``path``: refuse if something is there, unless
    ``force`` and it is a bag (its metadata.yaml and storage files, nothing else)."""
    if not path.exists():
        return
    if not force:
        raise UserError(f"{path} exists; give another --out or add --force to overwrite it")
    files = list(path.iterdir()) if path.is_dir() else [path]
    if not path.is_dir() or not all(
        f.is_file() and (f.name == "metadata.yaml" or f.suffix in {".mcap", ".db3"}) for f in files
    ):
        raise UserError(f"{path} is in the way of the ROS 2 bag and is not one; move it away")
    for f in files:
        f.unlink()
    path.rmdir()


def _status_line(rec: Any, elapsed: float) -> str:
    stats = rec.writer.stats
    total = sum(s.messages for s in stats.values())
    per_topic = ", ".join(
        f"{t.rsplit('/', 1)[-1]} {s.messages}" for t, s in sorted(stats.items()) if s.messages
    )
    backlog = rec.backlog()
    return (
        f"{elapsed:6.1f} s  {total} messages  {_mb(rec.writer.bytes_written())}"
        + (f"  ({per_topic})" if per_topic else "  (nothing yet: is the pipeline running?)")
        + (f"  backlog {backlog}" if backlog > 10 else "")
    )


TopicOpt = Annotated[
    str | None,
    typer.Option(
        "--topic",
        help="An MCAP written by another tool: the topic of the image channel to read "
        "(foxglove.CompressedImage/RawImage, sensor_msgs/msg/CompressedImage/Image); "
        "needed when it has several.",
    ),
]


def _image_channel(path: Path | str, topic: str | None) -> str | None:
    """For a file another tool wrote: which channel's images become frames and their
    size (its first image read, so a file ovis cannot use is refused before anything
    starts); None for an ovis recording. RecordingError saying why not."""
    from ovis.common.recording.foreign import choose_channel, first_image

    info = choose_channel(path, topic)
    if info is None:
        return None
    image = first_image(path, info)
    colour = "grey" if image.ndim == 2 else "BGR"
    return f"frames from {info.describe()}: {image.shape[1]}x{image.shape[0]} {colour}"


def replay(
    session_file: Annotated[
        Path,
        typer.Argument(
            help="Session file (.mcap) written by `ovis record`, or an MCAP with an image "
            "channel written by another tool (Foxglove, ROS 2).",
            dir_okay=False,
        ),
    ],
    connect: ConnectOpt = None,
    config: ConfigOpt = None,
    speed: Annotated[
        str,
        typer.Option(
            help="Pace: a factor of the recorded pace (1, 0.5, 4) or 'max' (as fast as Zenoh "
            "takes them; the stages keep the newest frame, so a slow one skips frames)."
        ),
    ] = "1",
    loop: Annotated[
        bool,
        typer.Option(help="Start again at the end (frames keep increasing seq and stamps)."),
    ] = False,
    only: Annotated[
        list[str] | None,
        typer.Option(
            help="Replay only what this stage publishes (repeatable): capture (frames, "
            "ground truth and the physical world's drive reports: the live pipeline "
            "processes the recorded images), preprocess, label, pose, calibrator, planner "
            "(the robots' commands; a robot refuses them: a recording keeps no proof)."
        ),
    ] = None,
    arena: Annotated[
        str | None, typer.Option(help="Publish under ovis/<arena>/ (default: as recorded).")
    ] = None,
    stamps: Annotated[
        str,
        typer.Option(
            help="Frame stamps: 'original' (bit-exact), 'now' (moved so the first frame is "
            "stamped now) or 'auto' (original unless the recording is too old for the "
            "services, which refuse frames stamped an hour away from their clock)."
        ),
    ] = "auto",
    topic: TopicOpt = None,
) -> None:
    """Publish a recorded session back on the bus at its recorded pace.

    Each bus message goes out on its recorded key exactly as it travelled; frames are
    rebuilt bit-exact. With --only capture, a pipeline started with the recording's
    calibration (ovis up --source SESSION.mcap does both) processes the recorded images
    again and publishes the same obstacles. An MCAP written by another tool gives the
    images of its image channel (--topic picks one) as frames on ovis/<arena>/frames,
    at the pace of their log times. See docs/recording.md.
    """
    from ovis.common.messages import Topics
    from ovis.common.recording.pacing import parse_speed
    from ovis.common.recording.session import RecordingError
    from ovis.services.bus import open_session
    from ovis.services.replay import FLUSH_S, DeliveryCheck, Replayer

    try:
        pace = parse_speed(speed)
        if arena is not None:
            Topics(arena)
        images = _image_channel(session_file, topic)  # unusable: say so before connecting
    except ValueError as exc:  # RecordingError too
        raise UserError(str(exc)) from None
    cfg = config_with_options(config, connect=connect)
    if images is not None:
        print(images, file=sys.stderr)
        arena = arena or cfg.service.arena  # a foreign file names no arena
    stop = stop_on_signals()
    with contextlib.ExitStack() as sessions:
        # sees the replay's messages come back: declared before the replay's session opens
        checker = sessions.enter_context(open_session(cfg.zenoh, wait=False))
        delivered = DeliveryCheck(checker)
        sessions.callback(delivered.close)
        session = sessions.enter_context(open_session(cfg.zenoh, wait=False))
        try:
            player = Replayer(
                session,
                session_file,
                speed=pace,
                loop=loop,
                only=only,
                arena=arena,
                stamps=stamps,
                stop=stop,
                topic=topic,
            )
        except (RecordingError, ValueError) as exc:
            raise UserError(str(exc)) from None
        progress = _Progress()
        done = threading.Event()

        def show() -> None:
            while not done.wait(0.5):
                r = player.report
                progress.show(
                    f"replayed {r.messages} messages ({r.frames} frames), pass {r.passes + 1}"
                )

        threading.Thread(target=show, daemon=True).start()
        try:
            report = player.run()
        except RecordingError as exc:
            raise UserError(str(exc)) from None
        finally:
            done.set()
            progress.done()
            arrived = player.close(delivered)  # every message sent before the process ends
    if not arrived:
        print(
            f"warning: the last messages did not come back through the router within "
            f"{FLUSH_S:g} s: the last ones may not have reached their subscribers",
            file=sys.stderr,
        )
    if report.cut:
        print(f"warning: {report.cut}", file=sys.stderr)
    if report.shift_s:
        print(f"frame stamps moved by {report.shift_s:.0f} s (--stamps)", file=sys.stderr)
    if report.skipped:
        print(
            f"warning: {report.skipped} messages could not be published (the last: "
            f"{report.skip_reason})",
            file=sys.stderr,
        )
    topics = ", ".join(f"{k.rsplit('/', 1)[-1]} {n}" for k, n in sorted(report.by_topic.items()))
    print(
        f"replayed {report.messages} messages ({topics or 'none'}) in {report.passes} pass(es)"
        + (f" from {report.channel}" if report.channel else "")
    )


def prepare_recorded_source(cfg: Any) -> str | None:
    """For ``ovis up --source SESSION.mcap``: check the file (for one another tool wrote:
    its image channel, ``source_topic``, and its first image), and give the calibrator
    the recording's calibration unless its state folder holds one; None for other
    sources."""
    from ovis.common.recording.calibration import adopt_recorded_calibration
    from ovis.common.recording.session import RecordingError
    from ovis.services.replay import is_recording

    source = cfg.service.source
    if not is_recording(source):
        return None
    try:
        images = _image_channel(source, cfg.service.source_topic or None)
        adopted = adopt_recorded_calibration(source, cfg.service.state_dir)
    except RecordingError as exc:
        raise UserError(str(exc)) from None
    return adopted if images is None else f"{images}; {adopted}"


def register(app: typer.Typer) -> None:
    for command in (record, replay):
        app.command()(command)

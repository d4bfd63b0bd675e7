"""Capture service: frames from the configured source, stamped with a sequence number,
the capture time and the stream's identity (random, new at each start), published on
``ovis/<arena>/frames`` (and, for the simulated arena, the ground truth on
``ovis/<arena>/truth``).

A source that fails is reopened after waits that grow while it stays away
(:mod:`ovis.common.capture.backoff`); a folder or video that ended with looping off is
lost for good. Each loss is recorded (:mod:`ovis.common.pipeline.gaps`), said at once
and then every ``SOURCE_REPEAT_S`` on ``ovis/<arena>/source`` (the pose stage folds it
into the stream's health), and shown in the status: state "source lost", the reason,
the losses so far.

The physical world with driven robots (``[navigation] drive``) takes their commands
from ``ovis/<arena>/robots/<id>/cmd``: only those the planner's key signed (the others
are refused and counted, ``unproven_cmd`` in the status and ``refused`` in each robot's
report); or, with ``[navigation] follow = "cmd_vel"``, from each robot's ROS 2
``cmd_vel`` (:mod:`ovis.services.follow_cmd_vel`). It says with each frame what each
robot did, and what it follows, on ``ovis/<arena>/robots/<id>/drive``
(:class:`~ovis.common.messages.RobotDrive`), and so at each instant a frame was due
while its camera is unplugged (``SIGUSR1`` toggles it: the camera's source lost
mid-drive, the world running on)."""

from __future__ import annotations

import contextlib
import secrets
import threading
import time
from typing import TYPE_CHECKING, Any

import msgspec
import zenoh

from ovis.common.capture.backoff import Backoff
from ovis.common.capture.sources import (
    FrameSource,
    NoFrameError,
    SourceEndedError,
    SourceError,
)
from ovis.common.messages import Frame, RobotCommand, RobotDrive, ServiceStatus, TruthFrame
from ovis.common.pipeline.gaps import SourceGaps
from ovis.common.pipeline.health import SOURCE_REPEAT_S
from ovis.common.pipeline.pacing import Pacer
from ovis.services.replay import capture_from_recording, is_recording
from ovis.services.ros2_source import open_source
from ovis.services.service import Service

if TYPE_CHECKING:
    from ovis.common.ros2.cmd_vel import TwistCommand


def announce_source(service: Service, gaps: SourceGaps, changed: threading.Event) -> None:
    """Publish the source's state on ``ovis/<arena>/source`` when ``changed`` is set,
    and every ``SOURCE_REPEAT_S`` while the source is lost, until the service stops."""
    publish = service.publisher(service.topics.source, drop=False)
    while not service.stop.is_set():
        changed.wait(SOURCE_REPEAT_S)
        if not (changed.is_set() or gaps.lost):
            continue
        changed.clear()
        try:
            publish(gaps.message(time.time_ns()))
        except zenoh.ZError:  # the session is closing
            return


class Commands:
    """The commands the driven source in use follows: the planner's on the bus, or
    with ``[navigation] follow = "cmd_vel"`` each robot's ROS 2 ``cmd_vel``
    (:mod:`ovis.services.follow_cmd_vel`, open while :meth:`following` lasts)."""

    def __init__(self, service: Service) -> None:
        self.source: Any = None
        self.refused = 0
        self.clamped = 0  # cmd_vel over the robot's limits, clamped to them
        self.follows = service.config.navigation.follow
        self._service = service
        self._publishers: dict[int, Any] = {}
        if self.follows == "ovis":
            self._follow_ovis()

    def _give(self, robot_id: int, v: float, omega: float, stamp_ns: int, stop: str) -> None:
        source = self.source
        if source is not None:
            source.command(robot_id, v, omega, stamp_ns, stop)

    def _follow_ovis(self) -> None:
        service = self._service
        proven = service.proven("planner", "cmd")

        def on_sample(sample: zenoh.Sample) -> None:
            payload = service.take(sample.payload, "small", "cmd")
            if payload is None or not proven(sample, payload):
                self.refused += 1
                return
            msg = service.decode(payload, RobotCommand, "cmd")
            if msg is None:
                self.refused += 1
            else:
                self._give(msg.robot_id, msg.v_cm_s, msg.omega_deg_s, msg.stamp_ns, msg.stop)

        service.session.declare_subscriber(service.topics.commands_all, on_sample)

    def following(self) -> contextlib.AbstractContextManager[None]:
        """What must stay open while the commands are followed (ROS 2's node)."""
        if self.follows != "cmd_vel":
            return contextlib.nullcontext()
        from ovis.services.follow_cmd_vel import follow_cmd_vel

        def follow(robot_id: int, command: TwistCommand) -> None:
            self.clamped += command.clamped
            self._give(robot_id, command.v_cm_s, command.omega_deg_s, command.stamp_ns, "")

        def refuse(why: str) -> None:
            self.refused += 1
            self._service.error("refused_cmd_vel", f"cmd_vel not followed: {why}")

        return follow_cmd_vel(self._service, follow, refuse)

    def report(self, stamp_ns: int) -> None:
        """Each driven robot's :class:`RobotDrive` of the frame stamped ``stamp_ns``."""
        if self.source is None:
            return
        for fields in self.source.drives():
            ident = int(fields["robot_id"])
            if ident not in self._publishers:
                topic = self._service.topics.drive(ident)
                self._publishers[ident] = self._service.publisher(topic)
            counts = {"refused": self.refused, "clamped": self.clamped}
            drive = RobotDrive(stamp_ns=stamp_ns, follows=self.follows, **counts, **fields)
            self._publishers[ident](drive)


def main(service: Service) -> None:
    cfg = service.config.service
    gaps, backoff, changed = SourceGaps(), Backoff(), threading.Event()
    # frames a source on its own clock missed (their instant passed while it was busy
    # rendering the one before: the physical world) count as dropped here
    missed = [0, None]  # [missed by sources closed before, the source now]

    def amend_status(status: ServiceStatus) -> ServiceStatus:
        now = missed[0] + getattr(missed[1], "missed", 0)
        status = msgspec.structs.replace(status, dropped=status.dropped + now)
        return gaps.amend(status, time.time_ns())

    service.amend_status = amend_status
    threading.Thread(
        target=announce_source, args=(service, gaps, changed), name="source", daemon=True
    ).start()

    def prerendering(done: int, total: int) -> None:
        service.state = f"prerendering {done}/{total}"
        if done == total or done % max(1, total // 4) == 0:
            service.log.info("prerendered %d/%d frames", done, total)

    def lost(exc: SourceError, then: str) -> None:
        if gaps.lose(str(exc), time.time_ns(), ended=isinstance(exc, SourceEndedError)):
            service.log.warning("source lost: %s", exc)
        changed.set()
        service.error("source", f"{exc}; {then}")

    if is_recording(cfg.source):  # a session file: its frames bit-exact, recorded pace
        capture_from_recording(service, lambda why: lost(SourceEndedError(why), "lost for good"))
        return
    publish_frame = service.publisher(service.topics.frames)
    publish_truth = service.publisher(service.topics.truth)
    commands = Commands(service) if service.config.navigation.drive else None
    following = contextlib.ExitStack()
    if commands is not None:
        following.enter_context(commands.following())
    pacer = Pacer(cfg.fps)
    source: FrameSource | None = None
    seq = 0

    def unplug() -> None:
        """The physical world's camera unplugged, or plugged back (module docstring)."""
        if hasattr(source, "unplugged"):  # said by the loss and the return it makes
            source.unplugged = not source.unplugged  # type: ignore[union-attr]
        else:
            service.log.warning("SIGUSR1 ignored: only the physical world's camera unplugs")

    service.on_user_signal = unplug  # SIGUSR1's handler (ovis.services.service.run)
    stream = secrets.token_hex(8)  # sequence numbers start again with a new stream
    service.log.info("stream %s", stream)

    service.ready()
    try:
        while not service.stop.is_set():
            try:
                if source is None:
                    source = open_source(cfg.source, service.config, progress=prerendering)
                    missed[1] = source
                    if commands is not None:
                        commands.source = source if getattr(source, "driving", None) else None
                    service.log.info("capturing from %s", source.description)
                    service.state = "ok"
                image, truth = source.read()
            except NoFrameError as exc:  # open, no frame this time: read it again
                lost(exc, "reading it again")
                if commands is not None:
                    commands.report(time.time_ns())  # the world runs on
                continue
            except SourceEndedError as exc:  # nothing more will come: idle until stopped
                lost(exc, "lost for good")
                service.stop.wait()
                break
            except SourceError as exc:
                wait = backoff.next_wait()
                lost(exc, f"next attempt in {wait:g} s")
                if source is not None:
                    missed[0] += getattr(source, "missed", 0)
                    missed[1] = None
                    if commands is not None:
                        commands.source = None
                    source.close()
                    source = None
                service.stop.wait(wait)
                continue
            backoff.reset()
            # a simulated camera on a shared trigger says when it exposed its frame
            stamp = truth.stamp_ns if truth is not None and truth.stamp_ns else time.time_ns()
            stamp = getattr(source, "capture_ns", None) or stamp  # a ROS 2 camera's own
            frame = Frame.from_image(
                image,
                seq=seq,
                stamp_ns=stamp,
                source=source.description,
                copy=False,
                stream=stream,
            )
            publish_frame(frame)  # first: the truth is for checking, not on the frame's path
            if truth is not None:
                publish_truth(TruthFrame(seq=seq, objects=truth.objects, stamp_ns=stamp))
            if commands is not None:
                commands.report(stamp)
            service.saw_frame(seq, stamp, stream)
            service.sent()
            seq += 1
            back = gaps.delivered(time.time_ns())
            if back is not None:
                changed.set()
                service.log.info("source back after %.1f s (lost: %s)", back.seconds, back.reason)
            # a source on its own clock (the physical world) waits for its frames itself
            service.stop.wait(0.0 if getattr(source, "self_paced", False) else pacer.delay())
    finally:
        following.close()
        if source is not None:
            source.close()

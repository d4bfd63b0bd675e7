"""Fusion service: the detections of several cameras (``[[cameras]]``), each from its own
capture → preprocess → label → pose chain on ``ovis/<arena>/cam/<name>/obstacles``,
merged into one world on ``ovis/<arena>/world`` (:class:`WorldFrame`, signed with the
"fusion" role's key; the logic is :mod:`ovis.common.fusion`). A camera that stops
leaves its area uncovered: after ``service.frame_timeout_s`` it is no longer waited
for, and each world frame names the cameras missing from it."""

from __future__ import annotations

import secrets
import threading
import time

import numpy as np
import zenoh

from ovis.common.fusion.accuracy import AccuracyMap
from ovis.common.fusion.sightings import COLUMNS, Sightings, detection_row
from ovis.common.fusion.world import WorldFrameResult, WorldFuser
from ovis.common.messages import CalibrationUpdate, ObstacleFrame, WorldFrame, WorldObject
from ovis.common.pipeline.hosting import camera_model
from ovis.services.inbox import Inbox
from ovis.services.service import Service
from ovis.services.trust import signer_for

__all__ = ["camera_model", "main"]

#: longest wait for a camera's frame while no world frame is open, s (how soon a silent
#: camera shows in the status); with one open, the wait ends when its wait runs out
IDLE_S = 0.05


def frame_columns(name: str, msg: ObstacleFrame) -> Sightings:
    """One camera's obstacle frame as detection columns, as fusion takes them (marked
    robots seen in this frame, by marker, at their marker's height; other objects with
    their measured height's covariance where their camera fitted one; see
    :func:`~ovis.common.fusion.sightings.detection_row`)."""
    rows = [
        detection_row(r.x_cm, r.y_cm, r.z_cm, r.radius_cm, heading_deg=r.heading_deg,
                      marker_id=r.marker_id, z_source="marker")
        for r in msg.robots
        if r.age_s == 0.0  # seen in this frame, not predicted
    ]  # fmt: skip
    objects = list(msg.obstacles)
    if not msg.robots and msg.robot is not None:
        objects.insert(0, msg.robot)
    robots = len(rows) + (not msg.robots and msg.robot is not None)
    rows += [
        detection_row(o.x_cm, o.y_cm, o.z_cm, o.radius_cm, covariance_cm2=o.covariance_cm2,
                      z_source=o.z_source, z_unmeasured=o.z_unmeasured,
                      z_fit_cm=o.z_fit_cm)
        for o in objects
    ]  # fmt: skip
    data = np.array(rows, float).reshape(-1, COLUMNS)
    return Sightings((name,), data, np.arange(len(data)) < robots, resolved=False)


def world_message(
    r: WorldFrameResult, seq: int, arena: str, late: dict[str, int], stream: str
) -> WorldFrame:
    """The world topic's message of one fused world frame (``seq`` of the run ``stream``)."""
    return WorldFrame(
        seq=seq,
        stamp_ns=r.stamp_ns,
        published_ns=time.time_ns(),
        arena=arena,
        objects=[
            WorldObject(
                id=t.id,
                kind="robot" if t.obj.kind == "robot" else "obstacle",
                x_cm=t.obj.x_cm,
                y_cm=t.obj.y_cm,
                z_cm=t.obj.z_cm,
                radius_cm=t.obj.radius_cm,
                sigma_cm=t.obj.sigma_cm,
                cameras=t.obj.cameras,
                marker_id=t.obj.marker_id,
                heading_deg=t.obj.heading_deg,
                z_sigma_cm=t.obj.z_sigma_cm,
                z_source=t.obj.z_source,  # type: ignore[arg-type]
                disagreeing=t.obj.disagreeing,
            )
            for t in r.objects
        ],
        cameras=r.cameras,
        missing=r.missing,
        late_frames=dict(late),
        stream=stream,
    )


def camera_state(missing: list[str], silent: list[str]) -> str:
    """The fusion service's state: "ok", or which cameras' areas are not covered."""
    parts = []
    if silent:
        parts.append(f"no frames from {', '.join(silent)} (area uncovered)")
    if missing:
        parts.append(f"late: {', '.join(missing)}")
    return "; ".join(parts) or "ok"


def follow_calibrations(service: Service, accuracy: dict[str, AccuracyMap]) -> None:
    """Each camera's newer calibration (``ovis/<arena>/cam/<name>/calibration``, from its
    chain's calibrator) replaces that camera's accuracy map only, built off the network
    thread; the other cameras are not touched."""
    cfg = service.config
    versions = dict.fromkeys(accuracy, 0)

    def rebuild(name: str, update: CalibrationUpdate) -> None:
        fresh = AccuracyMap(update.calibration.camera, cfg.fusion.pixel_sigma_px)
        fresh.prepare(cfg.pose.robot_height_cm, cfg.pose.obstacle_height_cm)
        accuracy[name] = fresh  # one assignment: the loop sees the old map or the new
        service.log.info("camera %s: calibration v%d", name, update.calibration.version)

    proven = service.proven("calibrator", "calibration")  # anyone may publish there
    for name in accuracy:

        def on_sample(sample: zenoh.Sample, name: str = name) -> None:
            payload = service.take(sample.payload, "small", "calibration")
            if payload is None or not proven(sample, payload):
                return
            update = service.decode(payload, CalibrationUpdate, "calibration")
            if update is None or update.calibration.version <= versions[name]:
                return
            versions[name] = update.calibration.version
            threading.Thread(target=rebuild, args=(name, update), daemon=True).start()

        service.session.declare_subscriber(service.topics.of_camera(name).calibration, on_sample)


def main(service: Service) -> None:
    cfg = service.config
    if not cfg.cameras:
        raise SystemExit("fusion: the configuration lists no [[cameras]]; nothing to fuse")
    models = {spec.name: camera_model(spec) for spec in cfg.cameras}
    sigma = cfg.fusion.pixel_sigma_px
    accuracy = {name: AccuracyMap(cam, sigma) for name, cam in models.items()}
    for each in accuracy.values():
        each.prepare(cfg.pose.robot_height_cm, cfg.pose.obstacle_height_cm)
    fuser = WorldFuser(
        list(models),
        cfg.fusion,
        stale_ns=int(cfg.service.frame_timeout_s * 1e9),
        views=accuracy,  # the same dict: a recalibrated camera's new map is used
        robot_radius_cm=max((r.radius_cm for r in cfg.pose.robots), default=0.0),
    )
    # every camera's frames are wanted (a world frame needs them all): room for several
    # frames of each; what overflows is counted as dropped in the status
    follow_calibrations(service, accuracy)
    inbox = Inbox(max(cfg.service.queue_depth, 8) * len(models))
    service._inboxes.append(inbox)  # its drops count in the status
    proven = service.proven("pose", "obstacles")  # only the chains' pose stages count
    for name in models:

        def on_sample(sample: zenoh.Sample, name: str = name) -> None:
            payload = service.take(sample.payload, "blobs", "obstacles")
            if payload is not None and proven(sample, payload):
                inbox.put((name, payload))

        service.session.declare_subscriber(service.topics.of_camera(name).obstacles, on_sample)
    # readers believe only world frames this key signed (docs/trust.md)
    publish = service.publisher(service.topics.world, signer=signer_for(cfg, "fusion"))
    seq = received = 0
    stream = secrets.token_hex(8)  # this run's: its seq starts again at 0

    def emit(results: list[WorldFrameResult]) -> None:
        nonlocal seq
        for r in results:
            out = world_message(r, seq, service.topics.arena, fuser.matcher.late, stream)
            for o in out.objects:  # counted in the status: errors["cameras disagree"]
                if o.disagreeing:
                    service.error("cameras disagree", f"object {o.id}: height of "
                                  f"{', '.join(o.disagreeing)} unlike the others'")  # fmt: skip
            seq += 1
            publish(out)
            service.sent()
            service.last_latency_ms = (out.published_ns - out.stamp_ns) / 1e6
            service.state = camera_state(r.missing, silent_cameras(time.time_ns()))

    def silent_cameras(now_ns: int) -> list[str]:
        return sorted(set(models) - set(fuser.matcher.live(now_ns)))

    def loop() -> None:
        nonlocal received
        service.ready()
        service.state = "waiting for input"
        while not service.stop.is_set():
            due_ns = fuser.matcher.next_due_ns()
            wait_s = IDLE_S if due_ns is None else (due_ns - time.time_ns()) / 1e9
            item = inbox.get(timeout=min(max(wait_s, 0.0), IDLE_S))
            now = time.time_ns()
            if item is None:
                emit(fuser.due(now))
                # every camera silent (a cut link): no world frame says so, the status must
                silent = silent_cameras(now) if received else []
                if silent:
                    service.state = camera_state([], silent)
                continue
            name, payload = item
            msg = service.decode(payload, ObstacleFrame, "obstacles")
            if msg is None:
                continue
            service.saw_frame(received, msg.stamp_ns)  # cameras' seqs interleave: ours
            received += 1
            try:
                emit(fuser.add(name, msg.stamp_ns, frame_columns(name, msg), now))
            except Exception as exc:  # a bad frame costs that world frame only
                service.error("processing", f"camera {name}: {type(exc).__name__}: {exc}")

    worker = threading.Thread(target=loop, daemon=True)
    worker.start()
    while not service.stop.wait(0.2):
        pass
    worker.join(timeout=1.0)

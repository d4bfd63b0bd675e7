#!/usr/bin/env python3
"""Print what ovis detects, without ovis: only ``zenoh`` (eclipse-zenoh 1.x) and ``msgpack``.

A standalone consumer of the obstacle topic, to copy into a robot's code::

    pip install eclipse-zenoh msgpack
    python subscribe_obstacles.py --connect tcp/192.168.1.10:7447 --arena default

It opens a Zenoh *client* session to a router (``ovis router`` or ``ovis up`` runs one),
subscribes to ``ovis/<arena>/obstacles`` and decodes every sample with
``msgpack.unpackb(payload, raw=False)``.

The message
-----------
Each payload (Zenoh encoding ``application/msgpack``) is one MessagePack **map** whose
keys are the field names:

``type``                ``"obstacles"`` (every ovis message carries its type tag).
``seq``                 frame sequence number (int >= 0), from the capture service.
``stamp_ns``            capture time of the frame, ns since the Unix epoch.
``published_ns``        when this message was published, ns since the Unix epoch.
``frame_age_ms``        how old the frame was when this was published, ms.
``calibration_version`` which camera calibration made the world coordinates (0: none).
``robot``               the robot (an *object* map, below), or nil if not found.
``obstacles``           array of *object* maps, one per obstacle.
``planner``             array of maps ``{obstacle_id, distance_cm, angle_deg}``: the motion
                        planner's inputs. ``distance_cm`` = |O - R| - r_O (robot centre to
                        obstacle centre, minus the obstacle's radius); ``angle_deg`` in
                        (-180, 180], counter-clockwise positive, from the goal direction
                        to the direction robot -> obstacle.
``arena``               the arena's name.

An *object* map: ``id`` (int; the robot is 0, an obstacle keeps its id while it is
tracked), ``kind`` (``"robot"`` or ``"obstacle"``), image measurements ``row``, ``col``,
``area_px``, ``perimeter_px``, ``compactness`` (4*pi*area / perimeter^2, ~1 for a disk);
world pose on the floor ``x_cm``, ``y_cm``, ``z_cm`` (height of its top face),
``radius_cm`` (disk of equal area), ``area_cm2``, ``heading_deg`` (degrees CCW from +X,
nil for round shapes), ``elongation``, and velocity ``vx_cm_s``, ``vy_cm_s`` (cm/s).

Senders may add new keys at the end of a map in later versions: ignore the ones you do
not know. Numbers meant as reals are float64, but accept integers there too.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import queue
import re
import signal
import sys
from collections.abc import Sequence
from typing import Any, TextIO

import msgpack
import zenoh

__all__ = ["BadMessageError", "client_config", "format_json", "format_text", "main", "parse"]

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
#: Messages waiting to be printed, at most (more are skipped).
INBOX = 1000
MESSAGE_TYPE = "obstacles"
_ARENA = re.compile(r"[A-Za-z0-9_.-]{1,64}")
_REQUIRED = ("seq", "calibration_version", "robot", "obstacles", "planner")


class BadMessageError(ValueError):
    """A payload that is not an ovis obstacle message; the text says why."""


def obstacles_key(arena: str) -> str:
    """The key expression of an arena's obstacle topic."""
    if not _ARENA.fullmatch(arena):
        raise ValueError(f"arena name {arena!r} must be 1-64 letters, digits, '_', '.' or '-'")
    return f"ovis/{arena}/obstacles"


def client_config(connect: Sequence[str]) -> zenoh.Config:
    """A Zenoh client configuration: connect to these routers, no multicast scouting."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def parse(payload: bytes) -> dict[str, Any]:
    """Decode one payload into the message map; raise :class:`BadMessageError` if it is not one."""
    try:
        msg = msgpack.unpackb(payload, raw=False)
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise BadMessageError(f"not MessagePack: {exc}") from None
    if not isinstance(msg, dict):
        raise BadMessageError(f"expected a map, got {type(msg).__name__}")
    if msg.get("type") != MESSAGE_TYPE:
        raise BadMessageError(f"expected type {MESSAGE_TYPE!r}, got {msg.get('type')!r}")
    missing = [k for k in _REQUIRED if k not in msg]
    if missing:
        raise BadMessageError(f"missing field(s) {', '.join(missing)}")
    if not isinstance(msg["obstacles"], list) or not isinstance(msg["planner"], list):
        raise BadMessageError("obstacles and planner must be arrays")
    return msg


def _finite(value: Any) -> Any:
    """JSON has no NaN or infinity: such numbers become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value


def format_json(msg: dict[str, Any]) -> str:
    """One JSON line: seq, stamp_ns, calibration_version, robot, obstacles, planner."""
    keys = ("seq", "stamp_ns", "calibration_version", "robot", "obstacles", "planner")
    out = {k: msg.get(k) for k in keys}
    if msg.get("robots"):  # marked robots (newer ovis): each with id, pose, heading, velocity
        out["robots"] = msg["robots"]
    return json.dumps(_finite(out), allow_nan=False)


def _num(value: Any, spec: str = ".1f") -> str:
    return format(value, spec) if isinstance(value, int | float) else "?"


def format_text(msg: dict[str, Any]) -> str:
    """Robot position, then each obstacle's id, position, radius, distance and angle, then
    each marked robot's id, name, position, heading, velocity and age."""
    robot = msg["robot"]
    if isinstance(robot, dict):
        where = f"robot at ({_num(robot.get('x_cm'))}, {_num(robot.get('y_cm'))}) cm"
        if robot.get("heading_deg") is not None:
            where += f" heading {_num(robot['heading_deg'])} deg"
    else:
        where = "robot not found"
    lines = [
        f"frame {msg['seq']} (calibration v{msg['calibration_version']}): {where}, "
        f"{len(msg['obstacles'])} obstacle(s)"
    ]
    planner = {p.get("obstacle_id"): p for p in msg["planner"] if isinstance(p, dict)}
    for obstacle in msg["obstacles"]:
        if not isinstance(obstacle, dict):
            continue
        entry = planner.get(obstacle.get("id"), {})
        lines.append(
            f"  obstacle {obstacle.get('id')}: at ({_num(obstacle.get('x_cm'))}, "
            f"{_num(obstacle.get('y_cm'))}) cm, radius {_num(obstacle.get('radius_cm'))} cm, "
            f"distance {_num(entry.get('distance_cm'))} cm, "
            f"angle {_num(entry.get('angle_deg'))} deg"
        )
    for robot in msg.get("robots") or []:  # marked robots (newer ovis; absent before)
        if not isinstance(robot, dict):
            continue
        lines.append(
            f"  robot {robot.get('id')} {robot.get('name', '')}: at ({_num(robot.get('x_cm'))}, "
            f"{_num(robot.get('y_cm'))}) cm, heading {_num(robot.get('heading_deg'))} deg, "
            f"velocity ({_num(robot.get('vx_cm_s'))}, {_num(robot.get('vy_cm_s'))}) cm/s, "
            f"seen {_num(robot.get('age_s'), '.2f')} s ago"
        )
    return "\n".join(lines)


def main(
    conf: zenoh.Config,
    key: str,
    *,
    count: int | None = None,
    as_json: bool = False,
    out: TextIO = sys.stdout,
) -> int:
    """Subscribe to ``key`` and print each obstacle message; stop after ``count`` of them.

    Payloads that are not obstacle messages are reported on stderr and skipped. Raises
    ``KeyboardInterrupt`` on Ctrl-C (the session is closed first).
    """
    session = zenoh.open(conf)
    try:
        # Zenoh's thread queues each sample; this (main) thread waits on the queue with a
        # timeout, so Ctrl-C and SIGTERM are handled at once whatever Zenoh is doing.
        inbox: queue.Queue[tuple[str, bytes]] = queue.Queue(maxsize=INBOX)

        def on_sample(sample: zenoh.Sample) -> None:
            with contextlib.suppress(queue.Full):  # a printer that cannot keep up skips
                inbox.put_nowait((str(sample.key_expr), sample.payload.to_bytes()))

        session.declare_subscriber(key, on_sample)
        print(f"subscribed to {key}", file=sys.stderr, flush=True)
        seen = 0
        while count is None or seen < count:
            try:
                where, payload = inbox.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                msg = parse(payload)
            except BadMessageError as exc:
                print(f"skipped a message on {where}: {exc}", file=sys.stderr)
                continue
            seen += 1
            out.write((format_json(msg) if as_json else format_text(msg)) + "\n")
            out.flush()
    finally:
        session.close()  # a session left open can hang the interpreter's exit
    return 0


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Print the robot and obstacles that ovis publishes (needs only "
        "eclipse-zenoh and msgpack)."
    )
    parser.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help=f"Zenoh router endpoint (repeatable); default {DEFAULT_CONNECT}.",
    )
    parser.add_argument("--arena", default="default", help="Arena name (default: default).")
    parser.add_argument("--count", type=_positive, help="Stop after N messages.")
    parser.add_argument(
        "--json", action="store_true", help="Print one JSON object per message and line."
    )
    return parser.parse_args(argv)


def _interrupt(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt


def cli(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point: exit 0 when done, 1 if no router, 130 on Ctrl-C/SIGTERM."""
    args = parse_args(argv)
    try:
        key = obstacles_key(args.arena)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    connect = args.connect or [DEFAULT_CONNECT]
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        return main(client_config(connect), key, count=args.count, as_json=args.json)
    except zenoh.ZError as exc:
        print(f"error: {exc} (connect: {', '.join(connect)})", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(cli())

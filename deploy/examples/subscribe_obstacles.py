#!/usr/bin/env python3
"""Print what ovis detects, without ovis: only ``zenoh`` (eclipse-zenoh 1.x), ``msgpack``
and ``cryptography`` (to check who sent it).

A standalone consumer of the obstacle topic, to copy into a robot's code::

    pip install eclipse-zenoh msgpack cryptography
    python subscribe_obstacles.py --connect tcp/192.168.1.10:7447 --arena default \
        --trust pose.pub

It opens a Zenoh *client* session to a router (``ovis router`` or ``ovis up`` runs one),
subscribes to ``ovis/<arena>/obstacles``, drops (and counts, on stderr) every sample
without the pose stage's proof of origin, and decodes the others with
``msgpack.unpackb(payload, raw=False)``.

The proof
---------
Anyone on the bus can publish on the obstacle key: believe only what the pose stage
signed. Its public key is the PEM file ``pose.pub`` that ``ovis up`` (or the pose stage)
writes in ``<state_dir>/keys/`` (``ovis-state/keys/pose.pub`` by default): copy it to this
machine, over a channel you trust (scp, your configuration management), and give it with
``--trust``. Each sample's Zenoh *attachment* is a MessagePack map with ``kid`` (8 bytes:
the first 8 bytes of SHA-256 of the raw 32-byte public key) and ``sig`` (64 bytes: an
Ed25519 signature of ``b"ovis-proof-v1\0" + key_expr + b"\0" + payload``, the key
expression as UTF-8 and the payload's exact bytes). Any Ed25519 library checks it.

A proof says who published a message, not that it is new: a recorded genuine message
sent again verifies. So a message is also dropped unless it comes after the last one
taken (:class:`ReplayCheck`): the same capture ``stream`` with a higher ``seq``, or a
stream never seen before (the capture restarted) with a later ``stamp_ns`` or one
within ``FRESH_S`` of this machine's clock (a restart after its clock stepped back).

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
import hashlib
import json
import math
import queue
import re
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

import msgpack
import zenoh

__all__ = [
    "BadMessageError",
    "ReplayCheck",
    "client_config",
    "format_json",
    "format_text",
    "main",
    "parse",
    "proof_checker",
]

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
DEFAULT_TRUST = "ovis-state/keys/pose.pub"
DOMAIN = b"ovis-proof-v1\x00"
#: How close to this machine's clock a new capture stream's first message must be
#: stamped when it is not later than the last message taken, s.
FRESH_S = 5.0
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


def proof_checker(pem_file: str) -> Callable[[str, bytes, bytes | None], str | None]:
    """A function (key expression, payload, attachment) -> why the sample is not signed
    by the key in ``pem_file``, or None. OSError/ValueError when the file is no key."""
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

    key = serialization.load_pem_public_key(Path(pem_file).read_bytes())
    if not isinstance(key, Ed25519PublicKey):
        raise ValueError(f"{pem_file} is not an Ed25519 public key")
    raw = key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    kid = hashlib.sha256(raw).digest()[:8]

    def problem(key_expr: str, payload: bytes, attachment: bytes | None) -> str | None:
        try:
            proof = msgpack.unpackb(attachment or b"", raw=False)
        except (ValueError, TypeError, msgpack.UnpackException):
            proof = None
        if not isinstance(proof, dict) or "sig" not in proof:
            return "no proof of origin"
        if proof.get("kid") != kid:
            return "signed by another key"
        try:
            key.verify(proof["sig"], DOMAIN + key_expr.encode() + b"\x00" + payload)
        except (InvalidSignature, TypeError):
            return "bad signature"
        return None

    return problem


class ReplayCheck:
    """Whether a proven message comes after the last one taken (a replay does not)."""

    def __init__(self) -> None:
        self.stream, self.seq, self.stamp = "", -1, -1
        self.streams: set[str] = set()

    def problem(self, msg: dict[str, Any], now_ns: int) -> str | None:
        """Why ``msg`` is a replay or out of order, or None: it is taken."""
        stream, seq, stamp = str(msg.get("stream", "")), msg["seq"], msg.get("stamp_ns", 0)
        if not (isinstance(seq, int) and isinstance(stamp, int)):
            return "seq and stamp_ns must be integers"
        if stream and stream == self.stream:  # the same run: its seq must rise
            taken = seq > self.seq
        elif stream and stream in self.streams:  # a run that was replaced: never again
            taken = False
        else:  # a new run (or none named): later than the last, or stamped now
            taken = stamp > self.stamp or abs(now_ns - stamp) <= FRESH_S * 1e9
        if self.stamp >= 0 and not taken:
            return f"replayed: seq {seq} of stream {stream or '-'} after seq {self.seq}"
        self.stream, self.seq, self.stamp = stream, seq, stamp
        self.streams.add(stream)
        return None


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
    check: Callable[[str, bytes, bytes | None], str | None],
    count: int | None = None,
    as_json: bool = False,
    out: TextIO = sys.stdout,
) -> int:
    """Subscribe to ``key`` and print each obstacle message; stop after ``count`` of them.

    Samples that ``check`` finds unproven are dropped and counted on stderr; payloads
    that are not obstacle messages are reported on stderr and skipped. Raises
    ``KeyboardInterrupt`` on Ctrl-C (the session is closed first).
    """
    session = zenoh.open(conf)
    try:
        # Zenoh's thread queues each sample; this (main) thread waits on the queue with a
        # timeout, so Ctrl-C and SIGTERM are handled at once whatever Zenoh is doing.
        inbox: queue.Queue[tuple[str, bytes, bytes | None]] = queue.Queue(maxsize=INBOX)

        def on_sample(sample: zenoh.Sample) -> None:
            attachment = None if sample.attachment is None else sample.attachment.to_bytes()
            with contextlib.suppress(queue.Full):  # a printer that cannot keep up skips
                inbox.put_nowait((str(sample.key_expr), sample.payload.to_bytes(), attachment))

        session.declare_subscriber(key, on_sample)
        print(f"subscribed to {key}", file=sys.stderr, flush=True)
        seen = dropped = 0
        replays = ReplayCheck()
        while count is None or seen < count:
            try:
                where, payload, attachment = inbox.get(timeout=0.2)
            except queue.Empty:
                continue
            problem = check(where, payload, attachment)
            msg: dict[str, Any] | None = None
            if problem is None:
                try:
                    msg = parse(payload)
                except BadMessageError as exc:
                    print(f"skipped a message on {where}: {exc}", file=sys.stderr)
                    continue
                problem = replays.problem(msg, time.time_ns())
            if problem is not None or msg is None:
                dropped += 1
                if dropped <= 5 or dropped % 100 == 0:
                    print(f"dropped {dropped} unproven message(s) ({problem})", file=sys.stderr)
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
        "--trust",
        default=DEFAULT_TRUST,
        metavar="FILE",
        help="The pose stage's public key (PEM; copy <state_dir>/keys/pose.pub from the "
        f"host of `ovis up`); default {DEFAULT_TRUST}. Only what it signed is printed.",
    )
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
    try:
        check = proof_checker(args.trust)
    except (OSError, ValueError) as exc:
        print(
            f"error: cannot read the pose stage's public key {args.trust}: {exc}; copy "
            "pose.pub from the state folder of `ovis up` (ovis-state/keys/) and give --trust",
            file=sys.stderr,
        )
        return 2
    connect = args.connect or [DEFAULT_CONNECT]
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        return main(client_config(connect), key, check=check, count=args.count, as_json=args.json)
    except zenoh.ZError as exc:
        print(f"error: {exc} (connect: {', '.join(connect)})", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(cli())

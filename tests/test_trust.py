"""The proof of origin (common/trust): key files, signatures bound to the key expression
and the exact payload, and which proven calibration a stage adopts
(common/pipeline/following.py: pick, newer)."""

from __future__ import annotations

import os
import stat
import threading
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest

from ovis.common.calibration.file import calibration_from_config
from ovis.common.config import load_config
from ovis.common.messages import (
    CalibrationUpdate,
    ObstacleFrame,
    StreamHealth,
    Topics,
    decode,
    encode,
)
from ovis.common.pipeline.following import CONFLICT_HOLD_S, Answer, CalibrationFollower, pick
from ovis.common.pipeline.health import StreamWatch
from ovis.common.trust.keys import (
    PublicKeyFile,
    key_id,
    load_or_create_private,
    load_public,
    public_key_path,
)
from ovis.common.trust.order import ReplayGuard
from ovis.common.trust.proof import Signer, Verifier

CFG = load_config()
KEY = Topics("default").obstacles
#: an obstacle message as the pose stage publishes it (fields by name, as any reader sees)
PAYLOAD = encode(
    msgspec.convert(
        {"type": "obstacles", "seq": 7, "stamp_ns": 1, "published_ns": 2,
         "frame_age_ms": 1.0, "calibration_version": 3, "robot": None, "obstacles": [],
         "planner": []},
        ObstacleFrame,
    )
)  # fmt: skip


@pytest.fixture
def keys(tmp_path: Path) -> tuple[Signer, Verifier, Path]:
    path = tmp_path / "keys" / "pose.key"
    signer = Signer(load_or_create_private(path))
    return signer, Verifier(PublicKeyFile(path.with_suffix(".pub"))), path


def test_a_genuine_message_is_proven(keys) -> None:
    signer, verifier, _ = keys
    assert verifier.problem(KEY, PAYLOAD, signer.attachment(KEY, PAYLOAD)) is None


def test_a_tampered_payload_fails(keys) -> None:
    signer, verifier, _ = keys
    proof = signer.attachment(KEY, PAYLOAD)
    tampered = PAYLOAD[:-1] + bytes([PAYLOAD[-1] ^ 1])
    assert verifier.problem(KEY, tampered, proof) == (
        f"bad signature for {KEY} (payload or key expression changed)"
    )


def test_a_proof_moved_to_another_key_expression_fails(keys) -> None:
    signer, verifier, _ = keys
    proof = signer.attachment(KEY, PAYLOAD)
    other = Topics("other").obstacles
    assert "bad signature for ovis/other/obstacles" in verifier.problem(other, PAYLOAD, proof)


def test_another_key_is_refused_by_its_id(keys, tmp_path: Path) -> None:
    _, verifier, path = keys
    forger = Signer(load_or_create_private(tmp_path / "forger.key"))
    trusted = key_id(load_public(path.with_suffix(".pub"))).hex()
    assert verifier.problem(KEY, PAYLOAD, forger.attachment(KEY, PAYLOAD)) == (
        f"signed by key {forger.kid.hex()}, not the trusted {trusted}"
    )
    # the forger copies the trusted key's id: the signature still fails
    forged = msgspec.msgpack.encode(
        {"kid": bytes.fromhex(trusted), "sig": msgspec.msgpack.decode(
            forger.attachment(KEY, PAYLOAD))["sig"]}
    )  # fmt: skip
    assert verifier.problem(KEY, PAYLOAD, forged).startswith("bad signature")


@pytest.mark.parametrize("cut", [0, 1, 20, 60])
def test_a_missing_or_truncated_attachment_fails(keys, cut: int) -> None:
    signer, verifier, _ = keys
    proof = signer.attachment(KEY, PAYLOAD)[:cut]
    problem = verifier.problem(KEY, PAYLOAD, proof)
    assert problem == "no proof of origin" if cut == 0 else problem.startswith("not a proof")
    assert verifier.problem(KEY, PAYLOAD, None) == "no proof of origin"


def test_other_keys_of_the_attachment_map_are_ignored(keys) -> None:
    signer, verifier, _ = keys
    proof = msgspec.msgpack.decode(signer.attachment(KEY, PAYLOAD))
    both = msgspec.msgpack.encode({"recording": "run.mcap", **proof})
    assert verifier.problem(KEY, PAYLOAD, both) is None


def test_the_private_key_is_made_once_with_mode_0600_and_kept(tmp_path: Path) -> None:
    path = tmp_path / "state" / "keys" / "calibrator.key"
    first = load_or_create_private(path)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    pub = load_public(path.with_suffix(".pub"))
    assert key_id(pub) == key_id(first.public_key())
    again = load_or_create_private(path)  # a restart: the same key
    assert key_id(again.public_key()) == key_id(first.public_key())
    path.with_suffix(".pub").unlink()  # a lost public half is written again
    load_or_create_private(path)
    assert key_id(load_public(path.with_suffix(".pub"))) == key_id(first.public_key())


def test_processes_making_the_key_at_once_get_the_same_one(tmp_path: Path) -> None:
    path = tmp_path / "keys" / "pose.key"
    ids: list[bytes] = []

    def make() -> None:
        ids.append(key_id(load_or_create_private(path).public_key()))

    threads = [threading.Thread(target=make) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(set(ids)) == 1 and len(ids) == 8
    assert sorted(p.name for p in path.parent.iterdir()) == ["pose.key", "pose.pub"]


def test_a_public_key_that_appears_later_is_read_then(tmp_path: Path) -> None:
    path = tmp_path / "keys" / "pose.key"
    trusted = PublicKeyFile(path.with_suffix(".pub"))
    assert trusted.key(now=0.0) is None
    assert trusted.problem == f"no public key at {path.with_suffix('.pub')}"
    signer = Signer(load_or_create_private(path))
    assert trusted.key(now=0.5) is None  # not read again before RETRY_S
    assert trusted.key(now=1.0) is not None
    verifier = Verifier(trusted)
    assert verifier.problem(KEY, PAYLOAD, signer.attachment(KEY, PAYLOAD)) is None


def test_where_keys_are_looked_for() -> None:
    assert public_key_path(CFG, "pose") == Path("ovis-state/keys/pose.pub")
    named = msgspec.structs.replace(
        CFG, trust=msgspec.structs.replace(CFG.trust, calibrator_public="/etc/ovis/c.pub")
    )
    assert public_key_path(named, "calibrator") == Path("/etc/ovis/c.pub")
    assert public_key_path(CFG, "fusion") == Path("ovis-state/keys/fusion.pub")
    named = msgspec.structs.replace(
        CFG, trust=msgspec.structs.replace(CFG.trust, fusion_public="/etc/ovis/f.pub")
    )
    assert public_key_path(named, "fusion") == Path("/etc/ovis/f.pub")


# --- which proven calibration a stage adopts --------------------------------------------


def _calib(version: int, epoch: str = "e" * 16, created: str = "2025-01-01T00:00:00+00:00"):
    base = calibration_from_config(CFG)
    return msgspec.structs.replace(base, version=version, epoch=epoch, created=created)


def test_the_genuine_newer_answer_wins_over_an_unproven_one() -> None:
    held = _calib(3)
    forged = Answer("replier f", _calib(2**63 - 1), unproven="no proof of origin")
    genuine = Answer("replier g", _calib(4))
    adopt, conflicts = pick(held, [forged, genuine])
    assert adopt == genuine.calibration
    assert conflicts == ["replier f: refused, no proof of origin"]


def test_a_replayed_older_genuine_calibration_is_refused_as_a_conflict() -> None:
    held = _calib(3)
    replay = Answer("replier r", _calib(2))
    current = Answer("replier g", _calib(3))
    assert pick(held, [replay, current]) == (
        None,
        ["replier r: refused v2@eeeeeeee, a replay (not newer than v3@eeeeeeee)"],
    )


def test_another_stores_calibration_counts_only_if_made_later() -> None:
    held = _calib(3, created="2025-06-01T00:00:00+00:00")
    old_store = Answer("replier r", _calib(9, epoch="a" * 16, created="2025-01-01T00:00:00+00:00"))
    adopt, conflicts = pick(held, [old_store])
    assert adopt is None and "a replay" in conflicts[0]
    new_store = Answer("replier n", _calib(1, epoch="b" * 16, created="2025-07-01T00:00:00+00:00"))
    assert pick(held, [new_store]) == (new_store.calibration, [])


def test_at_start_the_newest_of_several_proven_answers_is_taken() -> None:
    held = calibration_from_config(CFG)  # version 0: the configured camera
    old, new = Answer("replier r", _calib(2)), Answer("replier g", _calib(5))
    adopt, conflicts = pick(held, [old, new])
    assert adopt == new.calibration
    assert conflicts == ["replier r: refused v2@eeeeeeee, older than v5@eeeeeeee"]


def test_a_conflict_is_said_until_it_has_not_been_seen_for_a_while() -> None:
    follower = CalibrationFollower(CFG, _calib(3))
    follower.conflict("replier f: refused, no proof of origin", now=100.0)
    said = follower.problem(now=100.0 + CONFLICT_HOLD_S - 0.1)
    assert said == "calibration_conflict: replier f: refused, no proof of origin"
    assert follower.problem(now=100.0 + CONFLICT_HOLD_S) is None


# --- replays of genuine messages (common/trust/order.py) ---------------------------

NOW = 1_800_000_000 * 10**9


def _obstacles(seq: int, stamp_ns: int, stream: str = "s1") -> bytes:
    return encode(msgspec.structs.replace(decode(PAYLOAD, ObstacleFrame), seq=seq,
                                          stamp_ns=stamp_ns, stream=stream))  # fmt: skip


def test_a_replayed_genuine_message_is_refused_by_the_verifier(keys) -> None:
    """The proof verifies on a replay (same bytes): the verifier refuses it all the same,
    and any other consumer (its own verifier) still takes the message once."""
    signer, verifier, path = keys
    first, second = _obstacles(1, NOW), _obstacles(2, NOW + 10**8)
    for payload in (first, second):
        assert verifier.problem(KEY, payload, signer.attachment(KEY, payload)) is None
    why = verifier.problem(KEY, first, signer.attachment(KEY, first))
    assert why is not None and why.startswith("replayed or out of order: seq 1 of stream s1")
    other = Verifier(PublicKeyFile(path.with_suffix(".pub")))
    assert other.problem(KEY, first, signer.attachment(KEY, first)) is None


def test_order_rules_per_key() -> None:
    guard = ReplayGuard()
    take = lambda seq, stamp, stream="s1", key=KEY: guard.problem(  # noqa: E731
        key, _obstacles(seq, stamp, stream), NOW
    )
    assert take(5, NOW - 10**9) is None  # the first on its key
    assert take(6, NOW - 2 * 10**9) is None  # same stream, next seq: its clock stepped back
    assert take(6, NOW - 2 * 10**9).startswith("replayed or out of order: seq 6 of stream s1")
    assert take(5, NOW - 10**9) is not None  # an earlier one of the stream, stamped later
    assert take(0, NOW + 2 * 10**9, "s2") is None  # the capture restarted: a new stream
    assert take(9, NOW + 3 * 10**9, "s1").startswith("replayed: stream s1 (seq 9) was replaced")
    assert take(1, NOW - 3600 * 10**9, "old").startswith("replayed: stamped 3602.000 s before")
    assert take(1, NOW - 10**9, "s3") is None  # new, fresh: a restart after a clock step
    assert take(5, NOW - 10**9, key=Topics("default").of_camera("cam01").obstacles) is None


def test_health_is_ordered_by_its_publication_and_a_calibration_not_at_all() -> None:
    guard = ReplayGuard()
    key = Topics("default").health

    def health(published_ns: int) -> bytes:
        return encode(StreamHealth(state="ok", published_ns=published_ns))

    assert guard.problem(key, health(NOW - 10 * 10**9), NOW) is None
    assert guard.problem(key, health(NOW - 9 * 10**9), NOW) is None
    assert guard.problem(key, health(NOW - 10 * 10**9), NOW) is not None  # an older one
    assert guard.problem(key, health(NOW - 10**9), NOW) is None
    update = encode(CalibrationUpdate(calibration=calibration_from_config(CFG)))
    for _ in range(3):  # the same calibration, asked again and again: never a replay here
        assert guard.problem(Topics("default").calibration, update, NOW) is None
    assert guard.problem(KEY, b"\xc1 not msgpack", NOW) is None  # its decoding says why


def test_the_pose_stage_numbers_its_health_messages_in_its_run() -> None:
    """A health message says its run and number: a replay of an earlier one of the run
    is refused, however fresh; a restarted pose stage's first one is taken."""
    guard, key = ReplayGuard(), Topics("default").health

    def health(watch: StreamWatch) -> bytes:
        return encode(watch.message(last_seq=3, seconds_since_frame=0.1, last_frame_age_ms=2.0,
                                    frames_dropped=0, calibration_version=1))  # fmt: skip

    run = StreamWatch(timeout_s=1.0)
    first, second = health(run), health(run)
    assert (decode(first, StreamHealth).seq, decode(second, StreamHealth).seq) == (0, 1)
    now = time.time_ns()
    assert guard.problem(key, first, now) is None and guard.problem(key, second, now) is None
    assert guard.problem(key, first, now).startswith("replayed or out of order: seq 0")
    assert guard.problem(key, health(StreamWatch(timeout_s=1.0)), now) is None  # restarted


@pytest.mark.parametrize("seed", range(20))
def test_no_earlier_message_is_ever_taken_again(seed: int) -> None:
    """Property: genuine runs (streams one after another, seqs rising, stamps rising,
    recorded long ago) interleaved with replays of any earlier message of any run: every
    genuine message is taken, no replay is."""
    rng = np.random.default_rng(seed)
    guard = ReplayGuard()
    sent: list[bytes] = []
    stamp = NOW - 7200 * 10**9
    for run in range(4):
        for seq in range(int(rng.integers(1, 30))):
            stamp += int(rng.integers(1, 10**8))
            message = _obstacles(seq, stamp, f"run{run}")
            assert guard.problem(KEY, message, NOW) is None, (run, seq)
            sent.append(message)
            for old in rng.choice(len(sent), size=int(rng.integers(0, 3))):
                assert guard.problem(KEY, sent[old], NOW) is not None

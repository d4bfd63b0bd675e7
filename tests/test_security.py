"""The secure profile (deploy/secure/) end to end: certificates and passwords made by its
scripts, `ovis router` with the committed router.json5 (TLS, user/password, access
control), the five services as real processes, each with its own credentials; then who
may connect, watch, recalibrate and inject frames or calibrations. No mocks: real TLS on
loopback."""

from __future__ import annotations

import json
import shutil
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
import zenoh
from zenoh_helpers import alive, free_port, ovis_cmd, stop, wait_for

from ovis.common.config import ZenohConfig
from ovis.common.messages import (
    ENCODING,
    CalibrateRequest,
    CalibrationUpdate,
    Frame,
    FrameHeader,
    ObstacleFrame,
    ServiceStatus,
    decode,
    encode,
)
from ovis.services.bus import zenoh_config

SECURE = Path(__file__).resolve().parents[1] / "deploy" / "secure"
STAGES = ("capture", "preprocess", "label", "pose", "calibrator")
FORGED_SEQ = 10**9  # no real frame gets this number during a test
REMOTE = zenoh.Locality.REMOTE  # a session also delivers its own puts to itself
BLOCK = zenoh.CongestionControl.BLOCK  # no put dropped at the source for lack of room

pytestmark = pytest.mark.skipif(
    shutil.which("openssl") is None, reason="openssl is not installed (make-certs.sh needs it)"
)


class Secure:
    """The running secure deployment: its folder, endpoint and credentials."""

    def __init__(self, root: Path, endpoint: str) -> None:
        self.root = root  # mirrors the repository: deploy/secure/{*.toml,router.json5,out/}
        self.endpoint = endpoint
        self.out = root / "deploy" / "secure" / "out"
        self.passwords = dict(
            line.split(":", 1) for line in (self.out / "passwords.txt").read_text().split()
        )

    def conf(
        self, user: str | None, password: str | None = None, *, endpoint: str | None = None
    ) -> zenoh.Config:
        """A client configuration: the rendered out/<user>.json5 (TLS to our CA), with its
        password replaced when ``password`` is given; ``user=None``: TLS, no credentials."""
        json5 = self.out / "viewer.json5"
        if user is not None:
            json5 = self.out / f"{user}.json5"
        zc = ZenohConfig(config_file=str(json5), connect=[endpoint or self.endpoint])
        conf = zenoh_config(zc, wait=False)
        # the rendered files name the CA relative to the deployment folder; we run elsewhere
        conf.insert_json5(
            "transport/link/tls/root_ca_certificate", json.dumps(str(self.out / "ca.crt"))
        )
        if user is None:
            conf.insert_json5("transport/auth/usrpwd/user", "null")
            conf.insert_json5("transport/auth/usrpwd/password", "null")
        elif password is not None:
            conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
        return conf

    def session(
        self, user: str | None, password: str | None = None, *, endpoint: str | None = None
    ) -> zenoh.Session:
        return zenoh.open(self.conf(user, password, endpoint=endpoint))

    def router_conf(self, endpoint: str) -> zenoh.Config:
        """The committed router.json5 for a router in this process, on ``endpoint``."""
        conf = zenoh.Config.from_file(str(SECURE / "router.json5"))
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
        for key, name in (
            ("transport/link/tls/listen_certificate", "router.crt"),
            ("transport/link/tls/listen_private_key", "router.key"),
            ("transport/auth/usrpwd/dictionary_file", "passwords.txt"),
        ):
            conf.insert_json5(key, json.dumps(str(self.out / name)))
        return conf

    def cli(self, *args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
        """An ovis command run from the deployment folder (relative paths as documented)."""
        return subprocess.run(
            ovis_cmd(*args), cwd=self.root, capture_output=True, text=True, timeout=timeout
        )


def _status(session: zenoh.Session, service: str) -> ServiceStatus:
    for reply in session.get(f"ovis/default/status/{service}", timeout=3.0):
        if reply.ok is not None:
            return decode(reply.ok.payload.to_bytes(), ServiceStatus)
    raise AssertionError(f"no status from {service}")


def _pose_ready(session: zenoh.Session) -> bool:
    """Pose has published obstacles with a calibration (a status query that gets no
    answer in time, as on a loaded machine while the stages start, counts as not yet)."""
    try:
        status = _status(session, "pose")
    except AssertionError:
        return False
    return status.calibration_version >= 1 and status.frames_out > 0


def _spawn(args: list[str], cwd: Path, log: Path) -> subprocess.Popen[bytes]:
    fh = open(log, "wb")  # noqa: SIM115 (the child keeps it)
    return subprocess.Popen(
        args, cwd=cwd, stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
    )


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Secure]:
    """Certificates and passwords from the scripts, the committed configs, `ovis router`
    and the five services (10 fps) with the operator's credentials."""
    root = tmp_path_factory.mktemp("secure")
    deploy = root / "deploy" / "secure"
    deploy.mkdir(parents=True)
    tomls = [f"{name}.toml" for name in ("router", "operator", "viewer", *STAGES)]
    for name in ("router.json5", *tomls):
        shutil.copy(SECURE / name, deploy / name)
    for script in ("make-certs.sh", "make-passwords.sh"):
        subprocess.run(
            ["sh", str(SECURE / script), "deploy/secure/out"],
            cwd=root,
            check=True,
            capture_output=True,
            timeout=60,
        )
    endpoint = f"tls/127.0.0.1:{free_port()}"
    procs: list[subprocess.Popen[bytes]] = []
    try:
        router_args = ["router", "--config", "deploy/secure/router.toml", "--listen", endpoint]
        procs.append(_spawn(ovis_cmd(*router_args), root, root / "router.log"))
        wait_for(lambda: "listening" in (root / "router.log").read_text(), 20, "the router")
        for stage in STAGES:
            args = ["run", stage, "-c", f"deploy/secure/{stage}.toml", "--connect", endpoint]
            args += ["--fps", "10", "--state-dir", str(root / "state")]
            procs.append(_spawn(ovis_cmd(*args), root, root / f"{stage}.log"))
        deployment = Secure(root, endpoint)
        with deployment.session("operator") as session:
            wait_for(lambda: alive(session) >= set(STAGES), 60, "all five services alive")
            wait_for(
                lambda: _pose_ready(session), 60, "obstacles made with the initial calibration"
            )
        yield deployment
    finally:
        stop(procs)


def test_no_credentials_wrong_password_plain_tcp_and_unknown_ca_are_refused(secure: Secure):
    # (a) no user/password: the TLS handshake succeeds but the router refuses the session
    # during establishment, so zenoh.open fails at once — nothing to subscribe or query with
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        secure.session(None).close()
    # (d) the operator's name with a wrong password, and a user nobody created
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        secure.session("operator", "not-the-password").close()
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        secure.session("viewer", secure.passwords["operator"]).close()
    # the right password over plain TCP (the port only speaks TLS) ...
    conf = secure.conf("operator")
    conf.insert_json5("connect/endpoints", json.dumps([secure.endpoint.replace("tls/", "tcp/")]))
    conf.insert_json5("transport/link/protocols", '["tcp"]')
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(conf).close()
    # ... or TLS without our CA (the router's certificate is not trusted)
    conf = secure.conf("operator")
    conf.insert_json5("transport/link/tls/root_ca_certificate", "null")
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(conf).close()
    # the command line says so (exit 4)
    bad = secure.root / "wrong.toml"
    wrong = (secure.out / "operator.json5").read_text()
    wrong = wrong.replace(secure.passwords["operator"], "not-the-password")
    (secure.out / "wrong.json5").write_text(wrong)
    bad.write_text(
        f'[zenoh]\nconfig_file = "deploy/secure/out/wrong.json5"\nconnect = ["{secure.endpoint}"]\n'
    )
    result = secure.cli("recalibrate", "-c", str(bad), "--timeout", "5", timeout=60)
    assert result.returncode == 4, result.stderr
    assert "cannot reach Zenoh" in result.stderr and "user/password" in result.stderr
    # while the operator's credentials work
    with secure.session("operator") as session:
        assert alive(session) >= set(STAGES)


def test_viewer_watches_but_cannot_recalibrate_inject_or_impersonate(secure: Secure):
    with secure.session("operator") as op, secure.session("operator") as listener:
        # the operator's own view of the frame topic, to show what reaches the services
        frames_seen: list[int] = []
        lock = threading.Lock()

        def on_frame(sample: zenoh.Sample) -> None:
            try:
                seq = decode(sample.payload.to_bytes(), FrameHeader).seq
            except ValueError:
                seq = -1  # garbage
            with lock:
                frames_seen.append(seq)

        listener.declare_subscriber("ovis/default/frames", on_frame)
        obstacles_seen: list[bytes] = []
        listener.declare_subscriber(
            "ovis/default/obstacles", lambda s: obstacles_seen.append(s.payload.to_bytes())
        )
        calib_before = _status(op, "calibrator").calibration_version
        pre_before = _status(op, "preprocess")
        saved_before = sorted((secure.root / "state").glob("calibration-v*.json"))

        with secure.session("viewer") as viewer:
            # (b) the viewer receives obstacle frames
            received: list[ObstacleFrame] = []
            viewer.declare_subscriber(
                "ovis/default/obstacles",
                lambda s: received.append(decode(s.payload.to_bytes(), ObstacleFrame)),
                allowed_origin=REMOTE,  # not the viewer's own puts below
            )
            # and sees who is alive and their status
            assert alive(viewer) >= set(STAGES)
            assert _status(viewer, "pose").frames_out > 0
            wait_for(lambda: len(received) >= 3, 10, "obstacle frames at the viewer")
            assert all(isinstance(m, ObstacleFrame) and m.planner is not None for m in received)

            # a subscription wider than the ACL's key expressions is refused as a whole
            # (ovis/** is not inside ovis/*/obstacles): the router sends nothing for it.
            # It only sees what the session's allowed subscription brings in (a session
            # hands every sample it receives to all of its matching subscribers)
            wide: list[str] = []
            viewer.declare_subscriber(
                "ovis/**", lambda s: wide.append(str(s.key_expr)), allowed_origin=REMOTE
            )

            # the viewer's calibrate query reaches no calibrator: no reply, not even an error
            request = encode(CalibrateRequest(seed=1))
            replies = list(viewer.get("ovis/default/calibrate", payload=request, timeout=5.0))
            assert replies == []
            # nor does the current calibration, or any other queryable but status
            assert list(viewer.get("ovis/default/calibration", timeout=2.0)) == []

            # the viewer publishes a valid frame with a recognisable seq, and garbage.
            # (Its client does not even send them: it never learns of a subscriber. The
            # router drops them anyway: test_the_router_itself_drops_denied_puts_and_queries)
            forged = Frame(
                seq=FORGED_SEQ,
                stamp_ns=time.time_ns(),
                rows=480,
                cols=640,
                channels=1,
                data=bytes(480 * 640),
                source="intruder",
            )
            pub = viewer.declare_publisher(
                "ovis/default/frames", encoding=zenoh.Encoding(ENCODING), congestion_control=BLOCK
            )
            for _ in range(5):
                pub.put(encode(forged))
                viewer.put("ovis/default/frames", b"\xc1garbage" * 100, congestion_control=BLOCK)
                time.sleep(0.05)
            # and tries to impersonate: fake obstacles, a fake source of the current
            # calibration (what every service fetches at start), a fake service
            viewer.put("ovis/default/obstacles", b"spoofed obstacles")
            fake_calls: list[int] = []
            viewer.declare_queryable(
                "ovis/default/calibration",
                lambda q: (fake_calls.append(1), q.reply(q.key_expr, b"fake calibration")),
            )
            token = viewer.liveliness().declare_token("ovis/default/alive/impostor")
            time.sleep(1.0)
            assert "impostor" not in alive(op)
            current = list(op.get("ovis/default/calibration", timeout=3.0))
            assert len(current) == 1 and current[0].ok is not None
            update = decode(current[0].ok.payload.to_bytes(), CalibrationUpdate)
            assert update.calibration.version == calib_before
            token.undeclare()
            assert set(wide) <= {"ovis/default/obstacles", "ovis/default/health"}

        # the command line, with the viewer's credentials: refused like any query
        result = secure.cli(
            "recalibrate", "-c", "deploy/secure/viewer.toml", "--connect", secure.endpoint,
            "--timeout", "5", "--json",
        )  # fmt: skip
        assert result.returncode != 0
        assert "no calibrator" in result.stderr and "access control" in result.stderr
        watched = secure.cli(
            "watch", "-c", "deploy/secure/viewer.toml", "--connect", secure.endpoint,
            "--count", "2", "--json", "--duration", "15",
        )  # fmt: skip
        lines = [json.loads(line) for line in watched.stdout.splitlines()]
        assert watched.returncode == 0, watched.stderr
        assert sum(m["type"] == "obstacles" for m in lines) == 2

        # nothing changed: no recalibration, no forged frame reached preprocess or
        # anyone else, no garbage counted, no spoofed obstacles
        assert _status(op, "calibrator").calibration_version == calib_before
        assert sorted((secure.root / "state").glob("calibration-v*.json")) == saved_before
        pre_after = _status(op, "preprocess")
        assert pre_after.frames_in > pre_before.frames_in  # real frames kept flowing
        assert pre_after.errors == pre_before.errors
        assert pre_after.dropped < FORGED_SEQ // 2  # a seq of 10**9 would count as a gap
        with lock:
            assert FORGED_SEQ not in frames_seen and -1 not in frames_seen
            assert len(frames_seen) > 10  # the operator does receive the real frames
        assert b"spoofed obstacles" not in obstacles_seen and len(obstacles_seen) > 5
        assert not any(m.seq == FORGED_SEQ for m in received)

        # control: the same garbage with the capture's credentials does reach preprocess,
        # refused there
        with secure.session("capture") as capture:
            for _ in range(3):
                capture.put("ovis/default/frames", b"\xc1garbage" * 100, congestion_control=BLOCK)
                time.sleep(0.1)
        wait_for(
            lambda: (
                _status(op, "preprocess").errors.get("bad_frame", 0)
                >= pre_before.errors.get("bad_frame", 0) + 3
            ),
            10,
            "the operator's garbage counted by preprocess",
        )
        assert fake_calls == []


def test_operator_recalibrates(secure: Secure):
    with secure.session("operator") as op:
        before = _status(op, "calibrator").calibration_version
    # (c) `ovis recalibrate -c operator.toml --json`: ok and a new version
    result = secure.cli(
        "recalibrate", "-c", "deploy/secure/operator.toml", "--connect", secure.endpoint,
        "--json", "--seed", "3",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    answer = msgspec.json.decode(result.stdout.splitlines()[-1])
    assert answer["ok"] is True and answer["error"] == ""
    assert answer["version"] > before
    assert Path(answer["saved_to"]).is_file()
    with secure.session("operator") as op:
        wait_for(
            lambda: _status(op, "pose").calibration_version == answer["version"],
            10,
            "the new calibration in use downstream",
        )
    # and the viewer sees obstacles made with it
    with secure.session("viewer") as viewer:
        got: list[ObstacleFrame] = []
        viewer.declare_subscriber(
            "ovis/default/obstacles",
            lambda s: got.append(decode(s.payload.to_bytes(), ObstacleFrame)),
        )
        wait_for(
            lambda: any(m.calibration_version == answer["version"] for m in got),
            10,
            "obstacles with the new calibration at the viewer",
        )


def test_status_cli_with_viewer_credentials(secure: Secure):
    result = secure.cli(
        "status", "-c", "deploy/secure/viewer.toml", "--connect", secure.endpoint, "--json"
    )
    assert result.returncode == 0, result.stderr
    report = msgspec.json.decode(result.stdout)
    up = {s["service"] for s in report if s["alive"] and s["status"]}
    assert up >= set(STAGES)


def test_the_router_itself_drops_denied_puts_and_queries(secure: Secure):
    """The Python client of a viewer does not even send its frames: the router does not
    pass subscriber declarations on to it, so it knows of no subscriber and filters its
    own puts. A hostile client would send anyway. Model one by letting the router tell the
    viewer and the pose stage about every subscriber and queryable (declare_* egress): the
    router's ingress rules must still drop the viewer's puts on frames, obstacles and the
    world and its calibrate query, and the pose stage's world; only fusion's world
    passes."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    conf = secure.router_conf(endpoint)
    acl = json.loads(conf.get_json("access_control"))
    acl["rules"] += [
        {
            "id": "hostile",
            "permission": "allow",
            "flows": ["egress"],
            "messages": ["declare_subscriber", "declare_queryable"],
            "key_exprs": ["ovis/**"],
        },
        {  # a key the viewer may publish on: shows that its puts do leave it
            "id": "probe",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["put"],
            "key_exprs": ["ovis/default/probe"],
        },
    ]
    for policy in acl["policies"]:
        if "viewer" in policy["subjects"]:
            policy["rules"] += ["hostile", "probe"]
        if "pose" in policy["subjects"]:
            policy["rules"] += ["hostile"]
    conf.insert_json5("access_control", json.dumps(acl))
    with (
        zenoh.open(conf),
        secure.session("operator", endpoint=endpoint) as op,
        secure.session("calibrator", endpoint=endpoint) as calibrator,
        secure.session("viewer", endpoint=endpoint) as viewer,
        secure.session("pose", endpoint=endpoint) as pose,
        secure.session("fusion", endpoint=endpoint) as fusion,
    ):
        got: list[str] = []
        world: list[bytes] = []
        for key in ("ovis/default/frames", "ovis/default/obstacles", "ovis/default/probe"):
            op.declare_subscriber(key, lambda s: got.append(str(s.key_expr)), allowed_origin=REMOTE)
        op.declare_subscriber("ovis/default/world", lambda s: world.append(s.payload.to_bytes()))
        calls: list[int] = []
        calibrator.declare_queryable(
            "ovis/default/calibrate", lambda q: (calls.append(1), q.reply(q.key_expr, b"done"))
        )
        time.sleep(0.5)
        for _ in range(3):
            viewer.put("ovis/default/frames", b"\xc1garbage", congestion_control=BLOCK)
            viewer.put("ovis/default/obstacles", b"spoofed", congestion_control=BLOCK)
            viewer.put("ovis/default/probe", b"probe", congestion_control=BLOCK)
            viewer.put("ovis/default/world", b"viewer", congestion_control=BLOCK)
            pose.put("ovis/default/world", b"pose", congestion_control=BLOCK)
        fusion.put("ovis/default/world", b"fusion", congestion_control=BLOCK)
        replies = list(viewer.get("ovis/default/calibrate", timeout=2.0))
        wait_for(lambda: "ovis/default/probe" in got, 5, "the viewer's allowed put")
        wait_for(lambda: world, 5, "fusion's world")
        time.sleep(0.5)
        assert set(got) == {"ovis/default/probe"}
        assert world == [b"fusion"]
        assert replies == [] and calls == []
        # the operator's own query does reach the queryable
        assert [r.ok.payload.to_bytes() for r in op.get("ovis/default/calibrate") if r.ok]


def test_mutual_tls_as_documented(secure: Secure):
    """deploy/secure/README.md's mutual TLS: the router sets root_ca_certificate and
    enable_mtls; a client needs its certificate AND enable_mtls (without it, it sends no
    certificate and is refused) on top of its password."""
    subprocess.run(
        ["sh", str(SECURE / "make-certs.sh"), "deploy/secure/out", "--client", "viewer"],
        cwd=secure.root,
        check=True,
        capture_output=True,
        timeout=60,
    )
    endpoint = f"tls/127.0.0.1:{free_port()}"
    conf = secure.router_conf(endpoint)
    conf.insert_json5(
        "transport/link/tls/root_ca_certificate", json.dumps(str(secure.out / "ca.crt"))
    )
    conf.insert_json5("transport/link/tls/enable_mtls", "true")
    tls = "transport/link/tls/"
    with zenoh.open(conf):
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            secure.session("viewer", endpoint=endpoint).close()  # password, no certificate
        client = secure.conf("viewer", endpoint=endpoint)
        client.insert_json5(
            tls + "connect_certificate", json.dumps(str(secure.out / "client-viewer.crt"))
        )
        client.insert_json5(
            tls + "connect_private_key", json.dumps(str(secure.out / "client-viewer.key"))
        )
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(client).close()  # a certificate, but enable_mtls not set
        client.insert_json5(tls + "enable_mtls", "true")
        zenoh.open(client).close()
        client.insert_json5("transport/auth/usrpwd/password", '"wrong"')
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(client).close()  # a certificate does not replace the password


def test_operator_can_no_longer_publish_calibrations_or_frames(secure: Secure):
    """One identity per service: the operator's login (the person who recalibrates) may
    read and ask for a recalibration, but the router drops its frames and calibrations
    and refuses it the calibration queryable; the services go on with their jobs."""
    with secure.session("operator") as op, secure.session("calibrator") as watcher:
        seen: dict[str, list[bytes]] = {"frames": [], "calibration": []}
        for topic, got in seen.items():
            watcher.declare_subscriber(
                f"ovis/default/{topic}",
                lambda s, got=got: got.append(s.payload.to_bytes()),
                allowed_origin=REMOTE,
            )
        genuine = _status(op, "calibrator").calibration_version
        forged = CalibrationUpdate(
            calibration=msgspec.structs.replace(
                decode(
                    next(
                        r for r in op.get("ovis/default/calibration", timeout=3.0) if r.ok
                    ).ok.payload.to_bytes(),
                    CalibrationUpdate,
                ).calibration,
                version=999999,
            )
        )
        frame = Frame(
            seq=FORGED_SEQ,
            stamp_ns=time.time_ns(),
            rows=480,
            cols=640,
            data=bytes(480 * 640),
            source="operator",
        )
        calls: list[int] = []
        op.declare_queryable(
            "ovis/default/calibration",
            lambda q: (calls.append(1), q.reply(q.key_expr, encode(forged))),
        )
        for _ in range(30):
            op.put("ovis/default/calibration", encode(forged), congestion_control=BLOCK)
            op.put("ovis/default/frames", encode(frame), congestion_control=BLOCK)
            time.sleep(0.02)
        time.sleep(3.0)  # longer than a stage's reconcile period
        assert not any(encode(forged) == p for p in seen["calibration"])
        assert not any(decode(p, FrameHeader).seq == FORGED_SEQ for p in seen["frames"])
        assert len(seen["frames"]) > 10  # the capture's frames do reach the calibrator
        assert calls == []  # nobody asked the operator's fake queryable
        for stage in ("preprocess", "label", "pose"):
            status = _status(op, stage)
            assert status.calibration_version == genuine, stage
            assert status.state == "ok" and status.dropped < FORGED_SEQ // 2, stage
        # and each service still does its job: obstacles keep coming, with the genuine
        # calibration (the operator's recalibration: test_operator_recalibrates)
        out = _status(op, "pose").frames_out
        wait_for(lambda: _status(op, "pose").frames_out > out + 5, 10, "obstacles")


def test_frames_go_through_shared_memory_in_the_secure_profile(secure: Secure):
    """Issue 31 item 4: with TLS, passwords and access control, a frame still reaches a
    subscriber on the same host as a shared buffer (the capture's, through the router):
    the capture's own writer put them there, not only Zenoh's transport."""
    got: list[tuple[bool, int]] = []
    lock = threading.Lock()

    def on_frame(sample: zenoh.Sample) -> None:
        header = decode(sample.payload.to_bytes(), FrameHeader)
        with lock:
            got.append((sample.payload.as_shm() is not None, header.seq))

    with secure.session("operator") as op:
        op.declare_subscriber("ovis/default/frames", on_frame)
        wait_for(lambda: len(got) >= 5, 20, "frames at the operator")
        capture = _status(op, "capture")
        assert capture.shm_written >= capture.frames_out - 1 > 0, capture
    with lock:
        assert all(shm for shm, _ in got), f"frames came as bytes: {got}"
        assert [seq for _, seq in got] == sorted({seq for _, seq in got})

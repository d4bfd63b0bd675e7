"""ROS 2 ``cmd_vel`` read back for the physical world (``[navigation] follow =
"cmd_vel"``): a TwistStamped packed by the CDR format's rules (``cdr_helpers``) decoded to ovis's
units and floor; the planner's own messages round-trip; malformed and impossible ones
refused with the reason; speeds over the robot's limits clamped."""

from __future__ import annotations

import math

import pytest
from cdr_helpers import pack_twist_stamped

from ovis.common.ros2.cdr import typestore
from ovis.common.ros2.cmd_vel import (
    TWIST_STAMPED,
    CmdVelError,
    cmd_vel_message,
    cmd_vel_robot,
    read_cmd_vel,
)

NOW = 1_700_000_000_123_456_789
LIMITS = {"max_speed_cm_s": 20.0, "max_yaw_rate_deg_s": 240.0, "max_frame_age_s": 0.5}


def _read(cdr: bytes, robot_id: int = 1, mirrored: bool = False, **limits: float):
    return read_cmd_vel(cdr, robot_id, now_ns=NOW, mirrored=mirrored, **(LIMITS | limits))


def test_units_and_floor_mapped_back() -> None:
    sec, ns = divmod(NOW - 40_000_000, 1_000_000_000)
    cdr = pack_twist_stamped(sec, ns, "robot_1/base_link", (0.125, 0.0, 0.0, 0.0, 0.0, 0.5))
    plain = _read(cdr)
    assert plain.v_cm_s == pytest.approx(12.5)
    assert plain.omega_deg_s == pytest.approx(28.64788975654116)  # 0.5 rad/s
    assert plain.stamp_ns == NOW - 40_000_000 and not plain.clamped
    # a mirrored floor (the paper's camera): ROS's counter-clockwise is ovis's clockwise
    mirrored = _read(cdr, mirrored=True)
    assert mirrored.v_cm_s == pytest.approx(12.5)
    assert mirrored.omega_deg_s == pytest.approx(-28.64788975654116)
    # a frame_id left empty (teleop tools) is followed; another robot's is not
    assert _read(pack_twist_stamped(sec, ns, "", (0.1, 0, 0, 0, 0, 0))).v_cm_s == pytest.approx(
        10.0
    )
    with pytest.raises(CmdVelError, match="robot_2/base_link"):
        _read(pack_twist_stamped(sec, ns, "robot_2/base_link", (0.1, 0, 0, 0, 0, 0)))


@pytest.mark.parametrize("mirrored", [False, True])
def test_the_planners_messages_round_trip(mirrored: bool) -> None:
    for v, omega in ((15.0, -30.0), (-4.0, 200.0), (0.0, 0.0)):
        message = cmd_vel_message(3, v, omega, NOW - 1000, mirrored=mirrored)
        back = _read(message.cdr, robot_id=3, mirrored=mirrored)
        assert (back.v_cm_s, back.omega_deg_s) == pytest.approx((v, omega))
        assert back.stamp_ns == NOW - 1000


def test_over_the_limits_clamped() -> None:
    sec, ns = divmod(NOW, 1_000_000_000)
    fast = _read(pack_twist_stamped(sec, ns, "", (0.5, 0, 0, 0, 0, -10.0)))  # 50 cm/s, −573 °/s
    assert (fast.v_cm_s, fast.omega_deg_s, fast.clamped) == (20.0, -240.0, True)
    back = _read(pack_twist_stamped(sec, ns, "", (-0.3, 0, 0, 0, 0, 0)))
    assert (back.v_cm_s, back.clamped) == (-20.0, True)


@pytest.mark.parametrize(
    ("six", "why"),
    [
        ((math.nan, 0, 0, 0, 0, 0), "not a finite number"),
        ((0.1, 0, 0, 0, 0, math.inf), "not a finite number"),
        ((0.1, 0.05, 0, 0, 0, 0), "differential drive cannot"),
        ((0.1, 0, 0, 0, 0.2, 0), "differential drive cannot"),
    ],
)
def test_impossible_velocities_refused(six: tuple[float, ...], why: str) -> None:
    sec, ns = divmod(NOW, 1_000_000_000)
    with pytest.raises(CmdVelError, match=why):
        _read(pack_twist_stamped(sec, ns, "robot_1/base_link", six))


def test_malformed_and_future_messages_refused() -> None:
    sec, ns = divmod(NOW, 1_000_000_000)
    good = pack_twist_stamped(sec, ns, "robot_1/base_link", (0.1, 0, 0, 0, 0, 0))
    for bad in (good[:-8], good[:10], b"", b"\x00\x01\x00\x00" + b"\xff" * 8):
        with pytest.raises(CmdVelError, match=f"not a {TWIST_STAMPED}"):
            _read(bad)
    # stamped a second ahead of this clock: its age cannot be judged against 0.5 s
    ahead = pack_twist_stamped(sec + 1, ns, "robot_1/base_link", (0.1, 0, 0, 0, 0, 0))
    with pytest.raises(CmdVelError, match="ahead of the receiver's clock"):
        _read(ahead)
    # a stamp long past is decoded: the robot's frame-age rule stops it
    assert _read(pack_twist_stamped(0, 0, "", (0.1, 0, 0, 0, 0, 0))).stamp_ns == 0


def test_which_robot_a_topic_commands() -> None:
    assert cmd_vel_robot("/ovis/robots/robot_3/cmd_vel", "/ovis") == 3
    assert cmd_vel_robot("/ovis/robots/robot_12/cmd_vel", "/ovis/") == 12
    assert cmd_vel_robot("/robots/robot_0/cmd_vel", "/") == 0
    assert cmd_vel_robot("/other/robots/robot_3/cmd_vel", "/ovis") is None
    assert cmd_vel_robot("/ovis/robots/robot_x/cmd_vel", "/ovis") is None
    assert cmd_vel_robot("/ovis/robots/robot_3/odom", "/ovis") is None


def test_packing_here_is_rosbags_layout() -> None:
    """The hand packing is what rosbags writes (so the tests read real bytes)."""
    message = cmd_vel_message(1, 12.5, 0.0, NOW)
    sec, ns = divmod(NOW, 1_000_000_000)
    assert message.cdr == pack_twist_stamped(sec, ns, "robot_1/base_link", (0.125, 0, 0, 0, 0, 0.0))
    assert typestore().deserialize_cdr(message.cdr, TWIST_STAMPED).twist.linear.x == 0.125

"""The byte-level fast path of replay agrees with rosbags' own (de)serialisation."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from ccf_ros.messages import cdr as fastcdr
from ccf_ros.messages.paths import FastCdrPath
from ccf_ros.offline.bagio import typestore


def make_imu(frame_id: str = 'imu_link', nanosec: int = 123456789) -> tuple[Any, Any, bytes]:
    """Header, Imu message (gyro 1, 2, 3; acc 4, 5, 6) and its CDR bytes, by rosbags."""
    T = typestore().types
    hdr = T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=1700000001, nanosec=nanosec),
                                   frame_id=frame_id)
    V = T['geometry_msgs/msg/Vector3']
    imu = T['sensor_msgs/msg/Imu'](
        header=hdr, orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.arange(9.0), angular_velocity=V(x=1.0, y=2.0, z=3.0),
        angular_velocity_covariance=np.zeros(9), linear_acceleration=V(x=4.0, y=5.0, z=6.0),
        linear_acceleration_covariance=np.ones(9))
    return hdr, imu, bytes(typestore().serialize_cdr(imu, 'sensor_msgs/msg/Imu'))


# Every frame_id length mod 8 (the padding after the header differs with it), and a longer one.
FRAME_IDS = ['x' * k for k in range(9)] + ['imu_link', 'x' * 13]


@pytest.mark.parametrize('frame_id', FRAME_IDS)
def test_read_patch_and_build_match_rosbags(frame_id):
    ts = typestore()
    T = ts.types
    V = T['geometry_msgs/msg/Vector3']
    hdr, _, raw = make_imu(frame_id)
    t, off, g, a = fastcdr.read_imu(raw)
    assert t == 1700000001 + 123456789 * 1e-9 and g == (1.0, 2.0, 3.0) and a == (4.0, 5.0, 6.0)
    buf = bytearray(raw)
    fastcdr.patch_imu(buf, off, (0.1, 0.2, 0.3, 0.9), tuple(float(i) for i in range(10, 19)))
    back = ts.deserialize_cdr(bytes(buf), 'sensor_msgs/msg/Imu')
    assert (back.orientation.x, back.orientation.y, back.orientation.z, back.orientation.w) == (0.1, 0.2, 0.3, 0.9)
    assert list(back.orientation_covariance) == list(range(10, 19))
    assert list(back.linear_acceleration_covariance) == [1.0] * 9 and back.header.frame_id == frame_id
    v3 = T['geometry_msgs/msg/Vector3Stamped'](header=hdr, vector=V(x=7.0, y=8.0, z=9.0))
    assert fastcdr.vector3_stamped(raw, off, (7.0, 8.0, 9.0)) == bytes(
        ts.serialize_cdr(v3, 'geometry_msgs/msg/Vector3Stamped'))
    mf = T['sensor_msgs/msg/MagneticField'](header=hdr, magnetic_field=V(x=1e-5, y=2e-5, z=3e-5),
                                            magnetic_field_covariance=np.zeros(9))
    assert fastcdr.read_mag(bytes(ts.serialize_cdr(mf, 'sensor_msgs/msg/MagneticField'))) == (
        1700000001 + 123456789 * 1e-9, (1e-5, 2e-5, 3e-5))


@pytest.mark.parametrize('vectors', [False, True])
def test_an_answer_filled_into_a_message_serializes_to_the_patched_bytes(vectors):
    """messages.fill_imu (the deserializing path) and patch_imu/patch_imu_vectors (the fast path) write the same
    answer: rosbags serializes the filled message to exactly the patched bytes; stamps read alike."""
    from ccf_ros.engine import Output
    from ccf_ros.messages.convert import fill_imu, seconds, stamp_s

    hdr, imu, raw = make_imu(nanosec=999999999)
    out = Output((0.1, 0.2, 0.3, 0.9), tuple(float(i) for i in range(9)), (1e-3, 2e-3, 3e-3), 0,
                 *(((0.5, 0.6, 0.7), (0.0, 0.1, 9.7)) if vectors else ()))
    t, off, _, _ = fastcdr.read_imu(raw)
    assert t == seconds(1700000001, 999999999) == stamp_s(hdr)
    buf = bytearray(raw)
    fastcdr.patch_imu(buf, off, out.orientation_xyzw, out.covariance)
    fastcdr.patch_imu_vectors(buf, off, out.angular_velocity, out.linear_acceleration)
    fill_imu(imu, out, np.array(out.covariance))
    # FastCdrPath.answer writes patch_imu out (and calls patch_imu_vectors): the same bytes.
    assert FastCdrPath().answer(raw, off, out)[1] == buf
    assert bytes(typestore().serialize_cdr(imu, 'sensor_msgs/msg/Imu')) == bytes(buf)
    tail = off + fastcdr.ANGULAR_VELOCITY
    assert (bytes(buf[tail:]) != raw[tail:]) == vectors  # rate and acceleration replaced only when given

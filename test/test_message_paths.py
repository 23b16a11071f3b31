"""The two message paths the node and replay share (ccf_ros.messages.paths) answer alike, and the new layout keeps
its promises: old import paths give the same objects, plain-code modules import no ROS."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from test_fastcdr import make_imu

from ccf_ros.engine import Output
from ccf_ros.frames import rotation_matrix
from ccf_ros.messages import cdr
from ccf_ros.messages.paths import FastCdrPath, MessagePath
from ccf_ros.offline.bagio import typestore

IMU, V3S = 'sensor_msgs/msg/Imu', 'geometry_msgs/msg/Vector3Stamped'


def _paths(frame: str, rot):
    """Both paths, each answering with the CDR bytes rosbags would write (the message path: a fresh message as
    deserialization gives it)."""
    ts = typestore()
    T = ts.types

    def stamped(header, v):
        return T[V3S](header=header, vector=T['geometry_msgs/msg/Vector3'](x=v[0], y=v[1], z=v[2]))

    fast = FastCdrPath(frame, rot)
    slow = MessagePath(lambda raw: make_imu('imu_link')[1], None, stamped, np.array, frame, rot)
    return ts, fast, slow


@pytest.mark.parametrize('frame', ['', 'base_link', 'a_much_longer_output_frame'])
@pytest.mark.parametrize('turned', [False, True])
@pytest.mark.parametrize('vectors', [False, True])
def test_fast_and_message_paths_give_the_same_bytes(frame, turned, vectors):
    rot = rotation_matrix('mount_rotation', (0.1, 0.2, 0.3)) if turned else None
    ts, fast, slow = _paths(frame, rot)
    assert fast.reframes == slow.reframes == bool(frame or turned)
    _, _, raw = make_imu('imu_link')
    out = Output((0.1, 0.2, 0.3, 0.9), tuple(float(i) for i in range(9)), (1e-3, 2e-3, 3e-3), 0,
                 *(((0.5, 0.6, 0.7), (0.0, 0.1, 9.7)) if vectors else ()))
    answers = []
    for path in (fast, slow):
        t, same, src, off, gyr, acc = path.read_imu(raw)
        assert same is path and (t, gyr, acc) == (1700000001 + 123456789 * 1e-9, (1.0, 2.0, 3.0), (4.0, 5.0, 6.0))
        assert path.frame_id(src) == 'imu_link'
        imu, src, off = path.answer(src, off, out)
        bias = path.stamped(src, off, out.bias)
        answers.append((path.header(src), imu, bias))
    (h_fast, imu_fast, bias_fast), (h_msg, imu_msg, bias_msg) = answers
    assert h_fast == h_msg == (1700000001, 123456789, frame or 'imu_link')
    assert imu_fast == bytes(ts.serialize_cdr(imu_msg, IMU))
    assert bias_fast == bytes(ts.serialize_cdr(bias_msg, V3S))
    back = ts.deserialize_cdr(imu_fast, IMU)
    assert (back.orientation.x, back.orientation.w) == (0.1, 0.9)
    if turned:  # the input's rate covariance (0) stays 0, the acceleration's (ones) turns
        assert not np.array_equal(back.linear_acceleration_covariance, np.ones(9))


def test_output_frame_is_set_on_the_path_object():
    """The node changes the output frame on its path objects (held samples keep their path)."""
    fast = FastCdrPath()
    _, _, raw = make_imu('imu_link')
    out = Output((0.0, 0.0, 0.0, 1.0), (0.0,) * 9, (0.0, 0.0, 0.0), 0)
    _, _, src, off, _, _ = fast.read_imu(raw)
    assert fast.answer(src, off, out)[0] == bytes(fast.answer(src, off, out)[1])
    fast.set_output('base_link', None)
    assert fast.reframes and cdr.frame_id(fast.answer(src, off, out)[0]) == 'base_link'
    fast.set_output('', None)
    assert not fast.reframes and cdr.frame_id(fast.answer(src, off, out)[0]) == 'imu_link'


@pytest.mark.parametrize('frame_id', ['x' * k for k in range(9)] + ['x' * 13])  # every length mod 8
def test_fast_path_reads_as_cdr_read_imu_for_every_header_length(frame_id):
    """FastCdrPath.read_imu writes cdr.read_imu out (a call less per message): the copies agree, on every padding."""
    _, _, raw = make_imu(frame_id)
    fast = FastCdrPath()
    t, off, gyr, acc = cdr.read_imu(raw)
    assert fast.read_imu(raw) == (t, fast, raw, off, gyr, acc)
    assert (t, gyr, acc) == (1700000001 + 123456789 * 1e-9, (1.0, 2.0, 3.0), (4.0, 5.0, 6.0))
    assert cdr.frame_id(fast.answer(raw, off, Output((0.0, 0.0, 0.0, 1.0), (0.0,) * 9, (0.0,) * 3, 0))[0]) == frame_id


def test_fast_path_refuses_an_imu_shorter_than_its_tail():
    _, _, raw = make_imu('imu_link')
    off = cdr.read_imu(raw)[1]
    need = len(raw) - off
    assert FastCdrPath(tail=need).read_imu(raw)[2] is raw
    with pytest.raises(ValueError, match='too short'):
        FastCdrPath(tail=need + 1).read_imu(raw)


def test_old_module_paths_give_the_new_objects():
    import ccf_ros.compat
    import ccf_ros.node.compat
    import ccf_ros.node.debug
    import ccf_ros.node.diagnostics
    import ccf_ros.node.parameters
    import ccf_ros.node.stats
    import ccf_ros.node.sync
    import ccf_ros.node_support
    import ccf_ros.sync
    from ccf_ros.messages import convert
    from ccf_ros.offline import fastcdr, messages

    for name in ('read_imu', 'read_mag', 'patch_imu', 'patch_imu_vectors', 'vector3_stamped', 'reframe_imu',
                 'frame_id', 'stamped_columns', 'LITTLE_ENDIAN_CDR', 'ANGULAR_VELOCITY', 'LINEAR_ACCELERATION',
                 '_gather'):
        assert getattr(fastcdr, name) is getattr(cdr, name), name
    for name in ('seconds', 'stamp_s', 'fill_imu', 'reframe_msg'):
        assert getattr(messages, name) is getattr(convert, name), name
    for name in ('HOLD_S', 'HoldStats', 'ImuMagSync'):
        assert getattr(ccf_ros.sync, name) is getattr(ccf_ros.node.sync, name), name
    for name in ('PROFILES', 'NodeProfile', 'defaults_for', 'tf_transform', 'MEANINGLESS_GAINS'):
        assert getattr(ccf_ros.compat, name) is getattr(ccf_ros.node.compat, name), name
    homes = (ccf_ros.node.debug, ccf_ros.node.diagnostics, ccf_ros.node.parameters, ccf_ros.node.stats)
    for name in ccf_ros.node_support.__all__:
        new = cdr.header if name == 'imu_header' else next(getattr(m, name) for m in homes if hasattr(m, name))
        assert getattr(ccf_ros.node_support, name) is new, name


def test_node_package_names_resolve_and_the_entry_points_are_functions():
    import ccf_ros.node
    from ccf_ros.node import entry, lifecycle, node

    for name in ccf_ros.node.__all__:
        assert getattr(ccf_ros.node, name) is getattr({'entry': entry, 'lifecycle': lifecycle, 'node': node}[
            ccf_ros.node._HOME[name]], name)
    for name in ('main', 'lifecycle_main', 'imu_filter_madgwick_main', 'complementary_filter_main'):
        assert callable(getattr(ccf_ros.node, name)) and getattr(ccf_ros.node, name).__module__ == 'ccf_ros.node.entry'
    with pytest.raises(AttributeError):
        ccf_ros.node.no_such_name  # noqa: B018


def test_plain_code_modules_import_no_ros():
    """The message code and the node's plain-code modules load without rclpy or rosbags (the CLI imports compat)."""
    code = ('import sys; import ccf_ros.messages.paths, ccf_ros.node.compat, ccf_ros.node.sync, ccf_ros.node.stats, '
            'ccf_ros.node.diagnostics, ccf_ros.node.parameters, ccf_ros.node.debug, ccf_ros.sync, ccf_ros.compat, '
            'ccf_ros.node_support; '
            'print(sorted(m for m in sys.modules if m.split(".")[0] in ("rclpy", "rosbags")))')
    r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120, check=True)
    assert r.stdout.strip() == '[]'

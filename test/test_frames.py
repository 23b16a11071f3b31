"""Mounting (mount_rotation, mag_rotation, output_frame_id), gyro_offset_rad_s and the state file (bias_file)."""

from __future__ import annotations

import json
import math
import os
import re
import time

import numpy as np
import pytest

from ccf_ros.core import make_filter
from ccf_ros.engine import ImuEngine
from ccf_ros.errors import ParameterError
from ccf_ros.frames import rotate_covariance, rotation_matrix
from ccf_ros.offline.simulate import generate
from ccf_ros.settings import adapter_settings, build
from ccf_ros.state_file import State, StateFileError, read_state, write_state

#: Mounts: a 90° bracket, upside down, an arbitrary one (rpy), the same kind as a quaternion [x, y, z, w].
MOUNTS = {
    'bracket_90': [0.0, 0.0, math.pi / 2],
    'upside_down': [math.pi, 0.0, 0.0],
    'arbitrary': [0.3, -1.1, 2.5],
    'quaternion': [0.2, -0.4, 0.5, math.sqrt(1 - 0.04 - 0.16 - 0.25)],
}


@pytest.fixture(scope='module')
def sim():
    return generate(40.0, 200.0, seed=5)


def run(engine: ImuEngine, t, gyr, acc, mag):
    out = []
    for k in range(len(t)):
        engine.on_mag(float(t[k]), tuple(mag[k]))
        out.append(engine.on_imu(float(t[k]), tuple(gyr[k]), tuple(acc[k])))
    return out


def engine(**settings) -> ImuEngine:
    filt, adapter = build(settings)
    return ImuEngine(filt, adapter)


def orientations(outs) -> np.ndarray:
    return np.array([o.orientation_xyzw for o in outs if o is not None])


def into_imu_frame(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """What an IMU mounted with rotation R (IMU -> output frame) measures of output-frame vectors v (N, 3)."""
    return v @ R  # R^T v per row


@pytest.mark.parametrize('mount', MOUNTS)
def test_a_rotated_recording_with_mount_rotation_gives_the_unrotated_result(sim, mount):
    """Gyro, accelerometer and magnetometer turned into a mounted IMU's frame, with mount_rotation set: the same
    orientation, rate and acceleration (in the output frame) as the unrotated recording."""
    R = np.array(rotation_matrix('m', MOUNTS[mount])).reshape(3, 3)
    ref = run(engine(), sim.t_s, sim.gyr, sim.acc, sim.mag)
    got = run(engine(mount_rotation=MOUNTS[mount]), sim.t_s, into_imu_frame(R, sim.gyr), into_imu_frame(R, sim.acc),
              into_imu_frame(R, sim.mag))
    assert len(orientations(ref)) == len(orientations(got)) > 0
    assert np.max(np.abs(orientations(got) - orientations(ref))) < 1e-9
    outs = [o for o in got if o is not None]
    n = len(sim.t_s) - len(outs)
    # Rates and accelerations are published in the output frame: the unrotated recording's.
    assert np.max(np.abs(np.array([o.angular_velocity for o in outs]) - sim.gyr[n:])) < 1e-12
    assert np.max(np.abs(np.array([o.linear_acceleration for o in outs]) - sim.acc[n:])) < 1e-12
    cov_ref = np.array([o.covariance for o in ref if o is not None])
    assert np.max(np.abs(np.array([o.covariance for o in outs]) - cov_ref)) < 1e-12


@pytest.mark.parametrize('mount', ['bracket_90', 'arbitrary', 'quaternion'])
def test_a_magnetometer_on_another_chip_with_mag_rotation_gives_the_same_result(sim, mount):
    R = np.array(rotation_matrix('m', MOUNTS[mount])).reshape(3, 3)
    ref = run(engine(), sim.t_s, sim.gyr, sim.acc, sim.mag)
    got = run(engine(mag_rotation=MOUNTS[mount]), sim.t_s, sim.gyr, sim.acc, into_imu_frame(R, sim.mag))
    assert np.max(np.abs(orientations(got) - orientations(ref))) < 1e-9
    # Without mag_rotation the heading is wrong: the test can tell.
    bad = run(engine(), sim.t_s, sim.gyr, sim.acc, into_imu_frame(R, sim.mag))
    assert np.max(np.abs(orientations(bad) - orientations(ref))) > 0.1


def test_mount_and_mag_rotation_and_hard_iron_compose(sim):
    """Both chips turned differently, the magnetometer with a hard-iron offset (in its own frame)."""
    Rm = np.array(rotation_matrix('m', MOUNTS['arbitrary'])).reshape(3, 3)
    Rg = np.array(rotation_matrix('g', MOUNTS['upside_down'])).reshape(3, 3)
    offset = np.array([30e-6, -12e-6, 8e-6])
    mag_chip = into_imu_frame(Rg, into_imu_frame(Rm, sim.mag)) + offset
    ref = run(engine(), sim.t_s, sim.gyr, sim.acc, sim.mag)
    got = run(engine(mount_rotation=MOUNTS['arbitrary'], mag_rotation=MOUNTS['upside_down'],
                     mag_bias_x=offset[0], mag_bias_y=offset[1], mag_bias_z=offset[2]),
              sim.t_s, into_imu_frame(Rm, sim.gyr), into_imu_frame(Rm, sim.acc), mag_chip)
    assert np.max(np.abs(orientations(got) - orientations(ref))) < 1e-9


def test_identity_mount_is_skipped_and_bit_identical(sim):
    e = engine(mount_rotation=[0.0, 0.0, 0.0, 1.0], mag_rotation=[0, 0, 0])
    assert e.output_rotation is None and e._reframe is None and e._mag_cal is None
    ref = run(engine(), sim.t_s[:500], sim.gyr, sim.acc, sim.mag)
    got = run(e, sim.t_s[:500], sim.gyr, sim.acc, sim.mag)
    assert [o.orientation_xyzw for o in got if o] == [o.orientation_xyzw for o in ref if o]
    assert all(o.angular_velocity is None and o.linear_acceleration is None for o in got if o)


def test_gyro_offset_is_subtracted_first(sim):
    off = np.radians([5.0, -3.0, 4.0])
    ref = run(engine(), sim.t_s, sim.gyr, sim.acc, sim.mag)
    got = run(engine(gyro_offset_rad_s=list(off)), sim.t_s, sim.gyr + off, sim.acc, sim.mag)
    # Subtraction rounds differently from the clean input: equal to rounding, not bit for bit.
    assert np.max(np.abs(orientations(got) - orientations(ref))) < 1e-9
    outs = [o for o in got if o is not None]
    assert np.max(np.abs(np.array([o.angular_velocity for o in outs]) - sim.gyr[len(sim.t_s) - len(outs):])) < 1e-12


@pytest.mark.parametrize(('name', 'value', 'message'), [
    ('mount_rotation', [0.0, 1.0], 'mount_rotation must be \\[roll, pitch, yaw\\]'),
    ('mount_rotation', [0.0, 0.0, 0.5, 0.5], 'norm 1'),
    ('mag_rotation', [0.0, float('nan'), 0.0], 'mag_rotation must be'),
    ('mag_rotation', 'a, b, c', 'mag_rotation must be a number'),
    ('gyro_offset_rad_s', [0.1, 0.2], 'gyro_offset_rad_s must be 3 finite numbers'),
    ('output_frame_id', 3, 'output_frame_id must be a string'),
])
def test_bad_mounting_values_are_refused_by_name(name, value, message):
    with pytest.raises(ParameterError, match=message):
        build({name: value})


def test_settings_take_text_from_the_command_line():
    a = adapter_settings({'mount_rotation': '[0, 0, 1.5707963267948966]', 'gyro_offset_rad_s': '0.1, 0, 0',
                          'output_frame_id': 'base_link'})
    assert a.mount_rotation == (0.0, 0.0, math.pi / 2) and a.gyro_offset_rad_s == (0.1, 0.0, 0.0)
    R = np.array(a.mount_matrix).reshape(3, 3)
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0])  # IMU x points along the output's y


def test_rpy_matches_the_quaternion_form_and_static_transform_publisher_order():
    # fixed X-Y-Z: R = Rz(yaw) Ry(pitch) Rx(roll)
    r, p, y = 0.3, -1.1, 2.5
    Rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    Ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    Rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    assert np.allclose(np.array(rotation_matrix('m', [r, p, y])).reshape(3, 3), Rz @ Ry @ Rx, atol=1e-15)
    # Quaternion of a 90° turn about z, [x, y, z, w]:
    h = math.sqrt(0.5)
    assert np.allclose(rotation_matrix('m', [0, 0, h, h]), rotation_matrix('m', [0, 0, math.pi / 2]), atol=1e-15)


def test_covariance_is_rotated_and_unknown_is_kept():
    R = rotation_matrix('m', [0, 0, math.pi / 2])
    c = rotate_covariance(R, (1.0, 0, 0, 0, 4.0, 0, 0, 0, 9.0))
    assert np.allclose(c, (4.0, 0, 0, 0, 1.0, 0, 0, 0, 9.0), atol=1e-12)
    assert rotate_covariance(R, (-1.0,) + (0.0,) * 8) == (-1.0,) + (0.0,) * 8
    iso = (2.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0)
    assert rotate_covariance(R, iso) is iso  # c I: unchanged by any rotation, not recomputed


# --- state file -----------------------------------------------------------------------------------------------------


def test_set_gyro_bias_sets_the_state_and_its_covariance():
    f = make_filter({'filter': 'ccf'})
    assert f.set_gyro_bias((0.01, -0.02, 0.005), 0.001)
    assert f.gyro_bias == (0.01, -0.02, 0.005)
    assert f.gyro_bias_sigma_rad_s == pytest.approx(0.001)
    assert not make_filter({'filter': 'madgwick'}).set_gyro_bias((0.01, 0.0, 0.0), 0.001)


def test_state_file_round_trip_keeps_other_sections(tmp_path):
    path = tmp_path / 'bias.json'
    st = State('imu_link', time.time(), {'hard_iron': {'offset_t': [1e-6, 2e-6, 3e-6]}})
    st.set_gyro_bias((0.01, -0.02, 0.03), 0.0004)
    write_state(path, st)
    back = read_state(path)
    assert back.frame_id == 'imu_link' and back.gyro_bias() == ((0.01, -0.02, 0.03), 0.0004)
    assert back.sections['hard_iron'] == {'offset_t': [1e-6, 2e-6, 3e-6]}
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bias.json']  # no temporary left


def test_an_interrupted_write_leaves_the_previous_file(tmp_path, monkeypatch):
    """The write goes to a temporary and is renamed: a failure mid-write leaves the old file whole, no temporary."""
    path = tmp_path / 'bias.json'
    old = State('imu_link', time.time())
    old.set_gyro_bias((0.01, 0.0, 0.0), 0.001)
    write_state(path, old)
    before = path.read_bytes()

    def boom(*_a, **_k):
        raise OSError('disk full')

    monkeypatch.setattr(os, 'fsync', boom)
    new = State('imu_link', time.time())
    new.set_gyro_bias((0.5, 0.5, 0.5), 0.001)
    with pytest.raises(OSError, match='disk full'):
        write_state(path, new)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bias.json']


@pytest.mark.parametrize(('content', 'message'), [
    ('{"version": 1, "frame_id": "imu_link", "stamp": NOW, "sections": {"gyro_bias": {"bias_rad_s": [0.01, 0, 0], '
     '"sigma_rad_s": 0.001}}}', "written for frame_id 'imu_link', this IMU is 'other_imu'"),
    ('{"version": 1, "fram', 'not JSON'),
    ('{"version": 7}', 'version 7'),
    ('{"version": 1, "frame_id": "imu_link", "stamp": NOW, "sections": {"gyro_bias": {"bias_rad_s": [1, 2]}}}',
     'bias_rad_s must be 3'),
    ('{"version": 1, "frame_id": "imu_link", "stamp": OLD, "sections": {}}', 'stale'),
    (b'\xff\xfe\x00', 'cannot read'),
])
def test_a_foreign_corrupt_or_stale_bias_file_is_one_warning_never_a_crash(sim, tmp_path, content, message):
    path = tmp_path / 'bias.json'
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content.replace('NOW', str(time.time())).replace('OLD', str(time.time() - 100 * 86400)))
    seen: list[str] = []
    e = engine(bias_file=str(path))
    e.on_warning = seen.append
    e.set_sensor_frame('other_imu')
    assert len(e.warnings) == 1 and re.search(message, e.warnings[0]), e.warnings
    assert e.filter.gyro_bias == (0.0, 0.0, 0.0)
    run(e, sim.t_s[:200], sim.gyr, sim.acc, sim.mag)  # runs on
    assert len(e.warnings) == 1
    # The adapter's logger gets the one it set after loading (the node logs earlier ones itself).
    assert seen == (e.warnings if 'frame_id' in message else [])


def test_a_missing_bias_file_is_silent_and_is_written_on_save(sim, tmp_path):
    path = tmp_path / 'bias.json'
    e = engine(bias_file=str(path))
    e.set_sensor_frame('imu_link')
    run(e, sim.t_s[:2000], sim.gyr, sim.acc, sim.mag)
    e.save_state(path)
    assert not e.warnings
    data = json.loads(path.read_text())
    assert data['version'] == 1 and data['frame_id'] == 'imu_link'
    assert np.allclose(data['sections']['gyro_bias']['bias_rad_s'], e.filter.gyro_bias)


def test_the_bias_file_is_kept_in_the_imu_frame_with_the_offset(sim, tmp_path):
    """Saved under one mount and offset, loaded under another: the bias means the same sensor's."""
    path = tmp_path / 'bias.json'
    a = engine(mount_rotation=MOUNTS['arbitrary'], gyro_offset_rad_s=[0.01, 0.0, -0.02], bias_file=str(path))
    a.set_sensor_frame('imu_link')
    a.on_imu(1.7e9, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81))  # an orientation exists: the state is worth saving
    a.filter.set_gyro_bias((0.003, -0.004, 0.002), 1e-4)
    a.save_state(path)
    R = np.array(rotation_matrix('m', MOUNTS['arbitrary'])).reshape(3, 3)
    b_imu = R.T @ [0.003, -0.004, 0.002] + [0.01, 0.0, -0.02]
    assert np.allclose(read_state(path).gyro_bias()[0], b_imu, atol=1e-15)
    stamp = read_state(path).stamp
    t0 = time.time()
    b = engine(bias_file=str(path))
    b.set_sensor_frame('imu_link')
    t1 = time.time()
    assert np.allclose(b.filter.gyro_bias, b_imu, atol=1e-15)
    # The saved sigma, grown by the bias walk over the wall time between writing and loading (which a loaded machine
    # stretches: 35 ms already adds 5 %): bounded by the clock read before and after the load.
    walk = b.filter.params.bias_walk_rad_s_sqrt_s
    lo, hi = (math.sqrt(1e-8 + walk * walk * max(t - stamp, 0.0)) for t in (t0, t1))
    assert lo * (1 - 1e-12) <= b.filter.gyro_bias_sigma_rad_s <= hi * (1 + 1e-12)


def test_state_file_error_is_a_value_error():
    assert issubclass(StateFileError, ValueError)


# --- replay (real bags, the fast CDR path) ----------------------------------------------------------------------


def read_out(bag):
    from ccf_ros.offline.bagio import read_topic

    imu = [m for _, _, m in read_topic(bag, '/imu/data')]
    bias = [m for _, _, m in read_topic(bag, '/imu/gyro_bias')]
    return imu, bias


@pytest.fixture(scope='module')
def sim_bags(tmp_path_factory):
    """A short simulated recording, as is and as an IMU mounted on an arbitrary bracket measures it."""
    from ccf_ros.offline.simulate import SimData, write_bag

    d = generate(20.0, 100.0, seed=3)
    R = np.array(rotation_matrix('m', MOUNTS['arbitrary'])).reshape(3, 3)
    rotated = SimData(d.t_s, d.q_true, into_imu_frame(R, d.gyr), into_imu_frame(R, d.acc), into_imu_frame(R, d.mag),
                      d.bias, d.moving)
    root = tmp_path_factory.mktemp('frames')
    write_bag(d, root / 'plain')
    write_bag(rotated, root / 'mounted')
    return root


def test_replay_with_mount_rotation_and_output_frame_id(sim_bags):
    from ccf_ros.cli import main as ccf

    root = sim_bags
    assert ccf(['replay', str(root / 'plain'), '-o', str(root / 'out_plain')]) == 0
    mount = '[' + ', '.join(repr(v) for v in MOUNTS['arbitrary']) + ']'
    assert ccf(['replay', str(root / 'mounted'), '-o', str(root / 'out_mounted'), '--param',
                f'mount_rotation={mount}', '--param', 'output_frame_id=base_link']) == 0
    ref, ref_bias = read_out(root / 'out_plain')
    got, got_bias = read_out(root / 'out_mounted')
    assert len(ref) == len(got) > 1000
    q = lambda ms: np.array([(m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w) for m in ms])  # noqa: E731
    v = lambda ms, f: np.array([(getattr(m, f).x, getattr(m, f).y, getattr(m, f).z) for m in ms])  # noqa: E731
    assert np.max(np.abs(q(got) - q(ref))) < 1e-9
    assert np.max(np.abs(v(got, 'angular_velocity') - v(ref, 'angular_velocity'))) < 1e-12
    assert np.max(np.abs(v(got, 'linear_acceleration') - v(ref, 'linear_acceleration'))) < 1e-12
    assert np.max(np.abs(v(got_bias, 'vector') - v(ref_bias, 'vector'))) < 1e-9
    assert {m.header.frame_id for m in got} == {m.header.frame_id for m in got_bias} == {'base_link'}
    assert {m.header.frame_id for m in ref} == {'imu_link'}
    assert [m.header.stamp.nanosec for m in got] == [m.header.stamp.nanosec for m in ref]


def test_reframe_imu_matches_a_serialized_message_and_turns_the_covariances():
    from ccf_ros.messages.cdr import frame_id, read_imu, reframe_imu
    from ccf_ros.offline.bagio import typestore

    st = typestore()
    T = st.types
    V, Q = T['geometry_msgs/msg/Vector3'], T['geometry_msgs/msg/Quaternion']
    R = rotation_matrix('m', MOUNTS['arbitrary'])
    c1 = np.diag([1.0, 2.0, 3.0]).ravel()
    c2 = np.array([4.0, 0.5, 0.0, 0.5, 5.0, 0.1, 0.0, 0.1, 6.0])
    for old, new in [('', 'base_link'), ('imu_link', 'x'), ('abcdefg', 'abcdefgh')]:
        hdr = T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=5, nanosec=7), frame_id=old)
        m = T['sensor_msgs/msg/Imu'](header=hdr, orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
                                     orientation_covariance=np.zeros(9), angular_velocity=V(x=1.0, y=2.0, z=3.0),
                                     angular_velocity_covariance=c1, linear_acceleration=V(x=4.0, y=5.0, z=6.0),
                                     linear_acceleration_covariance=c2)
        raw = bytes(st.serialize_cdr(m, 'sensor_msgs/msg/Imu'))
        buf, _ = reframe_imu(raw, read_imu(raw)[1], new.encode(), R)
        hdr.frame_id = new
        m.angular_velocity_covariance = np.array(rotate_covariance(R, c1))
        m.linear_acceleration_covariance = np.array(rotate_covariance(R, c2))
        assert bytes(buf) == bytes(st.serialize_cdr(m, 'sensor_msgs/msg/Imu'))
        assert frame_id(buf) == new


def test_a_second_replay_starts_from_the_bias_file(sim_bags, tmp_path):
    """Replay writes bias_file at the end; a second replay loads it: its first published bias is the file's."""
    from ccf_ros.cli import main as ccf

    path = tmp_path / 'bias.json'
    assert ccf(['replay', str(sim_bags / 'plain'), '-o', str(tmp_path / 'a'), '--param', f'bias_file={path}']) == 0
    st = read_state(path)
    b, sigma = st.gyro_bias()
    assert st.frame_id == 'imu_link' and 0 < sigma < math.radians(0.5)
    _, bias_a = read_out(tmp_path / 'a')
    last = bias_a[-1].vector
    assert np.allclose(b, (last.x, last.y, last.z), atol=1e-15)
    assert np.linalg.norm(b) > math.radians(0.1)  # something learnt
    assert ccf(['replay', str(sim_bags / 'plain'), '-o', str(tmp_path / 'b'), '--param', f'bias_file={path}']) == 0
    _, bias_b = read_out(tmp_path / 'b')
    first = bias_b[0].vector
    # The first sample already has the learnt bias (one sample's update away from it at most).
    assert np.linalg.norm(np.subtract((first.x, first.y, first.z), b)) < 0.02 * np.linalg.norm(b)
    first_a = bias_a[0].vector
    assert np.linalg.norm((first_a.x, first_a.y, first_a.z)) < 0.02 * np.linalg.norm(b)  # run 1 started at 0
    assert read_state(path).stamp > st.stamp  # written again at the end


def test_every_executable_and_replay_know_the_new_parameters():
    from ccf_ros.node.compat import PROFILES, defaults_for
    from ccf_ros.settings import config_yaml

    names = {'mount_rotation', 'mag_rotation', 'output_frame_id', 'gyro_offset_rad_s', 'bias_file',
             'bias_save_interval_s'}
    for profile in PROFILES.values():
        assert names <= set(defaults_for(profile)), profile.executable
    assert all(f'    {n}: ' in config_yaml() for n in names)


def test_reframe_msg_turns_a_deserialized_message():
    """The message path of replay (ROS 1, big-endian bags): rosbags' numpy covariances, header."""
    from ccf_ros.messages.convert import reframe_msg
    from ccf_ros.offline.bagio import typestore

    T = typestore().types
    V, Q = T['geometry_msgs/msg/Vector3'], T['geometry_msgs/msg/Quaternion']
    hdr = T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=1, nanosec=2), frame_id='imu_link')
    c = np.array([1.0, 0, 0, 0, 2.0, 0, 0, 0, 3.0])
    m = T['sensor_msgs/msg/Imu'](header=hdr, orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=c.copy(),
                                 angular_velocity=V(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=c.copy(),
                                 linear_acceleration=V(x=0.0, y=0.0, z=0.0),
                                 linear_acceleration_covariance=np.array([-1.0] + [0.0] * 8))
    R = rotation_matrix('m', [0, 0, math.pi / 2])
    reframe_msg(m, 'base_link', R)
    assert m.header.frame_id == 'base_link'
    assert np.allclose(m.angular_velocity_covariance, [2.0, 0, 0, 0, 1.0, 0, 0, 0, 3.0], atol=1e-12)
    assert list(m.linear_acceleration_covariance) == [-1.0] + [0.0] * 8  # unknown stays unknown
    assert list(m.orientation_covariance) == list(c)  # the engine's, written by fill_imu: not touched here


def test_replay_with_a_foreign_bias_file_warns_once_and_runs(sim_bags, tmp_path, capsys):
    from ccf_ros.cli import main as ccf

    path = tmp_path / 'bias.json'
    other = State('another_imu', time.time())
    other.set_gyro_bias((0.5, 0.5, 0.5), 0.001)
    write_state(path, other)
    assert ccf(['replay', str(sim_bags / 'plain'), '-o', str(tmp_path / 'out'), '--param', f'bias_file={path}']) == 0
    err = capsys.readouterr().err
    assert err.count('bias_file ignored') == 1 and "written for frame_id 'another_imu'" in err
    _, bias = read_out(tmp_path / 'out')
    assert np.linalg.norm((bias[0].vector.x, bias[0].vector.y, bias[0].vector.z)) < 0.01  # not the file's 0.5
    assert read_state(path).frame_id == 'imu_link'  # replaced by this IMU's at the end


def test_bias_file_heading_keeps_the_6d_heading_across_a_restart(tmp_path):
    """bias_file_heading: a 6-D filter restarted (the robot did not turn meanwhile) goes on from its last heading
    instead of 0; without the option the heading starts again from 0, as before."""
    from ccf_ros.core.quaternion import rpy_of

    sim = generate(40.0, 100.0, seed=4)
    path = tmp_path / 'state.json'
    half = len(sim.t_s) // 2
    first = engine(use_mag=False, bias_file=str(path), bias_file_heading=True)
    first.set_sensor_frame('imu_link')
    run(first, sim.t_s[:half], sim.gyr[:half], sim.acc[:half], sim.mag[:half])
    yaw_before = first.heading_state()
    first.save_state(path)
    assert abs(read_state(path).sections['heading']['yaw_rad'] - yaw_before) < 1e-12
    yaws = {}
    for keep in (True, False):
        second = engine(use_mag=False, bias_file=str(path), bias_file_heading=keep)
        second.set_sensor_frame('imu_link')
        assert second.on_imu(sim.t_s[half], tuple(sim.gyr[half]), tuple(sim.acc[half])) is not None
        yaws[keep] = rpy_of(second.filter.quaternion)[2]
    assert abs(math.remainder(yaws[True] - yaw_before, 2 * math.pi)) < math.radians(0.5), (yaws, yaw_before)
    # Without the option the restart's heading is the level start's, unrelated to the one before.
    assert abs(math.remainder(yaws[False] - yaw_before, 2 * math.pi)) > math.radians(2.0), (yaws, yaw_before)

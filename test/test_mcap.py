"""The own MCAP reader yields rosbags' messages in rosbags' order; the fast write path writes rosbags' bytes."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from ccf_ros.offline.bagio import open_bag, open_writer, read_messages, typestore
from ccf_ros.offline.mcap import McapFile, fast_messages, fast_writer


def _both(bag: Path) -> tuple[list, list]:
    with open_bag(bag) as reader:
        conns = list(reader.connections)
        fast = fast_messages(reader, conns)
        assert fast is not None
        mine = [(c.topic, t, bytes(raw)) for c, t, raw in fast]
        theirs = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages(connections=conns)]
    return mine, theirs


def test_reader_matches_rosbags_on_a_simulated_bag(sim_bag):
    mine, theirs = _both(sim_bag)
    assert len(mine) == 4 * 17160 and mine == theirs


def test_reader_matches_rosbags_on_broad():
    from conftest import TRIAL, need_shared

    mine, theirs = _both(need_shared(TRIAL))
    assert mine == theirs


def test_overlapping_chunks_and_equal_stamps_merge_as_rosbags_does(tmp_path):
    """Messages written out of time order (chunks overlap in time), many with equal stamps on two topics."""
    ts = typestore()
    rng = random.Random(3)
    bag = tmp_path / 'shuffled'
    with open_writer(bag) as w:
        a = w.add_connection('/a', 'std_msgs/msg/String', typestore=ts)
        b = w.add_connection('/b', 'std_msgs/msg/String', typestore=ts)
        String = ts.types['std_msgs/msg/String']
        for k in range(30_000):
            t = rng.randrange(0, 2_000) * 1_000_000
            payload = ts.serialize_cdr(String(data=f'{k:08d}' * 8), 'std_msgs/msg/String')
            w.write(a if k % 3 else b, t, payload)
    assert len(McapFile(next(bag.glob('*.mcap')))._chunks) > 1
    mine, theirs = _both(bag)
    assert len(mine) == 30_000 and mine == theirs


def test_read_messages_fast_gives_rosbags_messages(sim_bag):
    with open_bag(sim_bag) as reader:
        conns = [c for c in reader.connections if c.topic == '/imu/data_raw']
        fast = list(read_messages(reader, sim_bag, conns, fast=True))
        slow = list(read_messages(reader, sim_bag, conns))
    assert [(c.id, t, r) for c, t, r in fast] == [(c.id, t, r) for c, t, r in slow]


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_fast_writer_writes_rosbags_bytes(sim_bag, tmp_path, storage):
    def copy(dst: Path, fast: bool) -> bytes:
        with open_bag(sim_bag) as reader, open_writer(dst, storage) as w:
            conns = {c.id: w.add_connection(c.topic, c.msgtype, typestore=typestore()) for c in reader.connections}
            write, flush = fast_writer(w.writer) if fast else (w.writer.write, lambda: None)
            for k, (c, t, raw) in enumerate(reader.messages()):
                write(conns[c.id], t, raw)
                if k % 5000 == 4999:  # flushed in blocks, as replay does
                    flush()
            flush()
        return b''.join(p.read_bytes() for p in sorted(dst.iterdir()))

    (tmp_path / 'x').mkdir()
    (tmp_path / 'y').mkdir()
    assert copy(tmp_path / 'x' / 'bag', True) == copy(tmp_path / 'y' / 'bag', False)


def test_scan_without_message_index_gives_the_same_messages(sim_bag, monkeypatch):
    """Chunks are read through their message index; without one, by scanning every record: same result."""
    import dataclasses

    import ccf_ros.offline.mcap as mcap

    calls = {'indexed': 0}
    real = mcap.McapFile._indexed

    def counting(self, *a):
        calls['indexed'] += 1
        return real(self, *a)

    monkeypatch.setattr(mcap.McapFile, '_indexed', counting)
    indexed, _ = _both(sim_bag)
    assert calls['indexed'] > 0
    real_init = mcap.McapFile.__init__

    def no_index(self, path):
        real_init(self, path)
        self._chunks = [dataclasses.replace(c, index={}) for c in self._chunks]

    monkeypatch.setattr(mcap.McapFile, '__init__', no_index)
    n = calls['indexed']
    scanned, theirs = _both(sim_bag)
    assert calls['indexed'] == n and scanned == indexed == theirs


def test_topics_are_detected_by_type(sim_bag, tmp_path):
    """One Imu topic (whatever its name) is the IMU; of several, /imu/data_raw, else an error naming them."""
    from conftest import copy_bag

    from ccf_ros.errors import BagError
    from ccf_ros.offline.bagio import detect_topics

    with open_bag(sim_bag) as reader:
        assert detect_topics(reader, sim_bag, None, None) == ('/imu/data_raw', '/imu/mag', False)
        assert detect_topics(reader, sim_bag, None, None, no_mag=True) == ('/imu/data_raw', None, False)
        assert detect_topics(reader, sim_bag, None, '/m') == ('/imu/data_raw', '/m', True)
    two = copy_bag(sim_bag, tmp_path / 'two', stop_s=1.0)
    from rosbags.rosbag2 import Writer

    odd = tmp_path / 'odd'
    with open_bag(two) as reader, Writer(odd, version=9) as w:
        ts = typestore()
        conns = {c.id: w.add_connection('/a/imu' if c.topic == '/imu/data_raw' else c.topic, c.msgtype, typestore=ts)
                 for c in reader.connections}
        extra = w.add_connection('/b/imu', 'sensor_msgs/msg/Imu', typestore=ts)
        for c, t, raw in reader.messages():
            w.write(conns[c.id], t, raw)
            if c.topic == '/imu/data_raw':
                w.write(extra, t, raw)
    with open_bag(odd) as reader, pytest.raises(BagError, match=r'several sensor_msgs/Imu topics \(/a/imu, /b/imu\)'):
        detect_topics(reader, odd, None, None)


def test_overlapping_chunks_stream_one_neighbour_at_a_time(tmp_path):
    """Stamps jitter by +-5 ms around a steady clock: each chunk overlaps its neighbours in time only. The merge
    gives rosbags' order while holding at most two chunks decoded, not all of them."""
    ts = typestore()
    rng = random.Random(5)
    bag = tmp_path / 'jitter'
    String = ts.types['std_msgs/msg/String']
    with open_writer(bag) as w:
        a = w.add_connection('/a', 'std_msgs/msg/String', typestore=ts)
        for k in range(16_000):
            payload = ts.serialize_cdr(String(data=f'{k:08d}' * 120), 'std_msgs/msg/String')
            w.write(a, 10**9 + k * 1_000_000 + rng.randrange(-5_000_000, 5_000_000), payload)
    mcap = McapFile(next(bag.glob('*.mcap')))
    assert len(mcap._chunks) >= 10
    with open_bag(bag) as reader:
        conns = list(reader.connections)
        theirs = [(t, bytes(raw)) for _, t, raw in reader.messages(connections=conns)]
    (cid,) = mcap.channels
    mine = [(t, bytes(raw)) for _, t, raw in mcap.messages({cid: conns[0]})]
    assert len(mine) == 16_000 and mine == theirs
    assert 1 <= mcap.max_open_chunks <= 2, mcap.max_open_chunks


def _frames_varied(src: Path, dst: Path, stop_s: float) -> Path:
    """The first ``stop_s`` of ``src`` with IMU frame_ids of three lengths: the records differ in length and header."""
    from test_offline import rewrite_bag

    def change(k, msgtype, raw, deserialize, ts):
        if msgtype != 'sensor_msgs/msg/Imu':
            return raw
        msg = deserialize(raw, msgtype)
        msg.header.frame_id = ('imu', 'imu_link', 'a_long_imu_frame')[k % 3]
        return ts.serialize_cdr(msg, msgtype)

    return rewrite_bag(src, dst, stop_s, change)


@pytest.mark.parametrize('params', [[], ['bias_corrected_rate=true', 'remove_gravity_vector=true']])
@pytest.mark.parametrize('varied', [False, True])
def test_bulk_replay_writes_the_message_paths_bytes(sim_bag, tmp_path, monkeypatch, params, varied):
    """replay's bulk path (a chunk decoded and its answers framed with numpy) writes the bag that message by
    message writes: same messages, same bytes, same chunking of the file."""
    from ccf_ros.cli import main
    from ccf_ros.offline import replay as replay_mod

    bag = _frames_varied(sim_bag, tmp_path / 'varied', 20.0) if varied else sim_bag
    args = [a for p in params for a in ('--param', p)]
    assert main(['replay', str(bag), '-o', str(tmp_path / 'bulk'), *args]) == 0
    taken = []
    monkeypatch.setattr(replay_mod._Replayer, '_bulk', lambda self: taken.append(1))
    assert main(['replay', str(bag), '-o', str(tmp_path / 'each'), *args]) == 0
    assert taken == [1]
    bulk, one = (next((tmp_path / n).glob('*.mcap')).read_bytes() for n in ('bulk', 'each'))
    # (the file's metadata names the bag)
    assert len(bulk) == len(one) and bulk.replace(b'bulk.mcap', b'each.mcap') == one


def test_record_writer_writes_rosbags_bytes_across_several_chunks_per_call(tmp_path):
    """Framed records appended in calls of up to 60 records of 1 byte to 300 kB (several chunk closes in one call,
    two channels interleaved at random) give rosbags' file, byte for byte."""
    import struct

    from ccf_ros.offline.mcap import record_writer

    rng = random.Random(9)
    msgs = [(rng.randrange(2), 10**9 + k * 1000, bytes([k % 251]) * rng.choice((1, 77, 5_000, 300_000)))
            for k in range(400)]
    calls = []
    k = 0
    while k < len(msgs):
        n = rng.randrange(1, 60)
        calls.append(msgs[k:k + n])
        k += n

    def written(dst: Path, bulk: bool) -> bytes:
        with open_writer(dst) as w:
            conns = [w.add_connection(t, 'std_msgs/msg/String', typestore=typestore()) for t in ('/a', '/b')]
            write_records = record_writer(w.writer)
            assert write_records is not None
            for call in calls:
                if bulk:
                    blob = b''.join(struct.pack('<BQHIQQ', 5, 22 + len(d), conns[c].id, 0, t, t) + d for c, t, d in call)
                    write_records(blob, [conns[c].id for c, _, _ in call], [t for _, t, _ in call],
                                  [31 + len(d) for _, _, d in call])
                else:
                    for c, t, d in call:
                        w.writer.write(conns[c], t, d)
        return next(dst.glob('*.mcap')).read_bytes()

    (tmp_path / 'x').mkdir()
    (tmp_path / 'y').mkdir()
    mine, theirs = written(tmp_path / 'x' / 'bag', True), written(tmp_path / 'y' / 'bag', False)
    assert len(McapFile(next((tmp_path / 'y' / 'bag').glob('*.mcap')))._chunks) >= 20
    assert mine == theirs

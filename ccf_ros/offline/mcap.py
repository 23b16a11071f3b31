"""A streaming reader of indexed MCAP files (rosbag2's default storage) and a fast write path for rosbags' MCAP
writer: the read and write sides of :mod:`ccf_ros.offline.replay` and ``ccf fleet`` at a few µs per message less.

Reading: the summary (schemas, channels, chunk indexes) is parsed once; chunks are then read, decompressed (zstd or
lz4, with the libraries rosbags depends on) and split into message records one at a time, so memory holds one
chunk, whatever the bag's length. Messages come in rosbags' order (log time; equal times in file order), so a
replay through this reader sees exactly what it sees through rosbags. Anything this reader does not handle
(unindexed files, message-compressed bags, several storage files) is left to rosbags: :func:`fast_messages` says
None.

Writing: :func:`fast_writer` returns a ``write(connection, t_ns, data)`` that queues messages and a ``flush()`` that
appends them to rosbags' pending MCAP chunk with the same bytes and counters as rosbags' ``Writer.write`` (the file
is identical, bit for bit), without its per-message checks and ``BytesIO`` records. It relies on rosbags' ``McapWriter`` internals (rosbags is
pinned to < 0.12 in setup.py); for any other writer it returns rosbags' own ``write``.
"""

from __future__ import annotations

import heapq
import struct
import sys
import zlib
from array import array
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from io import BytesIO
from itertools import chain, pairwise
from operator import itemgetter
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection
    from rosbags.rosbag2 import Writer

__all__ = ['McapError', 'McapFile', 'fast_batches', 'fast_messages', 'fast_writer', 'record_writer']

MAGIC = b'\x89MCAP0\r\n'
_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')
_FOOTER = struct.Struct('<BQQQI')  # opcode 0x02, record length, summary start, summary offset start, crc
_MESSAGE = struct.Struct('<BQHIQQ')  # opcode 0x05, record length, channel, sequence, log time, publish time
_CHUNK_INDEX = struct.Struct('<QQQQ')  # message start time, end time, chunk start offset, chunk length
_CHUNK_HEAD = struct.Struct('<QQQI')  # a chunk's start time, end time, uncompressed size, crc
_RECORD = struct.Struct('<BQ')  # opcode, record length
_INDEX_HEAD = struct.Struct('<HI')  # a message index's channel id, byte length of its (time, offset) pairs
_CID_OFFSET = struct.Struct('<HQ')
#: A chunk's pending messages beyond this many bytes are written out (rosbags' McapWriter rule).
_CHUNK_BYTES = 2**20


class McapError(Exception):
    """The MCAP file is malformed or truncated."""


@dataclass(frozen=True)
class _Chunk:
    start_ns: int
    end_ns: int
    offset: int  # of the chunk record in the file
    channels: frozenset[int]  # channel ids with messages in the chunk (from its message index offsets)
    index: dict[int, int]  # channel id -> file offset of its message index record
    compression: str
    compressed_size: int
    uncompressed_size: int


@dataclass(frozen=True)
class _Columns:
    """The wanted messages of one chunk as arrays: log times (ns), owner (which wanted channel, by position),
    and where each message's data starts and ends in ``buf`` (the chunk's decompressed records); (N,) each."""

    buf: bytes
    t_ns: Any
    owner: Any
    start: Any
    end: Any

    @classmethod
    def empty(cls, buf: bytes) -> _Columns:
        import numpy as np

        z = np.zeros(0, dtype=np.int64)
        return cls(buf, z, z, z, z)


def _string(buf: bytes | memoryview, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    return bytes(buf[pos + 4:pos + 4 + n]).decode(), pos + 4 + n


def _decompress(data: bytes, compression: str, size: int) -> bytes:
    if compression == '':
        out = data
    elif compression == 'zstd':
        try:
            from compression import zstd  # type: ignore[import-not-found,unused-ignore]  # Python >= 3.14
        except ImportError:
            from backports import zstd  # type: ignore[import-not-found,no-redef,unused-ignore]  # rosbags' dependency
        out = zstd.decompress(data)
    elif compression == 'lz4':
        from lz4.frame import decompress as lz4_decompress

        out = lz4_decompress(data)
    else:
        raise McapError(f'unsupported chunk compression {compression!r}')
    if len(out) != size:
        raise McapError(f'chunk size mismatch: expected {size} bytes, got {len(out)}')
    return out


class McapFile:
    """An indexed MCAP file: its channels (id -> (topic, schema name)) and chunks, read from the summary."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.channels: dict[int, tuple[str, str]] = {}
        self._chunks: list[_Chunk] = []
        #: the most chunks decoded at once by the latest :meth:`messages` (memory holds that many)
        self.max_open_chunks = 0
        with self.path.open('rb') as f:
            if f.read(8) != MAGIC:
                raise McapError(f'{self.path}: not an MCAP file')
            f.seek(-(_FOOTER.size + 8), 2)
            tail = f.read()
            if tail[-8:] != MAGIC:
                raise McapError(f'{self.path}: truncated (no end magic)')
            op, _, summary_start, _, _ = _FOOTER.unpack_from(tail)
            if op != 0x02 or not summary_start:
                raise McapError(f'{self.path}: no summary (unindexed)')
            f.seek(summary_start)
            summary = f.read()
        self._read_summary(summary)
        if not self._chunks:
            raise McapError(f'{self.path}: no chunk index')

    def _read_summary(self, buf: bytes) -> None:
        schemas: dict[int, str] = {}
        pos, end = 0, len(buf)
        while pos + 9 <= end:
            op = buf[pos]
            (n,) = _U64.unpack_from(buf, pos + 1)
            rec = pos + 9
            if op == 0x03:  # schema
                (sid,) = _U16.unpack_from(buf, rec)
                schemas[sid] = _string(buf, rec + 2)[0]
            elif op == 0x04:  # channel
                cid, sid = struct.unpack_from('<HH', buf, rec)
                topic, _ = _string(buf, rec + 4)
                self.channels[cid] = (topic, schemas.get(sid, ''))
            elif op == 0x08:  # chunk index
                start, stop, offset, _ = _CHUNK_INDEX.unpack_from(buf, rec)
                (nmap,) = _U32.unpack_from(buf, rec + 32)
                index = dict(struct.iter_unpack('<HQ', buf[rec + 36:rec + 36 + nmap]))
                ids = frozenset(index)
                p = rec + 36 + nmap + 8  # message index length
                compression, p = _string(buf, p)
                csize, usize = struct.unpack_from('<QQ', buf, p)
                self._chunks.append(_Chunk(start, stop, offset, ids, index, compression, csize, usize))
            elif op == 0x02:  # footer
                break
            pos = rec + n

    def _chunk_data(self, f: Any, chunk: _Chunk) -> bytes:
        """The decompressed records of ``chunk``, checked against its size and CRC."""
        f.seek(chunk.offset)
        head = f.read(9 + 28)  # opcode, length, start time, end time, uncompressed size, crc
        if len(head) < 37 or head[0] != 0x06:
            raise McapError(f'{self.path}: no chunk at offset {chunk.offset}')
        (clen,) = _U32.unpack(f.read(4))
        compression = f.read(clen).decode()
        (csize,) = _U64.unpack(f.read(8))
        data = f.read(csize)
        if len(data) != csize:
            raise McapError(f'{self.path}: truncated chunk at offset {chunk.offset}')
        (crc,) = _U32.unpack_from(head, 9 + 24)
        buf = _decompress(data, compression, chunk.uncompressed_size)
        if crc and zlib.crc32(buf) != crc:
            raise McapError(f'{self.path}: chunk checksum mismatch at offset {chunk.offset}')
        return buf

    def _index_columns(self, f: Any, chunk: _Chunk, wanted: dict[int, Any], buf: bytes) -> _Columns | None:
        """The wanted messages of a chunk located through its message index records (no scan of the other
        records), sorted by (time, offset) as rosbags sorts them; None if the index is absent or does not match."""
        import numpy as np

        times, offsets, owners = [], [], []
        for k, cid in enumerate(wanted):
            pos = chunk.index.get(cid)
            if pos is None:
                continue
            f.seek(pos)
            head = f.read(15)
            if len(head) < 15:
                return None
            op, _, ch, n = struct.unpack('<BQHI', head)
            raw = f.read(n)
            if op != 0x07 or ch != cid or len(raw) != n or n % 16:
                return None
            pairs = np.frombuffer(raw, dtype='<u8').reshape(-1, 2)
            times.append(pairs[:, 0])
            offsets.append(pairs[:, 1])
            owners.append(np.full(len(pairs), k, dtype=np.int64))
        if not times:
            return _Columns.empty(buf)
        t = np.concatenate(times)
        off = np.concatenate(offsets)
        if len(off) and int(off.max()) + 31 > len(buf):
            return None
        order = np.lexsort((off, t))
        t, off = t[order].astype(np.int64), off[order].astype(np.int64)
        u8 = np.frombuffer(buf, dtype=np.uint8)

        def field(at: int, size: int, dtype: str) -> Any:
            return u8[(off + at)[:, None] + np.arange(size)].copy().view(dtype).ravel()

        lengths = field(1, 8, '<u8').astype(np.int64)
        if (u8[off] != 0x05).any() or (field(15, 8, '<u8') != t).any() or (lengths < 22).any():
            return None
        ends = off + 9 + lengths
        if len(ends) and int(ends.max()) > len(buf):
            return None
        return _Columns(buf, t, np.concatenate(owners)[order], off + 31, ends)

    def _indexed(self, f: Any, chunk: _Chunk, wanted: dict[int, Any], buf: bytes) -> list[tuple[int, Any, bytes]] | None:
        """:meth:`_index_columns` as ``(log_time_ns, wanted[channel], data)`` records."""
        cols = self._index_columns(f, chunk, wanted, buf)
        if cols is None:
            return None
        conns = list(wanted.values())
        return [(ti, conns[k], buf[s:e]) for ti, k, s, e in zip(cols.t_ns.tolist(), cols.owner.tolist(),
                                                                 cols.start.tolist(), cols.end.tolist(), strict=True)]

    def batches(self, wanted: dict[int, Any]) -> Iterator[_Columns] | None:
        """The messages of :meth:`messages` as one :class:`_Columns` per chunk (``owner``: the index of the
        message's channel in ``wanted``), or None where the chunks overlap in time (then only :meth:`messages`
        merges them)."""
        chunks = [c for c in self._chunks if c.channels & wanted.keys() or not c.channels]
        chunks.sort(key=lambda c: c.offset)
        if not all(a.end_ns <= b.start_ns for a, b in pairwise(chunks)):
            return None
        return self._batches(chunks, wanted)

    def _batches(self, chunks: list[_Chunk], wanted: dict[int, Any]) -> Iterator[_Columns]:
        import numpy as np

        index = {cid: k for k, cid in enumerate(wanted)}
        with self.path.open('rb') as f:
            for c in chunks:
                buf = self._chunk_data(f, c)
                cols = self._index_columns(f, c, wanted, buf) if c.index else None
                if cols is None:  # no usable index: scan the records
                    recs = self._scan(c, buf, {cid: (cid, k) for cid, k in index.items()})
                    cols = _Columns(buf, np.array([r[0] for r in recs], dtype=np.int64),
                                    np.array([r[1][1] for r in recs], dtype=np.int64),
                                    np.array([r[2][0] for r in recs], dtype=np.int64),
                                    np.array([r[2][1] for r in recs], dtype=np.int64))
                yield cols

    def _records(self, f: Any, chunk: _Chunk, wanted: dict[int, Any]) -> list[tuple[int, Any, bytes]]:
        """The wanted messages of one chunk as ``(log_time_ns, wanted[channel], data)``, sorted by time (stable)."""
        buf = self._chunk_data(f, chunk)
        if chunk.index:
            found = self._indexed(f, chunk, wanted, buf)
            if found is not None:
                return found
        return [(t, conn, buf[s:e]) for t, conn, (s, e) in self._scan(chunk, buf, wanted)]

    def _scan(self, chunk: _Chunk, buf: bytes, wanted: dict[int, Any]) -> list[tuple[int, Any, tuple[int, int]]]:
        """The wanted messages of a chunk's records, found by reading every record header: ``(log_time_ns,
        wanted[channel], (data start, data end))``, sorted by time (stable)."""
        out: list[tuple[int, Any, tuple[int, int]]] = []
        add = out.append
        unpack, u64 = _MESSAGE.unpack_from, _U64.unpack_from
        pos, end = 0, len(buf)
        try:
            while pos < end:
                if buf[pos] == 0x05:
                    _, n, cid, _, t, _ = unpack(buf, pos)
                    conn = wanted.get(cid)
                    if conn is not None:
                        add((t, conn, (pos + 31, pos + 9 + n)))
                else:
                    (n,) = u64(buf, pos + 1)
                pos += 9 + n
        except struct.error as err:
            raise McapError(f'{self.path}: truncated record in chunk at offset {chunk.offset}') from err
        if pos != end:
            raise McapError(f'{self.path}: record overruns its chunk at offset {chunk.offset}')
        out.sort(key=itemgetter(0))
        return out

    def messages(self, wanted: dict[int, Any]) -> Iterator[tuple[Any, int, bytes]]:
        """``(wanted[channel], log_time_ns, data)`` of the messages of the ``wanted`` channels, in rosbags' order.

        Chunks that follow each other in time (the usual case) are read one after the other; overlapping chunks are
        merged by (time, chunk offset), as rosbags merges them, streaming: a chunk is decoded only once the merge
        reaches its start time, so memory holds the chunks that overlap the current time, not the whole file.
        """
        chunks = [c for c in self._chunks if c.channels & wanted.keys() or not c.channels]
        chunks.sort(key=lambda c: c.offset)
        with self.path.open('rb') as f:
            if all(a.end_ns <= b.start_ns for a, b in pairwise(chunks)):
                self.max_open_chunks = min(len(chunks), 1)
                for c in chunks:
                    for t, conn, data in self._records(f, c, wanted):
                        yield conn, t, data
                return
            yield from self._merged(f, chunks, wanted)

    def _merged(self, f: Any, chunks: list[_Chunk], wanted: dict[int, Any]) -> Iterator[tuple[Any, int, bytes]]:
        """The k-way merge of :meth:`messages` for chunks that overlap in time.

        A chunk holds no message before its start time, so before the earliest pending message (time ``t``) is
        given out, every chunk starting at or before ``t`` must be open; the later ones wait. The heap holds one
        pending message per open chunk, keyed (time, chunk offset, index in chunk)."""
        todo = sorted(chunks, key=lambda c: (c.start_ns, c.offset))
        heap: list[tuple[int, int, int, Any, bytes, Iterator[tuple[int, Any, bytes]]]] = []
        nxt, n_open = 0, 0
        self.max_open_chunks = 0

        def open_chunk(c: _Chunk) -> None:
            nonlocal n_open
            it = iter(self._records(f, c, wanted))
            first = next(it, None)
            if first is not None:
                n_open += 1
                self.max_open_chunks = max(self.max_open_chunks, n_open)
                heapq.heappush(heap, (first[0], c.offset, 0, first[1], first[2], it))

        while heap or nxt < len(todo):
            while nxt < len(todo) and (not heap or todo[nxt].start_ns <= heap[0][0]):
                open_chunk(todo[nxt])
                nxt += 1
            if not heap:
                continue
            t, off, i, conn, data, it = heap[0]
            yield conn, t, data
            rec = next(it, None)
            if rec is None:
                heapq.heappop(heap)
                n_open -= 1
            else:
                heapq.heapreplace(heap, (rec[0], off, i + 1, rec[1], rec[2], it))


def _mcap_path(reader: AnyReader) -> Path | None:
    """The one MCAP storage file of a rosbag2 reader that stores messages uncompressed (else None)."""
    if not reader.is2 or len(reader.readers) != 1:
        return None
    bag: Any = reader.readers[0]
    storage = getattr(bag, 'storage', None)
    for owner in (bag, storage):
        if getattr(getattr(owner, 'metadata', None), 'compression_mode', None) not in (None, '', 'none'):
            return None  # messages or files compressed one by one: rosbags decompresses them
    storages = getattr(storage, 'storages', None)
    candidates = storages if storages is not None else [storage]
    if len(candidates) != 1:
        return None
    path = getattr(candidates[0], 'path', None)
    return Path(path) if path is not None and str(path).endswith('.mcap') else None


def _wanted(reader: AnyReader, connections: list[Connection]) -> tuple[McapFile, dict[int, Any]] | None:
    """The bag's :class:`McapFile` and its channel id for each of ``connections`` (in their order), or None where
    rosbags must read them (see :func:`fast_messages`)."""
    path = _mcap_path(reader)
    if path is None:
        return None
    try:
        mcap = McapFile(path)
    except McapError:
        return None  # unindexed or odd: rosbags reads it (or says what is wrong)
    by_key: dict[tuple[str, str], list[int]] = {}
    for cid, key in mcap.channels.items():
        by_key.setdefault(key, []).append(cid)
    wanted: dict[int, Any] = {}
    for conn in connections:
        ids = by_key.get((conn.topic, conn.msgtype), [])
        if len(ids) != 1 or sum(1 for c in reader.connections if (c.topic, c.msgtype) == (conn.topic, conn.msgtype)) != 1:
            return None
        wanted[ids[0]] = conn
    return mcap, wanted


def fast_messages(
    reader: AnyReader, connections: list[Connection]
) -> Iterator[tuple[Connection, int, bytes]] | None:
    """The messages of ``connections`` through :class:`McapFile` (same order and bytes as rosbags), or None where
    rosbags must read them (not a single uncompressed-message MCAP file, unindexed, or channels that do not map
    one-to-one to connections). Raises :class:`McapError` on a malformed file."""
    found = _wanted(reader, connections)
    return None if found is None else found[0].messages(found[1])


def fast_batches(reader: AnyReader, connections: list[Connection]) -> Iterator[_Columns] | None:
    """The messages of :func:`fast_messages` as one :class:`_Columns` per chunk (``owner``: the index in
    ``connections``), or None where they cannot come so (see :func:`fast_messages`; chunks that overlap in time)."""
    found = _wanted(reader, connections)
    return None if found is None else found[0].batches(found[1])


def fast_writer(writer: Writer) -> tuple[Callable[[Connection, int, Any], None], Callable[[], None]]:
    """``(write, flush)`` for rosbags' ``writer``: ``write(connection, t_ns, data)`` queues a message, ``flush()``
    appends the queued ones to rosbags' pending MCAP chunk with the same bytes and counters as ``writer.write``
    (MCAP storage, no compression; the file is identical, bit for bit), in one tight loop. For any other storage or
    compression: ``writer.write`` itself and a ``flush`` that does nothing. Flush before the writer is closed."""
    from rosbags.rosbag2.enums import CompressionMode
    from rosbags.rosbag2.storage_mcap import McapWriter

    storage: Any = getattr(writer, 'storage', None)
    if type(storage) is not McapWriter or writer.compression_mode != CompressionMode.NONE:
        return writer.write, lambda: None
    counts, stats = writer.counts, storage.channel_stats
    header = struct.Struct('<BQHIQQ').pack
    pending: list[tuple[int, int, Any]] = []
    add = pending.append

    def write(connection: Connection, t_ns: int, data: Any) -> None:
        add((connection.id, t_ns, data))

    def flush() -> None:
        # The steps of rosbags' Writer.write and McapWriter.write, message by message, on their state.
        if not pending:
            return
        times = [p[1] for p in pending]
        t_lo, t_hi = min(times), max(times)
        writer.min_timestamp = min(t_lo, writer.min_timestamp)
        writer.max_timestamp = max(t_hi, writer.max_timestamp)
        storage.message_start_time = min(t_lo, storage.message_start_time)
        storage.message_end_time = max(t_hi, storage.message_end_time)
        chunk = storage.chunk
        bio, msgs, pos = chunk.bio, chunk.msgs, chunk.bio.tell()
        lo, hi = chunk.message_start_time, chunk.message_end_time
        parts: list[Any] = []
        part = parts.append
        for cid, t, data in pending:
            counts[cid] += 1
            stats[cid] += 1
            if t < lo:
                lo = t
            if t > hi:
                hi = t
            msgs[cid].append((t, pos))
            n = len(data)
            part(header(0x05, 22 + n, cid, 0, t, t))
            part(data)
            pos += 31 + n
            if pos > _CHUNK_BYTES:  # rosbags closes the chunk after the message that passes 1 MiB
                bio.write(b''.join(parts))
                parts.clear()
                chunk.message_start_time, chunk.message_end_time = lo, hi
                _close_chunk(storage)
                chunk = storage.chunk
                bio, msgs, pos = chunk.bio, chunk.msgs, 0
                lo, hi = chunk.message_start_time, chunk.message_end_time
        bio.write(b''.join(parts))
        chunk.message_start_time, chunk.message_end_time = lo, hi
        pending.clear()

    return write, flush


def _close_chunk(storage: Any) -> None:
    """rosbags' ``McapWriter.close_chunk`` (the same bytes), with the message index packed in one call per channel
    instead of two writes per message."""
    chunk = storage.chunk
    data = chunk.bio.getvalue()
    compressed = storage.compressor(data)
    comp = storage.compression.encode()
    rec = b''.join((_CHUNK_HEAD.pack(chunk.message_start_time, chunk.message_end_time, len(data), 0),
                    _U32.pack(len(comp)), comp, _U64.pack(len(compressed)), compressed))
    bio = storage.bio
    chunk_start = bio.tell()
    bio.write(_RECORD.pack(0x06, len(rec)))
    bio.write(rec)
    chunk_end = bio.tell()
    offsets: list[tuple[int, int]] = []
    for cid, msgs in chunk.msgs.items():
        offsets.append((cid, bio.tell()))
        pairs = array('Q', chain.from_iterable(msgs))
        if sys.byteorder == 'big':
            pairs.byteswap()
        index = pairs.tobytes()
        bio.write(_RECORD.pack(0x07, 6 + len(index)))
        bio.write(_INDEX_HEAD.pack(cid, len(index)))
        bio.write(index)
    summary = BytesIO()
    summary.write(_CHUNK_INDEX.pack(chunk.message_start_time, chunk.message_end_time, chunk_start,
                                    chunk_end - chunk_start))
    summary.write(_U32.pack(len(offsets) * 10))
    for cid, offset in offsets:
        summary.write(_CID_OFFSET.pack(cid, offset))
    summary.write(_U64.pack(bio.tell() - chunk_end))
    summary.write(_U32.pack(len(comp)))
    summary.write(comp)
    summary.write(_U64.pack(len(compressed)))
    summary.write(_U64.pack(len(data)))
    storage.chunks.append(summary)
    storage.chunk = type(chunk)(2**63 - 1, 0, BytesIO(), defaultdict(list))


#: Writes framed MCAP message records: ``(records, channel ids, log times ns, record sizes)``.
RecordWriter = Callable[[Any, Any, Any, Any], None]


def record_writer(writer: Writer) -> RecordWriter | None:
    """For rosbags' MCAP writer without compression: a ``write_records(records, cids, times, sizes)`` that appends
    message records already framed (opcode 0x05, length, channel, sequence 0, log and publish time, data: ``sizes``
    bytes each, concatenated in ``records``) to the pending chunk, with the counters, message index and chunk
    boundaries of rosbags' ``Writer.write`` (the file is identical, bit for bit). None for any other writer.

    Do not mix it with queued :func:`fast_writer` writes that are not flushed."""
    import numpy as np
    from rosbags.rosbag2.enums import CompressionMode
    from rosbags.rosbag2.storage_mcap import McapWriter

    storage: Any = getattr(writer, 'storage', None)
    if type(storage) is not McapWriter or writer.compression_mode != CompressionMode.NONE:
        return None
    counts, stats = writer.counts, storage.channel_stats

    def write_records(records: Any, cids: Any, times: Any, sizes: Any) -> None:
        cids = np.asarray(cids, dtype=np.int64)
        times = np.asarray(times, dtype=np.int64)
        n = len(cids)
        if not n:
            return
        t_lo, t_hi = int(times.min()), int(times.max())
        writer.min_timestamp = min(t_lo, writer.min_timestamp)
        writer.max_timestamp = max(t_hi, writer.max_timestamp)
        storage.message_start_time = min(t_lo, storage.message_start_time)
        storage.message_end_time = max(t_hi, storage.message_end_time)
        for cid, k in zip(*np.unique(cids, return_counts=True), strict=True):
            counts[int(cid)] += int(k)
            stats[int(cid)] += int(k)
        view = memoryview(records).cast('B')
        sizes = np.asarray(sizes, dtype=np.int64)
        ends = np.cumsum(sizes)
        i, at = 0, 0  # first record of this segment; its byte offset in records
        while i < n:
            chunk = storage.chunk
            pos = chunk.bio.tell()
            # rosbags closes the chunk after the message whose end passes 1 MiB
            rel = ends[i:] - at + pos
            j = int(np.searchsorted(rel, _CHUNK_BYTES, side='right'))
            last = min(i + j, n - 1)
            starts = rel[:last - i + 1] - sizes[i:last + 1]
            seg_c, seg_t = cids[i:last + 1], times[i:last + 1]
            # The message index per channel, channels in the order of their first message (rosbags' dict order).
            ids, first = np.unique(seg_c, return_index=True)
            msgs = chunk.msgs
            for cid in ids[np.argsort(first)].tolist():
                mask = seg_c == cid
                msgs[cid].extend(zip(seg_t[mask].tolist(), starts[mask].tolist(), strict=True))
            chunk.message_start_time = min(chunk.message_start_time, int(seg_t.min()))
            chunk.message_end_time = max(chunk.message_end_time, int(seg_t.max()))
            end = int(ends[last])
            chunk.bio.write(view[at:end])
            at, i = end, last + 1
            if chunk.bio.tell() > _CHUNK_BYTES:
                _close_chunk(storage)

    return write_records

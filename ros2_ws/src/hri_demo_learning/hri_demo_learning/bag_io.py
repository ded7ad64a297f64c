"""Reading and writing rosbag2 bags (MCAP storage) of HRI demonstrations, without ROS.

The recorder writes what it receives into a rosbag2 bag through `BagWriter` (the rosbags
writer, rosbag2 format version 8 as ROS 2 Jazzy writes it, MCAP storage, the receive time of
each message as its bag timestamp). `BagWriter.flush` closes the open MCAP chunk and hands it
to the operating system, so a recorder killed with SIGKILL loses only what came after its last
flush.

The learner reads bags back with `read_bag` (messages per topic) and `read_demonstration`
(the arrays of paper section II-B: receive times, end-effector positions x_i and the reference
x_r). Three layouts are read:

- a rosbag2 folder with metadata.yaml (closed cleanly): opened with the rosbags reader
  (metadata, summary, message definitions); its messages come from a walk of the MCAP data
  section (`_walk_records`: payloads kept as offsets into the file, `PayloadTable`; zstd
  chunks are inflated in place first, `_inflate_chunks`), or from the rosbags reader where
  chunks have another compression or files are compressed; a storage file that does not
  match its metadata is reported as truncated or corrupt;
- a folder without metadata.yaml (the recorder was killed), or a bare .mcap file: when the
  MCAP file has no footer, every message up to the last complete chunk is recovered with
  mcap's `NonSeekingReader` (the rosbags reader cannot open such a file);
- every failure is a `BagError` (a `ValueError`) with a one-line reason.

Messages are deserialised with the rosbags typestore of ROS 2 Jazzy; types it lacks are
registered from the bag's own message definitions. `read_demonstration` takes a fast path for
the two types a demonstration is made of, JointState and PointStamped: `read_bag` keeps their
raw CDR bytes, and `_joint_positions` / `_point_array` read the numbers straight into
numpy arrays (hri_core.cdr). The first message of a topic gives the byte layout (a small CDR
walk); every message with the same length and the same bytes where the layout could differ
(encoding, frame_id, joint names, sequence lengths) has that layout and is read by one fancy-
indexed view; any other message is deserialised with rosbags, which stays the reference (the
unit tests hold the two equal on the fixture bags and on a crash-recovered bag).

Positions are 3-D (x, y, z of /ee_position and /demo/reference). A bag without /ee_position
gets its tool positions from /joint_states through the forward kinematics of the arm its
/robot_description names (the URDF text the recorder records with the demonstration; pinocchio,
batched by hri_core.robot_description.ToolKinematics); a bag recorded before bags carried their
robot, with the SCARA's joints joint1, joint2, through the SCARA's (l1, l2, z = 0). A bag with
neither /ee_position nor a /robot_description for other joints, or whose joint states name
joints its URDF lacks, is refused in one line.
"""

import os
import struct
import zlib
from array import array
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
import zstandard
from mcap.exceptions import EndOfFile, McapError
from mcap.reader import NonSeekingReader
from rosbags.interfaces import Connection, Nodetype, Qos
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer
from rosbags.rosbag2.errors import ReaderError, WriterError
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from hri_core import topics
from hri_core.cdr import CdrLayout, joint_state_layout, point_stamped_layout, read_float64s
from hri_core.dynamics import forward_kinematics
from hri_core.robot_description import (
    ToolKinematics,
    description_model,
    urdf_joint_names,
)
from hri_core.robot_model import PinocchioModel

#: rosbag2 bag format version that ROS 2 Jazzy's rosbag2 writes.
JAZZY_BAG_VERSION = 8
#: The 8-byte magic that starts and ends every MCAP file.
MCAP_MAGIC = b'\x89MCAP0\r\n'

#: Compression of the MCAP chunks that BagWriter offers ('none' or 'zstd').
COMPRESSIONS = ('none', 'zstd')

# Where a demonstration's data is in a bag: the recorder's default topics.
POSITION_TOPIC = topics.EE_POSITION.name
JOINT_STATE_TOPIC = topics.JOINT_STATES.name
REFERENCE_TOPIC = topics.DEMO_REFERENCE.name
POINT_STAMPED = topics.EE_POSITION.type_name
JOINT_STATE = topics.JOINT_STATES.type_name
DESCRIPTION_TOPIC = topics.ROBOT_DESCRIPTION.name
STRING = topics.ROBOT_DESCRIPTION.type_name
# The SCARA's joints: a bag without /robot_description that names them is the SCARA's.
JOINT_NAMES = ('joint1', 'joint2')


class BagError(ValueError):
    """A bag cannot be written or read; the message is a one-line reason."""

    def __init__(self, reason: str):
        super().__init__(' '.join(str(reason).split()))


def jazzy_typestore() -> Typestore:
    """A fresh rosbags typestore with the message types of ROS 2 Jazzy."""
    return get_typestore(Stores.ROS2_JAZZY)


def _referenced_type_names(fielddef) -> Iterator[str]:
    """Names of the message types that a rosbags field definition refers to (recursively)."""
    if isinstance(fielddef, tuple):
        if len(fielddef) == 2 and fielddef[0] == Nodetype.NAME and isinstance(fielddef[1], str):
            yield fielddef[1]
            return
        for item in fielddef:
            yield from _referenced_type_names(item)
    elif isinstance(fielddef, list):
        for item in fielddef:
            yield from _referenced_type_names(item)


def register_message_type(typestore: Typestore, msgtype: str,
                          read_definition: Callable[[str], str]) -> None:
    """Register `msgtype` and every type it refers to that `typestore` does not know yet.

    `read_definition(name)` returns the .msg text of a type 'pkg/msg/Name' (the recorder reads
    `<share of pkg>/msg/Name.msg`). Raises BagError when a definition cannot be found or parsed.
    """
    pending = [msgtype]
    while pending:
        name = pending.pop()
        if name in typestore.fielddefs:
            continue
        try:
            types = get_types_from_msg(read_definition(name), name)
        except (OSError, LookupError, ValueError) as err:
            raise BagError(f'no message definition for {name}: {err}') from None
        except Exception as err:  # noqa: BLE001 - the rosbags parser raises its own types
            raise BagError(f'cannot parse the message definition of {name}: {err}') from None
        typestore.register(types)
        for _consts, fields in types.values():
            pending.extend(n for n in _referenced_type_names(fields)
                           if n not in typestore.fielddefs)


def _register_from_definition(typestore: Typestore, msgtype: str, encoding: str,
                              text: str) -> None:
    """Register a type from a bag's own definition ('ros2msg' or 'ros2idl') if unknown."""
    if msgtype in typestore.fielddefs:
        return
    if not text:
        raise BagError(f'the bag has no message definition for the unknown type {msgtype}')
    try:
        if encoding.endswith('idl') or text.startswith('=' * 80 + '\nIDL: '):
            types = {}
            for part in text.split('=' * 80 + '\n'):
                if part.startswith('IDL: '):
                    types.update(get_types_from_idl(part.split('\n', 1)[1]))
        else:
            types = get_types_from_msg(text, msgtype)
        typestore.register(types)
    except Exception as err:  # noqa: BLE001 - the rosbags parser raises its own types
        raise BagError(f'cannot parse the message definition of {msgtype}: {err}') from None


# --------------------------------------------------------------------------------------------
# Writing


class BagWriter:
    """A rosbag2 bag (MCAP storage, format version 8) being written by the recorder.

    Refuses to overwrite: `path` must not exist. Messages are written as raw CDR bytes with a
    timestamp in ns (the receive time). `flush()` closes the open MCAP chunk and hands the bytes
    to the operating system; `close()` writes the MCAP summary and metadata.yaml.
    compression 'zstd' compresses each MCAP chunk (storage-level, as rosbag2's MCAP presets
    do; every MCAP reader decodes it), 'none' writes them plain.
    Use as a context manager or call `open()` / `close()`.
    """

    def __init__(self, path: str | os.PathLike, typestore: Typestore | None = None,
                 read_definition: Callable[[str], str] | None = None,
                 compression: str = 'none'):
        if compression not in COMPRESSIONS:
            raise BagError(f'compression must be one of {", ".join(COMPRESSIONS)}, '
                           f'got {compression!r}')
        self.compression = compression
        self.path = Path(path)
        self.typestore = typestore if typestore is not None else jazzy_typestore()
        self._read_definition = read_definition
        self._writer: Writer | None = None
        self._connections: dict[str, Connection] = {}
        self._counts: dict[str, int] = {}

    def open(self) -> 'BagWriter':
        """Create the bag folder and its .mcap file. Raises BagError if `path` exists."""
        if self.path.exists() or self.path.is_symlink():
            raise BagError(f'output bag {self.path} exists already; refusing to overwrite it')
        if not self.path.parent.is_dir():
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as err:
                raise BagError(f'cannot create {self.path.parent}: {err.strerror}') from None
        writer = Writer(self.path, version=JAZZY_BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        if self.compression == 'zstd':
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        try:
            writer.open()
        except WriterError as err:
            raise BagError(f'cannot open bag {self.path}: {err}') from None
        except OSError as err:
            raise BagError(f'cannot create bag {self.path}: {err.strerror}') from None
        storage = writer.storage
        if not all(hasattr(storage, name) for name in ('close_chunk', 'chunk', 'bio')):
            writer.abort()
            raise BagError('this rosbags version has no MCAP chunk control; flush is impossible')
        self._writer = writer
        return self

    @property
    def is_open(self) -> bool:
        return self._writer is not None

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, per topic."""
        return dict(self._counts)

    def add_topic(self, topic: str, msgtype: str, qos_profiles: Sequence[Qos] = ()) -> Connection:
        """Add a topic of type 'pkg/msg/Name'; returns the connection to write it with.

        Types missing from the typestore are registered through `read_definition`.
        """
        if self._writer is None:
            raise BagError(f'bag {self.path} is not open')
        if topic in self._connections:
            raise BagError(f'topic {topic} was added to bag {self.path} already')
        if msgtype not in self.typestore.fielddefs:
            if self._read_definition is None:
                raise BagError(f'unknown message type {msgtype} and no definition reader')
            register_message_type(self.typestore, msgtype, self._read_definition)
        try:
            connection = self._writer.add_connection(
                topic, msgtype, typestore=self.typestore, offered_qos_profiles=list(qos_profiles))
        except Exception as err:  # noqa: BLE001 - rosbags raises TypesysError or WriterError
            raise BagError(f'cannot add topic {topic} ({msgtype}): {err}') from None
        self._connections[topic] = connection
        self._counts[topic] = 0
        return connection

    def write(self, connection: Connection, timestamp_ns: int, data: bytes | memoryview) -> None:
        """Write one message: raw CDR bytes stamped `timestamp_ns` (receive time, ns)."""
        self._writer.write(connection, timestamp_ns, data)
        self._counts[connection.topic] += 1

    def flush(self) -> None:
        """Close the open MCAP chunk (if it holds messages) and pass the bytes to the OS.

        After flush() returns, a SIGKILL of this process loses nothing written before.
        """
        if self._writer is None:
            return
        storage = self._writer.storage
        if storage.chunk.msgs:
            storage.close_chunk()
        storage.bio.flush()

    def close(self) -> dict[str, int]:
        """Write the MCAP summary and metadata.yaml; return the message count per topic."""
        if self._writer is not None:
            writer, self._writer = self._writer, None
            writer.close()
        return self.counts

    def __enter__(self) -> 'BagWriter':
        return self.open()

    def __exit__(self, exc_type, exc, traceback) -> None:
        self.close()


# --------------------------------------------------------------------------------------------
# Reading


class PayloadTable(Sequence):
    """The payloads of one topic's messages where they lie in a bag file's bytes: `starts`
    (N,) and `lengths` (N,) byte offsets and counts into `data`, no Python object per message
    until one is asked for (item i is the memoryview of payload i). `read_float64s` reads a
    CdrLayout's values of all of them by numpy gathers: a 1M-message topic in one step."""

    _BLOCK = 65536  # rows per gather: bounds the index arrays (rows x checked words x 8 B)

    def __init__(self, data: memoryview, starts: np.ndarray, lengths: np.ndarray):
        self.data = data
        self.u8 = np.frombuffer(data, dtype=np.uint8)
        self.starts = np.asarray(starts, dtype=np.int64)
        self.lengths = np.asarray(lengths, dtype=np.int64)

    def __len__(self) -> int:
        return int(self.starts.size)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        start = int(self.starts[index])
        return self.data[start:start + int(self.lengths[index])]

    def take(self, order: np.ndarray) -> 'PayloadTable':
        """The payloads in `order` (N,) (indices)."""
        return PayloadTable(self.data, self.starts[order], self.lengths[order])

    def read_float64s(self, layout: CdrLayout) -> tuple[np.ndarray, np.ndarray]:
        """hri_core.cdr.read_float64s of these payloads: (values (N, k), NaN where a message
        does not share the layout; matched (N,) bool). The checked bytes are compared 8 at a
        time where a range is that long (a joint name), through a view whose element i is the
        8 bytes from byte i: a gather per word, not per byte."""
        count = len(self)
        values = np.full((count, len(layout.offsets)), np.nan)
        matched = np.zeros(count, dtype=bool)
        candidates = np.flatnonzero(self.lengths == layout.size)
        words, single = [], []
        for begin, end in layout.checks:
            if end - begin >= 8:  # words from begin, the last one ending at end (overlaps)
                words.extend([*range(begin, end - 8, 8), end - 8])
            else:
                single.extend(range(begin, end))
        words, single = np.array(words, dtype=np.int64), np.array(single, dtype=np.int64)
        offsets = np.asarray(layout.offsets, dtype=np.int64)
        template = bytes(layout.template)
        template_u8 = np.frombuffer(template, dtype=np.uint8)
        expected_words = _unaligned(template, '<u8')[words]
        buffer_words, buffer_values = _unaligned(self.data, '<u8'), _unaligned(self.data, '<f8')
        for first in range(0, candidates.size, self._BLOCK):
            rows = candidates[first:first + self._BLOCK]
            starts = self.starts[rows][:, None]
            same = np.all(buffer_words[starts + words] == expected_words, axis=1)
            same &= np.all(self.u8[starts + single] == template_u8[single], axis=1)
            rows = rows[same]
            matched[rows] = True
            values[rows] = buffer_values[starts[same] + offsets]
        return values, matched


def _unaligned(buffer, dtype: str) -> np.ndarray:
    """A read-only view of `buffer` whose element i is the 8-byte `dtype` value starting at
    byte i (elements overlap; numpy reads them unaligned)."""
    size = len(buffer)
    return np.ndarray((max(size - 7, 0),), dtype=dtype, buffer=buffer, offset=0, strides=(1,))


def _float64s(raw, layout: CdrLayout) -> tuple[np.ndarray, np.ndarray]:
    """read_float64s of raw payloads: a PayloadTable's by its gathers, a list's by hri_core."""
    if isinstance(raw, PayloadTable):
        return raw.read_float64s(layout)
    return read_float64s(raw, layout)


@dataclass
class TopicMessages:
    """The messages of one topic: type, bag timestamps (receive time, ns) and messages.

    For a type `read_bag` was asked to keep raw, `raw` holds each message's CDR bytes (a list,
    or a PayloadTable for a closed MCAP file read by the fast walk) and `messages` stays
    empty; otherwise `messages` holds the deserialised messages.
    """

    msgtype: str
    timestamps_ns: list[int] = field(default_factory=list)
    messages: list = field(default_factory=list)
    raw: list = field(default_factory=list)

    @property
    def count(self) -> int:
        return len(self.messages) + len(self.raw)

    def times(self) -> np.ndarray:
        """Bag timestamps as an array (N,) of seconds since the epoch."""
        return np.asarray(self.timestamps_ns, dtype=np.int64) * 1e-9


@dataclass
class BagContents:
    """What `read_bag` read: messages per topic, and whether a crashed bag was recovered."""

    path: Path
    topics: dict[str, TopicMessages]
    recovered: bool = False
    recovered_until_byte: int = 0
    file_size: int = 0

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    def counts(self) -> dict[str, int]:
        return {name: t.count for name, t in self.topics.items()}


def _one_line(err: BaseException) -> str:
    text = ' '.join(str(err).split())
    return f'{type(err).__name__}: {text}' if text else type(err).__name__


def _has_mcap_end(path: Path) -> bool:
    """Whether an MCAP file ends with the closing magic (its footer was written)."""
    size = path.stat().st_size
    if size < 2 * len(MCAP_MAGIC):
        return False
    with path.open('rb') as stream:
        stream.seek(size - len(MCAP_MAGIC))
        return stream.read(len(MCAP_MAGIC)) == MCAP_MAGIC


def _check_mcap_magic(path: Path) -> None:
    with path.open('rb') as stream:
        head = stream.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        if not head:
            raise BagError(f'{path} is an empty file, not a bag')
        raise BagError(f'{path} is not a bag: not an MCAP file (bad magic bytes)')


def _deserialize(typestore: Typestore, data: bytes | memoryview, msgtype: str,
                 topic: str, index: int, path: Path):
    try:
        return typestore.deserialize_cdr(data, msgtype)
    except Exception as err:  # noqa: BLE001 - any decoding failure means a corrupt message
        raise BagError(f'bag {path} is corrupt: message {index} on {topic} does not decode '
                       f'as {msgtype} ({_one_line(err)})') from None


def _keep(series: TopicMessages, typestore: Typestore, data, raw_types: frozenset,
          topic: str, index: int, path: Path) -> None:
    """Append one message to `series`: its raw bytes for raw_types, else deserialised."""
    if series.msgtype in raw_types:
        series.raw.append(data)
    else:
        series.messages.append(_deserialize(typestore, data, series.msgtype, topic, index, path))


# Reading an MCAP file's messages without a Python call per message beyond one unpack: the
# records of the data section walked in order (rosbags' reader costs about 4 us a message).
_RECORD_HEAD = struct.Struct('<BQ')           # opcode, content length
_CHUNK_HEAD = struct.Struct('<QQQI')          # start, end time, uncompressed size, crc
# A message record: opcode (1), length (8), channel id (2), sequence (4), log time (8), publish
# time (8), then the payload (from byte 31 of the record).
_MESSAGE_CHANNEL_TIME = struct.Struct('<H4xQ')  # channel id, (sequence), log time
_BYTE_OFFSETS = np.arange(8)  # the 8 bytes of a little-endian uint64, gathered by numpy
_OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_DATA_END = 0x04, 0x05, 0x06, 0x0F
SHORT_RUN = 16  # messages of one length in a row below which numpy costs more than it saves


def _mcap_files_of(path: Path) -> list[Path] | None:
    """The .mcap files of a closed bag, in order; None where the fast walk does not apply
    (file-level compression, or files that are not plain .mcap)."""
    if path.is_file():
        return [path] if path.suffix == '.mcap' else None
    try:
        info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
        if info.get('compression_mode') or info.get('compression_format'):
            return None
        files = [path / name for name in info['relative_file_paths']]
    except (OSError, KeyError, TypeError, yaml.YAMLError):
        return None
    return files if all(f.suffix == '.mcap' and f.is_file() for f in files) else None


def _message_run(u8: np.ndarray, first: int, end: int, length: int, probe: int) -> int:
    """How many message records of content length `length` follow each other from byte
    `first` on (1 at least: the one there), looking at most `probe` records ahead."""
    stride = 9 + length
    count = min(probe, (end - first) // stride)
    if count <= 1:
        return 1
    starts = first + stride * np.arange(count)
    lengths = u8[(starts + 1)[:, None] + _BYTE_OFFSETS].view('<u8')[:, 0]
    same = (u8[starts] == _OP_MESSAGE) & (lengths == length)
    return count if same.all() else max(1, int(np.argmin(same)))


def _take_run(u8: np.ndarray, first: int, count: int, length: int,
              sinks: dict[int, tuple | None]) -> None:
    """Hand the `count` message records of content length `length` from byte `first` on to
    their topics' sinks, in order: log times (ns) and payload offsets as arrays."""
    starts = first + (9 + length) * np.arange(count)
    channels = u8[starts + 9].astype(np.uint16) | (u8[starts + 10].astype(np.uint16) << 8)
    log_times = u8[(starts + 15)[:, None] + _BYTE_OFFSETS].view('<u8')[:, 0]
    one_channel = count == 1 or bool(np.all(channels == channels[0]))
    for channel in [int(channels[0])] if one_channel else np.unique(channels).tolist():
        sink = sinks.get(channel)
        if sink is None:
            continue
        mine = slice(None) if one_channel else channels == channel
        stamps, payloads = sink
        stamps.frombytes(log_times[mine].astype(np.uint64).tobytes())
        # The payload follows the 31 bytes of record head.
        payloads.frombytes((starts[mine] + 31).astype(np.int64).tobytes())


def _walk_records(data: memoryview, start: int, end: int, channels: dict[int, str],
                  sinks: dict[int, tuple | None], wanted: dict[str, tuple[array, array]]
                  ) -> bool:
    """Walk the MCAP records in data[start:end]: channels into `channels` (id -> topic) and
    `sinks` (id -> the (stamps, payloads) arrays of a topic in `wanted`, else None); each
    message of a wanted topic appends its log time (ns, array('Q')) and its payload's byte
    offset (array('q')) there, in order; chunks are walked inside. False at a compressed chunk
    (the caller falls back to rosbags), True at the end of the data section. ValueError or
    struct.error for records that do not fit.

    A recording is mostly runs of messages of one length (a 1 kHz stream of one layout): a run
    is found and read by numpy in one step (`_message_run`, `_take_run`), so the Python loop
    turns once per run, not once per message (1M joint states: 1.7 s one by one here). Where
    topics interleave (two 1 kHz streams in receive order: runs of 5 on the fixture bags) a
    probe costs more than the messages it finds, so a length whose last run was shorter than
    SHORT_RUN is read one message at a time until SHORT_RUN of it follow each other."""
    u8 = np.frombuffer(data, dtype=np.uint8)
    probes: dict[int, int] = {}  # message length -> records to probe ahead (0: one at a time)
    streak_length, streak = -1, 0  # the length of the last messages read one at a time
    at = start
    while at < end:
        opcode, length = _RECORD_HEAD.unpack_from(data, at)
        body = at + 9
        if body + length > end:
            raise ValueError(f'record at byte {at} runs past the end')
        if opcode == _OP_MESSAGE:
            probe = probes.get(length, SHORT_RUN)
            if probe:
                count = _message_run(u8, at, end, length, probe)
                if count >= SHORT_RUN:
                    _take_run(u8, at, count, length, sinks)
                    # Probe a little beyond the last run of this length: a long run (a fast
                    # topic between two messages of a slow one) is found in one step.
                    probes[length] = min(2 * count, 65536)
                    at += count * (9 + length)
                    continue
                probes[length] = 0
            channel, log_time = _MESSAGE_CHANNEL_TIME.unpack_from(data, body)
            sink = sinks.get(channel)
            if sink is not None:
                sink[0].append(log_time)
                sink[1].append(body + 22)
            at = body + length
            streak = streak + 1 if length == streak_length else 1
            streak_length = length
            if streak >= SHORT_RUN:
                probes[length], streak = SHORT_RUN, 0
            continue
        at = body + length
        if opcode == _OP_CHUNK:
            compression, inner, records_length = _chunk_records(data, body, at)
            if compression:
                return False
            if not _walk_records(data, inner, inner + records_length, channels, sinks,
                                 wanted):
                return False
        elif opcode == _OP_CHANNEL:
            (channel,) = struct.unpack_from('<H', data, body)
            (topic_length,) = struct.unpack_from('<I', data, body + 4)
            topic = bytes(data[body + 8:body + 8 + topic_length]).decode()
            channels[channel] = topic
            series = wanted.get(topic)
            sinks[channel] = series
        elif opcode == _OP_DATA_END:
            return True
    return True


def _chunk_records(data: memoryview, body: int, record_end: int) -> tuple[bytes, int, int]:
    """A chunk record's compression name (b'': none), and the offset and length of its
    records, from its content at byte `body` of `data`; ValueError where they run past the
    record's end (`record_end`)."""
    inner = body + _CHUNK_HEAD.size
    (name_length,) = struct.unpack_from('<I', data, inner)
    compression = bytes(data[inner + 4:inner + 4 + name_length])
    inner += 4 + name_length
    (records_length,) = struct.unpack_from('<Q', data, inner)
    inner += 8
    if inner + records_length > record_end:
        raise ValueError(f'chunk at byte {body - 9} runs past its record')
    return compression, inner, records_length


def _inflate_chunks(data: memoryview) -> memoryview | None:
    """`data` (a whole MCAP file) with each zstd chunk replaced by the same chunk uncompressed,
    so that every payload is an offset into one buffer: a compressed bag is read by the walk
    too (a fixture bag's demonstration in 0.030 s against 0.064 s through rosbags' reader, in
    one process, zstd included). `data` itself where no chunk is compressed; None where a
    chunk has another compression (the caller falls back to rosbags). ValueError for a chunk
    that does not inflate to its recorded size and CRC (a CRC of 0 is not recorded, as the
    MCAP specification says)."""
    parts: list = []
    copied, at = 0, len(MCAP_MAGIC)
    end = len(data) - len(MCAP_MAGIC)
    while at < end:
        opcode, length = _RECORD_HEAD.unpack_from(data, at)
        body = at + 9
        if body + length > end:
            raise ValueError(f'record at byte {at} runs past the end')
        if opcode == _OP_DATA_END:
            break
        if opcode == _OP_CHUNK:
            start_time, end_time, size, crc = _CHUNK_HEAD.unpack_from(data, body)
            compression, inner, records_length = _chunk_records(data, body, body + length)
            if compression and compression != b'zstd':
                return None
            if compression:
                records = zstandard.ZstdDecompressor().decompress(
                    data[inner:inner + records_length], max_output_size=size)
                if len(records) != size or (crc and zlib.crc32(records) != crc):
                    raise ValueError(f'chunk at byte {at} does not inflate to its size and CRC')
                parts += [data[copied:at],
                          _RECORD_HEAD.pack(_OP_CHUNK, _CHUNK_HEAD.size + 12 + size),
                          _CHUNK_HEAD.pack(start_time, end_time, size, crc),
                          struct.pack('<IQ', 0, size), records]
                copied = body + length
        at = body + length
    if not parts:
        return data
    parts.append(data[copied:])
    return memoryview(b''.join(parts))


def _read_mcap_data(files: list[Path], topics: dict[str, TopicMessages]) -> bool:
    """Read the messages of `topics` from closed MCAP files as raw bytes into their series;
    False (nothing kept) where a chunk has a compression other than zstd. ValueError,
    struct.error or zstandard.ZstdError if corrupt."""
    tables: list[tuple[memoryview, dict[str, tuple[array, array]]]] = []
    for mcap_file in files:
        data = memoryview(mcap_file.read_bytes())
        if bytes(data[:len(MCAP_MAGIC)]) != MCAP_MAGIC:
            raise ValueError(f'{mcap_file} does not start with the MCAP magic bytes')
        inflated = _inflate_chunks(data)
        if inflated is None:
            return False
        # Per topic its log times (ns) and payload offsets, grown in place (no numpy array a
        # message where two topics alternate, each message a run of its own).
        found_by_topic = {topic: (array('Q'), array('q')) for topic in topics}
        try:
            if not _walk_records(inflated, len(MCAP_MAGIC), len(inflated) - len(MCAP_MAGIC),
                                 {}, {}, found_by_topic):
                return False
        except ValueError as err:
            if inflated is data:
                raise
            raise ValueError(f'{err} (of the file with its zstd chunks inflated)') from None
        tables.append((inflated, found_by_topic))
    for topic, series in topics.items():
        parts = []
        for data, found_by_topic in tables:
            stamps, starts = found_by_topic[topic]
            if stamps:
                series.timestamps_ns.extend(stamps.tolist())
                starts = np.frombuffer(starts, dtype=np.int64)
                parts.append(PayloadTable(data, starts, _payload_lengths(data, starts)))
        if len(parts) == 1:
            series.raw = parts[0]
        else:  # several files: one list (each file's bytes stay alive through its views)
            series.raw = [payload for part in parts for payload in part]
    return True


def _payload_lengths(data: memoryview, starts: np.ndarray) -> np.ndarray:
    """The payload length of each message whose payload starts at `starts` (N,): its record's
    content length (the uint64 at 30 bytes before the payload) less the 22 bytes of channel
    id, sequence and times."""
    u8 = np.frombuffer(data, dtype=np.uint8)
    lengths = np.empty(starts.size, dtype=np.int64)
    for first in range(0, starts.size, PayloadTable._BLOCK):
        block = starts[first:first + PayloadTable._BLOCK]
        lengths[first:first + block.size] = u8[(block - 30)[:, None] + _BYTE_OFFSETS].view(
            '<u8')[:, 0] - 22
    return lengths


def _read_closed(path: Path, wanted: set[str] | None, typestore: Typestore,
                 raw_types: frozenset = frozenset()) -> BagContents:
    """Read a cleanly closed bag (folder with metadata.yaml, or a complete .mcap file)."""
    topics: dict[str, TopicMessages] = {}
    try:
        reader = Reader(path)
        reader.open()
    except ReaderError as err:
        if 'metadata' in str(err) or 'YAML' in str(err):
            raise BagError(f'{path} is not a bag: invalid metadata.yaml ({_one_line(err)})'
                           ) from None
        raise BagError(f'bag {path} is truncated or corrupt: {_one_line(err)}') from None
    except Exception as err:  # noqa: BLE001 - a garbage summary raises Overflow/struct errors
        raise BagError(f'bag {path} is truncated or corrupt: {_one_line(err)}') from None
    try:
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for connection in connections:
            _register_from_definition(typestore, connection.msgtype,
                                      connection.msgdef.format.name.lower(),
                                      connection.msgdef.data)
            topics.setdefault(connection.topic, TopicMessages(connection.msgtype))
        if connections:
            files = _mcap_files_of(path)
            if files is None or not _read_mcap_data(files, topics):
                for index, (connection, stamp, data) in enumerate(
                        reader.messages(connections)):
                    series = topics[connection.topic]
                    series.timestamps_ns.append(stamp)
                    _keep(series, typestore, data, raw_types, connection.topic, index, path)
            else:
                for topic, series in topics.items():
                    if series.msgtype not in raw_types:
                        series.messages = [
                            _deserialize(typestore, data, series.msgtype, topic, index, path)
                            for index, data in enumerate(series.raw)]
                        series.raw = []
                _sort_by_time(topics)
    except BagError:
        raise
    except Exception as err:  # noqa: BLE001 - rosbags/struct/zstd raise many types here
        raise BagError(f'bag {path} is truncated or corrupt: {_one_line(err)}') from None
    finally:
        reader.close()
    return BagContents(path, topics)


def _recover_mcap(path: Path, wanted: set[str] | None, typestore: Typestore,
                  topics: dict[str, TopicMessages], raw_types: frozenset = frozenset()) -> int:
    """Read an MCAP file without footer up to its last complete chunk; return bytes used."""
    size = path.stat().st_size
    used = 0
    with path.open('rb') as stream:
        reader = NonSeekingReader(stream, record_size_limit=max(size, 1))
        try:
            for index, (schema, channel, message) in enumerate(
                    reader.iter_messages(log_time_order=False)):
                used = stream.tell()
                if wanted is not None and channel.topic not in wanted:
                    continue
                if schema is None:
                    raise BagError(f'bag {path} is corrupt: channel {channel.topic} has no schema')
                msgtype = schema.name
                _register_from_definition(typestore, msgtype, schema.encoding,
                                          schema.data.decode('utf-8', errors='replace'))
                series = topics.setdefault(channel.topic, TopicMessages(msgtype))
                series.timestamps_ns.append(message.log_time)
                _keep(series, typestore, message.data, raw_types, channel.topic, index, path)
        except (EndOfFile, McapError):
            # The normal end of a killed recording: the last record was cut short (a record
            # longer than the whole file counts as cut short too).
            pass
        except BagError:
            raise
        except Exception as err:  # noqa: BLE001 - garbage records raise struct/Unicode errors
            if stream.tell() < size:
                raise BagError(f'bag {path} is corrupt: {_one_line(err)}') from None
            # A record cut short at the end of the file: the same as EndOfFile.
    return used


def _sort_by_time(topics: dict[str, TopicMessages]) -> None:
    for series in topics.values():
        order = np.argsort(np.asarray(series.timestamps_ns, dtype=np.int64), kind='stable')
        if np.any(order != np.arange(order.size)):
            # One of messages and raw holds the topic's messages, the other is empty.
            series.timestamps_ns = [series.timestamps_ns[i] for i in order]
            series.messages = [series.messages[i] for i in order] if series.messages else []
            if isinstance(series.raw, PayloadTable):
                series.raw = series.raw.take(order)
            else:
                series.raw = [series.raw[i] for i in order] if series.raw else []


def _read_unclosed(path: Path, mcap_files: list[Path], wanted: set[str] | None,
                   typestore: Typestore, raw_types: frozenset = frozenset()) -> BagContents:
    """Read .mcap files without metadata.yaml: complete ones normally, others recovered."""
    topics: dict[str, TopicMessages] = {}
    recovered = False
    used_total = 0
    size_total = 0
    for mcap_file in mcap_files:
        _check_mcap_magic(mcap_file)
        size = mcap_file.stat().st_size
        size_total += size
        if _has_mcap_end(mcap_file):
            part = _read_closed(mcap_file, wanted, typestore, raw_types)
            for name, series in part.topics.items():
                merged = topics.setdefault(name, TopicMessages(series.msgtype))
                merged.timestamps_ns.extend(series.timestamps_ns)
                merged.messages.extend(series.messages)
                merged.raw.extend(series.raw)
            used_total += size
        else:
            recovered = True
            used_total += _recover_mcap(mcap_file, wanted, typestore, topics, raw_types)
    _sort_by_time(topics)
    contents = BagContents(path, topics, recovered, used_total, size_total)
    if recovered and contents.message_count == 0 and wanted is None:
        raise BagError(f'bag {path} is truncated: no complete MCAP chunk '
                       f'({size_total} bytes, the recording ended before its first flush)')
    return contents


def read_bag(path: str | os.PathLike, topics: Iterable[str] | None = None,
             typestore: Typestore | None = None,
             raw_types: Iterable[str] = ()) -> BagContents:
    """Read the messages of a bag (a rosbag2 folder or a bare .mcap file) per topic.

    `topics` restricts the topics read (None: all); messages of the types in `raw_types`
    are kept as raw CDR bytes (TopicMessages.raw), the others deserialised. Bag timestamps
    are kept in ns (the recorder stores the receive time there). Raises BagError with a
    one-line reason for a path that does not exist or cannot be read, something that is not a
    bag, a bag without messages, and a truncated or corrupt bag (see the module docstring for
    crash recovery).
    """
    bag = Path(path)
    typestore = typestore if typestore is not None else jazzy_typestore()
    wanted = set(topics) if topics is not None else None
    raw_types = frozenset(raw_types)
    if not bag.exists():
        raise BagError(f'bag path does not exist: {bag}')
    if not os.access(bag, os.R_OK) or (bag.is_dir() and not os.access(bag, os.X_OK)):
        raise BagError(f'bag path is not readable (permission denied): {bag}')
    try:
        if bag.is_file() and bag.name == 'metadata.yaml':
            bag = bag.parent
        if bag.is_dir():
            mcap_files = sorted(bag.glob('*.mcap'))
            unreadable = [f for f in mcap_files if not os.access(f, os.R_OK)]
            if unreadable:
                raise BagError(f'bag file is not readable (permission denied): {unreadable[0]}')
            if (bag / 'metadata.yaml').is_file():
                contents = _read_closed(bag, wanted, typestore, raw_types)
            elif mcap_files:
                contents = _read_unclosed(bag, mcap_files, wanted, typestore, raw_types)
            else:
                raise BagError(f'{bag} is not a bag: no metadata.yaml and no .mcap file in it')
        elif bag.is_file():
            if bag.suffix != '.mcap':
                _check_mcap_magic(bag)
                raise BagError(f'{bag} is not a bag: an MCAP file must end in .mcap')
            contents = _read_unclosed(bag, [bag], wanted, typestore, raw_types)
        else:
            raise BagError(f'{bag} is not a bag: neither a folder nor a file')
    except PermissionError as err:
        raise BagError(f'bag path is not readable (permission denied): {err.filename}') from None
    except OSError as err:
        raise BagError(f'cannot read bag {bag}: {err.strerror or _one_line(err)}') from None
    if contents.message_count == 0 and wanted is None:
        raise BagError(f'bag {bag} is empty: it holds no messages')
    return contents


# --------------------------------------------------------------------------------------------
# Demonstrations


@dataclass(frozen=True)
class Demonstration:
    """One demonstration as arrays (paper section II-B), positions in 3-D.

    times: (N,) s, receive time since `start_time_ns`, increasing;
    positions: (N, 3) m, end-effector (tool) position x_i in the base frame;
    references: (N, 3) m, reference x_r in force at each sample;
    position_source: the topic the positions came from; kinematics: for /joint_states, the
    forward kinematics that made them positions ('' otherwise); robot: the arm of the bag's
    /robot_description ('' without one); reach: m, that arm's reach (RobotModel.reach; None
    without a /robot_description).
    """

    path: Path
    times: np.ndarray
    positions: np.ndarray
    references: np.ndarray
    start_time_ns: int
    position_source: str
    recovered: bool = False
    kinematics: str = ''
    robot: str = ''
    reach: float | None = None


def _decoded(series: TopicMessages, typestore: Typestore, topic: str, path: Path):
    """Yield (index, message) deserialised by rosbags: the messages, or the raw bytes'."""
    if series.messages:
        yield from enumerate(series.messages)
    for index, data in enumerate(series.raw):
        yield index, _deserialize(typestore, data, series.msgtype, topic, index, path)


def _point_array(series: TopicMessages, topic: str, path: Path,
                 typestore: Typestore | None = None) -> np.ndarray:
    """(N, 3) x, y, z (m) of PointStamped messages: raw bytes by the fast path, else rosbags."""
    planar = point_stamped_layout(series.raw[0]) if series.raw else None
    if planar is None:
        typestore = typestore if typestore is not None else jazzy_typestore()
        return np.array([[m.point.x, m.point.y, m.point.z] for _, m in _decoded(
            series, typestore, topic, path)], dtype=float).reshape(-1, 3)
    # hri_core.cdr's layout reads x, y; z is the float64 after y.
    x_offset, y_offset = planar.offsets
    layout = CdrLayout(planar.template, planar.size, planar.checks,
                       (x_offset, y_offset, y_offset + 8))
    values, matched = _float64s(series.raw, layout)
    if not matched.all():
        typestore = typestore if typestore is not None else jazzy_typestore()
        for index in np.flatnonzero(~matched):
            msg = _deserialize(typestore, series.raw[index], series.msgtype, topic, index, path)
            values[index] = (msg.point.x, msg.point.y, msg.point.z)
    return values


def _joint_row(msg, index: int, path: Path, joints: Sequence[str]) -> list[float]:
    """Positions of `joints` (rad or m) in one deserialised JointState."""
    names = list(msg.name)
    position = np.asarray(msg.position, dtype=float)
    if all(n in names for n in joints):
        idx = [names.index(n) for n in joints]
    elif not names and position.size >= len(joints):
        idx = list(range(len(joints)))
    else:
        raise BagError(f'bag {path}: {JOINT_STATE_TOPIC} message {index} has no '
                       f'positions for {", ".join(joints)} (names {names})')
    if position.size <= max(idx):
        raise BagError(f'bag {path}: {JOINT_STATE_TOPIC} message {index} has '
                       f'{position.size} positions for {len(names)} names')
    return position[idx].tolist()


def _joint_positions(series: TopicMessages, topic: str, path: Path,
                     joints: Sequence[str] = JOINT_NAMES,
                     typestore: Typestore | None = None) -> np.ndarray:
    """(N, len(joints)) positions of `joints` in rad (m for a prismatic joint) from JointState
    messages (raw bytes by the fast path where their layout allows, else rosbags)."""
    layout = joint_state_layout(series.raw[0], joints) if series.raw else None
    typestore = typestore if typestore is not None else jazzy_typestore()
    if layout is None:
        return np.array([_joint_row(m, i, path, joints) for i, m in _decoded(
            series, typestore, topic, path)], dtype=float).reshape(-1, len(joints))
    values, matched = _float64s(series.raw, layout)
    for index in np.flatnonzero(~matched):
        msg = _deserialize(typestore, series.raw[index], series.msgtype, topic, index, path)
        values[index] = _joint_row(msg, index, path, joints)
    return values


def _first_joint_names(series: TopicMessages, topic: str, path: Path) -> list[str]:
    """The joint names of the first JointState message."""
    first = series.messages[0] if series.messages else _deserialize(
        jazzy_typestore(), series.raw[0], series.msgtype, topic, 0, path)
    return list(first.name)


def end_effector_positions(joint_angles: np.ndarray, l1: float, l2: float) -> np.ndarray:
    """End-effector positions (N, 3) in m from the SCARA's joint angles (N, 2) in rad: the
    forward kinematics of hri_core.dynamics with link lengths l1, l2 (m), in the plane z = 0.
    """
    joint_angles = np.asarray(joint_angles, dtype=float).reshape(-1, 2)
    planar = np.asarray(forward_kinematics(joint_angles, l1, l2), dtype=float).reshape(-1, 2)
    return np.column_stack([planar, np.zeros(len(planar))])


@dataclass(frozen=True)
class BagRobot:
    """The arm a bag's /robot_description describes: its model and the URDF's joint names."""

    model: PinocchioModel
    urdf_joints: tuple[str, ...]


def bag_robot(series: TopicMessages, path: Path, tool_frame: str = '') -> BagRobot:
    """The arm of a bag's /robot_description messages (std_msgs/String, the URDF text) with
    its tool point at `tool_frame` ('' = hri_core.robot_description.default_tool_frame).
    Raises BagError (one line) for an unreadable URDF, several different ones, or a tool frame
    it lacks."""
    texts = list(dict.fromkeys(
        m.data for _, m in _decoded(series, jazzy_typestore(), DESCRIPTION_TOPIC, path)))
    if len(texts) > 1:
        raise BagError(f'bag {path} carries {len(texts)} different URDFs on '
                       f'{DESCRIPTION_TOPIC}: a demonstration is made by one arm')
    try:
        return BagRobot(description_model(texts[0], tool_frame), urdf_joint_names(texts[0]))
    except ValueError as err:
        raise BagError(f'bag {path}: the URDF on {DESCRIPTION_TOPIC}: {err}') from None


def _tool_positions(source: TopicMessages, topic: str, path: Path,
                    robot: BagRobot | None, l1: float, l2: float) -> tuple[np.ndarray, str]:
    """Tool positions (N, 3) m from JointState messages: through the bag's URDF where it has
    one, else (a bag recorded before bags carried their robot) the SCARA's forward kinematics
    with l1, l2 for its joints joint1, joint2. Returns them and which kinematics made them."""
    names = _first_joint_names(source, topic, path)
    if robot is None:
        if names and not all(joint in names for joint in JOINT_NAMES):
            raise BagError(
                f'bag {path} has neither {POSITION_TOPIC} nor {DESCRIPTION_TOPIC}: the '
                f'positions of its joints ({", ".join(names[:8])}) cannot be turned into '
                'tool positions; record the demonstration with /robot_description')
        joints = _joint_positions(source, topic, path, JOINT_NAMES)
        return end_effector_positions(joints, l1, l2), f'the SCARA\'s, l1={l1} l2={l2} m'
    model = robot.model
    unknown = [name for name in names if name not in robot.urdf_joints]
    if unknown:
        raise BagError(f'bag {path}: {topic} names joints its URDF ({model.name}) lacks: '
                       f'{", ".join(unknown[:8])}')
    missing = [name for name in model.joint_names if names and name not in names]
    if missing:
        raise BagError(f'bag {path}: {topic} lacks joints of {model.name} between its base '
                       f'and {model.tool_frame}: {", ".join(missing)}')
    joints = _joint_positions(source, topic, path, model.joint_names)
    if not np.all(np.isfinite(joints)):
        raise BagError(f'bag {path} is corrupt: non-finite joint positions')
    return (ToolKinematics(model).positions(joints),
            f'the URDF of {model.name}, tool frame {model.tool_frame}')


def read_demonstration(path: str | os.PathLike, l1: float = 0.35, l2: float = 0.30,
                       position_topic: str = POSITION_TOPIC,
                       joint_state_topic: str = JOINT_STATE_TOPIC,
                       reference_topic: str = REFERENCE_TOPIC,
                       fast: bool = True, tool_frame: str = '') -> Demonstration:
    """Read a demonstration bag into receive times, positions x_i and references x_r (3-D).

    Positions come from `position_topic` (PointStamped: x, y, z) when the bag has it, else from
    `joint_state_topic` through the forward kinematics of the arm on /robot_description
    (the URDF text; tool point at `tool_frame`, '' = the robot's own, see
    hri_core.robot_description), else, for a bag recorded before bags carried their robot,
    through the SCARA's with link lengths l1, l2 (m) (joints joint1, joint2; z = 0). x_r is
    the last `reference_topic` message received at or before each sample; samples received
    before the first reference take the first one. Raises BagError (one line) when the bag
    cannot be read or lacks the topics, when its URDF cannot be read or its joint states name
    joints the URDF lacks, or when a value is not finite. fast=False reads every message
    through the rosbags deserialiser (the reference of the raw CDR fast path).
    """
    if not (np.isfinite(l1) and np.isfinite(l2) and l1 > 0.0 and l2 > 0.0):
        raise BagError(f'link lengths must be finite and > 0 m, got l1={l1}, l2={l2}')
    wanted = (position_topic, joint_state_topic, reference_topic)
    contents = read_bag(path, topics=(*wanted, DESCRIPTION_TOPIC),
                        raw_types=(JOINT_STATE, POINT_STAMPED) if fast else ())
    bag = contents.path
    present = {name: s for name, s in contents.topics.items() if s.count}
    if not present.keys() & set(wanted):
        available = read_bag(path).topics
        raise BagError(f'bag {bag} has none of the topics {", ".join(wanted)} '
                       f'(it has {", ".join(sorted(available)) or "no topics"})')
    reference = present.get(reference_topic)
    if reference is None:
        raise BagError(f'bag {bag} has no {reference_topic} messages (the reference x_r)')
    if reference.msgtype != POINT_STAMPED:
        raise BagError(f'bag {bag}: {reference_topic} is {reference.msgtype}, '
                       f'not {POINT_STAMPED}')
    description = present.get(DESCRIPTION_TOPIC)
    if description is not None and description.msgtype != STRING:
        raise BagError(f'bag {bag}: {DESCRIPTION_TOPIC} is {description.msgtype}, '
                       f'not {STRING}')
    robot = None if description is None else bag_robot(description, bag, tool_frame)
    if position_topic in present:
        source = present[position_topic]
        if source.msgtype != POINT_STAMPED:
            raise BagError(f'bag {bag}: {position_topic} is {source.msgtype}, '
                           f'not {POINT_STAMPED}')
        positions = _point_array(source, position_topic, bag)
        source_topic, kinematics = position_topic, ''
    elif joint_state_topic in present:
        source = present[joint_state_topic]
        if source.msgtype != JOINT_STATE:
            raise BagError(f'bag {bag}: {joint_state_topic} is {source.msgtype}, '
                           f'not {JOINT_STATE}')
        positions, kinematics = _tool_positions(source, joint_state_topic, bag, robot,
                                                l1, l2)
        source_topic = joint_state_topic
    else:
        raise BagError(f'bag {bag} has no end-effector positions: neither {position_topic} '
                       f'nor {joint_state_topic} messages')
    stamps = np.asarray(source.timestamps_ns, dtype=np.int64)
    reference_points = _point_array(reference, reference_topic, bag)
    if not (np.all(np.isfinite(positions)) and np.all(np.isfinite(reference_points))):
        raise BagError(f'bag {bag} is corrupt: non-finite positions or references')
    reference_stamps = np.asarray(reference.timestamps_ns, dtype=np.int64)
    held = np.clip(np.searchsorted(reference_stamps, stamps, side='right') - 1, 0, None)
    start = int(stamps[0])
    return Demonstration(path=bag, times=(stamps - start) * 1e-9, positions=positions,
                         references=reference_points[held], start_time_ns=start,
                         position_source=source_topic, recovered=contents.recovered,
                         kinematics=kinematics,
                         robot='' if robot is None else robot.model.name,
                         reach=None if robot is None else robot.model.reach)

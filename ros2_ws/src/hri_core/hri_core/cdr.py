"""Raw CDR of the loop's messages: fixed byte layouts read and written without rclpy.

rclpy turns every message into a Python object and back (about 10-25 us for a JointState
each way here), which at 1 kHz is a large part of a node's CPU. The messages of the 1 kHz
loop keep one byte layout from one message to the next (the same joint names, frame_id and
sequence lengths), and so does the person's body (HumanBody, 100 Hz, in the controller's one
thread beside its cycles), so the nodes and the bag reader read and write them as serialized
CDR:

* reading: the first message of a stream gives a `CdrLayout` (a short CDR walk); every later
  message with the same length and the same bytes wherever the layout could differ
  (encoding, string and sequence lengths, joint names) shares it, and its float64 values are
  read at fixed offsets (`read_values`, `LayoutReader` for a stream; `read_float64s` does a
  whole bag at once); any other message goes to the full deserialiser (rclpy's or rosbags'),
  which stays the reference;
* writing: `MessageTemplate` lays a message out once (`joint_state_template`,
  `point_stamped_template`, `float64_array_template`) and then fills in the stamp and the
  float64 values of each new message.

CDR here is plain little-endian CDR (XCDR1) as Fast DDS writes it on this hardware: a 4-byte
encapsulation header (byte 1: 0x01), then the fields, each aligned to its size counted from the
byte after that header (an empty float64 sequence is not aligned; Fast CDR leaves padding bytes
unset, so they are never compared, and for messages with an empty sequence rclpy's serialiser
gave 4-8 bytes more than their fields, which a layout does not take: such messages go to the
full deserialiser). A std_msgs/Header is the stamp (int32 sec, uint32 nanosec) and the frame_id
(uint32 length including the NUL, the characters, the NUL). No ROS import: the unit tests hold
these equal to rclpy's serialiser.
"""

import dataclasses
import operator
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

CDR_LE = 1  # byte 1 of the encapsulation header: plain CDR, little endian
ENCAPSULATION = b'\x00\x01\x00\x00'
STAMP = struct.Struct('<iI')  # builtin_interfaces/Time: sec, nanosec; at byte 4 of a Header
STAMP_OFFSET = 4
_FRAME_LENGTH = (12, 16)  # byte range of the frame_id length word
# JointState's float64 sequences, in message order.
POSITION, VELOCITY, EFFORT = 0, 1, 2


@dataclass(frozen=True)
class CdrLayout:
    """Where the wanted float64 values are in messages laid out like `template`.

    size: bytes per message; checks: byte ranges that must equal the template's for a message
    to share the layout (encoding, string and sequence lengths, joint names; never padding,
    which a serialiser may leave unset); offsets: byte offset of each wanted float64; names:
    the message's names (a HumanBody's), the same in every message of the layout.
    """

    template: bytes
    size: int
    checks: tuple[tuple[int, int], ...]
    offsets: tuple[int, ...]
    names: tuple[str, ...] = ()  # a message's string sequence, where the layout checks it

    def __post_init__(self):
        # The checked byte ranges of a message in one C call (0.5 us against 2 for a loop).
        ranges = (operator.itemgetter(*(slice(start, end) for start, end in self.checks))
                  if self.checks else (lambda data: ()))
        object.__setattr__(self, '_ranges', ranges)
        object.__setattr__(self, '_expected', ranges(self.template))
        # The offsets as runs of adjacent float64s, one unpack each (a joint state's two
        # positions and two velocities: two calls, not four).
        runs = []
        for offset in self.offsets:
            if runs and offset == runs[-1][0] + 8 * runs[-1][1]:
                runs[-1][1] += 1
            else:
                runs.append([offset, 1])
        object.__setattr__(self, '_runs', tuple((struct.Struct(f'<{count}d').unpack_from, start)
                                                for start, count in runs))

    def matches(self, data: bytes) -> bool:
        """Whether `data` (one serialized message) shares this layout."""
        return len(data) == self.size and self._ranges(data) == self._expected


def read_values(data: bytes, layout: CdrLayout) -> tuple[float, ...] | None:
    """The layout's float64 values in one message, in `layout.offsets` order; None if the
    message does not share the layout."""
    if not layout.matches(data):
        return None
    values = ()
    for unpack, offset in layout._runs:
        values += unpack(data, offset)
    return values


class LayoutReader:
    """The float64 values of one stream's messages, read at the offsets of the last layout
    found: `find_layout(data)` gives a message's CdrLayout (or None) when the last one no
    longer fits."""

    def __init__(self, find_layout: Callable[[bytes], CdrLayout | None]):
        self._find_layout = find_layout
        self._layout: CdrLayout | None = None

    @property
    def layout(self) -> CdrLayout | None:
        """The layout of the last message read (None before one had a layout)."""
        return self._layout

    def read(self, data: bytes) -> tuple[float, ...] | None:
        """The wanted values of `data`; None if it has no layout that `find_layout` knows."""
        values = None if self._layout is None else read_values(data, self._layout)
        if values is None:
            layout = self._find_layout(data)
            if layout is None:
                return None
            self._layout = layout
            values = read_values(data, layout)
        return values


def read_stamp(data: bytes) -> tuple[int, int]:
    """(sec, nanosec) of a message that starts with a std_msgs/Header (checked by a layout)."""
    return STAMP.unpack_from(data, STAMP_OFFSET)


def read_frame(data: bytes) -> str:
    """The frame_id of a message that starts with a std_msgs/Header (checked by a layout)."""
    length = int.from_bytes(data[12:16], 'little')
    return bytes(data[16:15 + length]).decode('utf-8', errors='replace')


def _u32(data: bytes, at: int) -> int:
    if at + 4 > len(data):
        raise IndexError('message too short')
    return int.from_bytes(data[at:at + 4], 'little')


def _aligned(position: int, size: int) -> int:
    return 4 + -(-(position - 4) // size) * size


def _after_header(data: bytes) -> int:
    """Offset just after a std_msgs/Header (stamp and frame_id) at the start of a message."""
    return 16 + _u32(data, 12)


def point_stamped_layout(data: bytes) -> CdrLayout | None:
    """The layout of a PointStamped message (x, y wanted); None if not plain little-endian."""
    try:
        if data[1] != CDR_LE:
            return None
        point = _aligned(_after_header(data), 8)
        size = point + 24
    except IndexError:
        return None
    if size != len(data):
        return None
    return CdrLayout(bytes(data), size, ((0, 2), _FRAME_LENGTH), (point, point + 8))


def point3_layout(data: bytes) -> CdrLayout | None:
    """point_stamped_layout reading x, y and z."""
    layout = point_stamped_layout(data)
    if layout is None:
        return None
    return dataclasses.replace(layout, offsets=(*layout.offsets, layout.offsets[-1] + 8))


def _strings(data: bytes, position: int) -> tuple[list[str], list[tuple[int, int]], int]:
    """A string sequence's values at `position` (its count word), the byte ranges of its count
    and each string (its length word and characters, not the padding after it) and the offset
    after it. IndexError if the message ends first."""
    position = _aligned(position, 4)
    checks, names = [(position, position + 4)], []
    count = _u32(data, position)
    position += 4
    for _ in range(count):
        position = _aligned(position, 4)
        length = _u32(data, position)
        names.append(bytes(data[position + 4:position + 3 + length]).decode(
            'utf-8', errors='replace'))
        checks.append((position, position + 4 + length))
        position += 4 + length
    return names, checks, position


def _sequence(data: bytes, position: int) -> tuple[tuple[int, int], int, int]:
    """A sequence of float64s (or of structs of them) whose count word is at `position`
    (aligned to 4 first): the count's byte range, the count and the offset of its first
    element (aligned to 8 where there is one). IndexError if the message ends first."""
    position = _aligned(position, 4)
    count = _u32(data, position)
    start = _aligned(position + 4, 8) if count else position + 4
    return (position, position + 4), count, start


def human_body_layout(data: bytes) -> CdrLayout | None:
    """The layout of an hri_interfaces/HumanBody message (header, string[] names,
    geometry_msgs/Point[] points): every point's x, y, z wanted, point by point, and its
    names; None if not plain little-endian CDR, not whole, or with a point for other than
    each name."""
    try:
        if data[1] != CDR_LE:
            return None
        names, checks, position = _strings(data, _after_header(data))
        counted, count, position = _sequence(data, position)
        checks.append(counted)
    except IndexError:
        return None
    size = position + 24 * count
    if size != len(data) or count != len(names):
        return None
    return CdrLayout(bytes(data), size, ((0, 2), _FRAME_LENGTH, *checks),
                     tuple(position + 8 * i for i in range(3 * count)), tuple(names))


def joint_state_layout(data: bytes, joints: Sequence[str],
                       fields: Sequence[int] = (POSITION,),
                       one_value_per_name: bool = False) -> CdrLayout | None:
    """The layout of a sensor_msgs/JointState message with `fields` (POSITION, VELOCITY,
    EFFORT) of `joints` wanted: offsets field by field, joint by joint.

    None if the message is not plain little-endian CDR, does not name every joint, has a
    wanted sequence too short for them, or (`one_value_per_name`) has a wanted sequence whose
    length is not the number of names.
    """
    try:
        if data[1] != CDR_LE:
            return None
        names, checks, position = _strings(data, _after_header(data))
        checks = [(0, 2), _FRAME_LENGTH, *checks]
        sequences = []
        for _ in range(3):  # position, velocity, effort
            counted, count, position = _sequence(data, position)
            checks.append(counted)
            sequences.append((position, count))
            position += 8 * count
    except IndexError:
        return None
    if position != len(data) or not all(joint in names for joint in joints):
        return None
    index = [names.index(joint) for joint in joints]
    offsets = []
    for field in fields:
        start, count = sequences[field]
        if count <= max(index, default=-1) or (one_value_per_name and count != len(names)):
            return None
        offsets.extend(start + 8 * i for i in index)
    return CdrLayout(bytes(data), position, tuple(checks), tuple(offsets))


def float64_array_layout(data: bytes) -> CdrLayout | None:
    """The layout of a std_msgs/Float64MultiArray message (every value of `data` wanted);
    None if not plain little-endian CDR or not whole."""
    try:
        if data[1] != CDR_LE:
            return None
        position = 4
        dims = _u32(data, position)
        position += 4
        for _ in range(dims):  # MultiArrayDimension: label, size, stride
            position = _aligned(position, 4)
            position += 4 + _u32(data, position)
            position = _aligned(position, 4) + 8
        # Whatever the array layout, only the number of values matters here.
        counted, count, position = _sequence(data, _aligned(position, 4) + 4)  # data_offset
    except IndexError:
        return None
    size = position + 8 * count
    if size != len(data):
        return None
    return CdrLayout(bytes(data), size, ((0, 2), (4, 8), counted),
                     tuple(position + 8 * i for i in range(count)))


def read_float64s(raw: Sequence, layout: CdrLayout) -> tuple[np.ndarray, np.ndarray]:
    """The layout's float64 values of every message in `raw` that shares it.

    Returns (values (N, len(offsets)), NaN in rows that do not share the layout; matched (N,)
    bool). One pass over a (N, size) byte table: no per-message Python beyond its length.
    """
    count = len(raw)
    values = np.full((count, len(layout.offsets)), np.nan)
    lengths = np.fromiter(map(len, raw), dtype=np.int64, count=count)
    candidates = np.flatnonzero(lengths == layout.size)
    matched = np.zeros(count, dtype=bool)
    if candidates.size == 0:
        return values, matched
    chosen = raw if candidates.size == count else [raw[i] for i in candidates]
    table = np.frombuffer(b''.join(chosen), dtype=np.uint8).reshape(-1, layout.size)
    template = np.frombuffer(layout.template, dtype=np.uint8)
    same = np.ones(candidates.size, dtype=bool)
    for start, end in layout.checks:
        same &= np.all(table[:, start:end] == template[start:end], axis=1)
    rows = candidates[same]
    matched[rows] = True
    for column, offset in enumerate(layout.offsets):
        values[rows, column] = np.ascontiguousarray(
            table[same, offset:offset + 8]).view('<f8')[:, 0]
    return values, matched


# Writing ---------------------------------------------------------------------------------------
class _Writer:
    """A CDR byte string built field by field, remembering where the float64 runs went."""

    def __init__(self):
        self.data = bytearray(ENCAPSULATION)
        self.runs: list[tuple[int, int]] = []  # (offset, count) of each float64 run

    def _align(self, size: int) -> None:
        self.data.extend(b'\x00' * (_aligned(len(self.data), size) - len(self.data)))

    def u32(self, value: int) -> None:
        self._align(4)
        self.data.extend(struct.pack('<I', value))

    def string(self, text: str) -> None:
        encoded = text.encode('utf-8') + b'\x00'
        self.u32(len(encoded))
        self.data.extend(encoded)

    def float64s(self, count: int) -> None:
        """A run of `count` float64 values (zeros in the template), aligned if any."""
        if count:
            self._align(8)
        self.runs.append((len(self.data), count))
        self.data.extend(b'\x00' * (8 * count))

    def header(self, frame_id: str) -> None:
        self.data.extend(b'\x00' * 8)  # stamp, filled in per message
        self.string(frame_id)


class MessageTemplate:
    """One message's CDR laid out once; `encode` fills in the stamp and the float64 runs.

    Built by joint_state_template, point_stamped_template or float64_array_template. The
    values of each run must have the run's length (the template's sequence lengths).
    """

    def __init__(self, writer: _Writer, stamped: bool):
        self._template = bytes(writer.data)
        self._stamped = stamped
        self._runs = tuple((struct.Struct(f'<{count}d'), offset)
                           for offset, count in writer.runs)

    def encode(self, *runs: Sequence[float], stamp: tuple[int, int] | None = None) -> bytes:
        """The serialized message with `runs` (one sequence of floats per run) and, for a
        stamped message, `stamp` = (sec, nanosec)."""
        data = bytearray(self._template)
        if self._stamped:
            STAMP.pack_into(data, STAMP_OFFSET, *stamp)
        for (packer, offset), values in zip(self._runs, runs, strict=True):
            packer.pack_into(data, offset, *values)
        return bytes(data)


def joint_state_template(names: Sequence[str], frame_id: str = '') -> MessageTemplate:
    """sensor_msgs/JointState with `names`; runs: position, velocity, effort (one value
    per name each)."""
    writer = _Writer()
    writer.header(frame_id)
    writer.u32(len(names))
    for name in names:
        writer.string(name)
    for _ in range(3):
        writer.u32(len(names))
        writer.float64s(len(names))
    return MessageTemplate(writer, stamped=True)


def point_stamped_template(frame_id: str) -> MessageTemplate:
    """geometry_msgs/PointStamped in `frame_id`; one run: x, y, z (m)."""
    writer = _Writer()
    writer.header(frame_id)
    writer.float64s(3)
    return MessageTemplate(writer, stamped=True)


def float64_array_template(count: int) -> MessageTemplate:
    """std_msgs/Float64MultiArray with an empty layout (no dimensions, data_offset 0), as
    ros2_control's forward command controllers take it; one run: `count` values."""
    writer = _Writer()
    writer.u32(0)  # layout.dim: no dimensions
    writer.u32(0)  # layout.data_offset
    writer.u32(count)
    writer.float64s(count)
    return MessageTemplate(writer, stamped=False)

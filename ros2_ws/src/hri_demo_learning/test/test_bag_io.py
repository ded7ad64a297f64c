"""Unit tests of hri_demo_learning.bag_io: bag round trips, crash recovery and bad bags."""

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader

from hri_core.dynamics import forward_kinematics
from hri_demo_learning.bag_io import (
    BagError,
    BagWriter,
    PayloadTable,
    jazzy_typestore,
    read_bag,
    read_demonstration,
    register_message_type,
)

TYPES = jazzy_typestore()
JOINT_STATE = 'sensor_msgs/msg/JointState'
POINT_STAMPED = 'geometry_msgs/msg/PointStamped'
T0 = 1_700_000_000 * 10**9  # ns
PERIOD = 10**6  # ns: 1 kHz


def joint_state_bytes(index: int, q: np.ndarray) -> bytes:
    """A serialised JointState whose frame_id carries the sequence number `index`."""
    msg = TYPES.types[JOINT_STATE](
        header=TYPES.types['std_msgs/msg/Header'](
            stamp=TYPES.types['builtin_interfaces/msg/Time'](sec=index // 1000,
                                                             nanosec=(index % 1000) * 10**6),
            frame_id=f'seq{index:07d}'),
        name=['joint1', 'joint2'], position=np.asarray(q, dtype=float),
        velocity=np.zeros(2), effort=np.zeros(2))
    return bytes(TYPES.serialize_cdr(msg, JOINT_STATE))


def point_bytes(x: float, y: float, frame: str = 'base', z: float = 0.0) -> bytes:
    msg = TYPES.types[POINT_STAMPED](
        header=TYPES.types['std_msgs/msg/Header'](
            stamp=TYPES.types['builtin_interfaces/msg/Time'](sec=0, nanosec=0), frame_id=frame),
        point=TYPES.types['geometry_msgs/msg/Point'](x=x, y=y, z=z))
    return bytes(TYPES.serialize_cdr(msg, POINT_STAMPED))


def write_demo_bag(path: Path, count: int = 500, joints: bool = True, points: bool = True,
                   reference: bool = True, flush_every: int = 0,
                   compression: str = 'none') -> dict:
    """A bag of a straight-line motion at 1 kHz: returns the arrays that went in."""
    rng = np.random.default_rng(7)
    q = np.column_stack([np.linspace(0.2, 0.9, count), np.linspace(1.2, 0.6, count)])
    q += rng.normal(scale=1e-4, size=q.shape)
    xy = np.array([forward_kinematics(row, 0.35, 0.30) for row in q])
    x_r = np.array([[0.40, 0.20], [0.45, 0.25]])
    with BagWriter(path, compression=compression) as writer:
        js = writer.add_topic('/joint_states', JOINT_STATE) if joints else None
        ee = writer.add_topic('/ee_position', POINT_STAMPED) if points else None
        ref = writer.add_topic('/demo/reference', POINT_STAMPED) if reference else None
        for i in range(count):
            stamp = T0 + i * PERIOD
            if ref is not None and i in (10, count // 2):
                writer.write(ref, stamp, point_bytes(*x_r[0 if i == 10 else 1]))
            if js is not None:
                writer.write(js, stamp, joint_state_bytes(i, q[i]))
            if ee is not None:
                writer.write(ee, stamp + 1000, point_bytes(*xy[i]))
            if flush_every and i % flush_every == flush_every - 1:
                writer.flush()
    return {'q': q, 'xy': xy, 'x_r': x_r, 'count': count}


def test_round_trip_keeps_every_message_and_timestamp(tmp_path):
    bag = tmp_path / 'demo'
    sent = write_demo_bag(bag, count=400)
    assert (bag / 'metadata.yaml').is_file()
    contents = read_bag(bag)
    assert not contents.recovered
    assert contents.counts() == {'/joint_states': 400, '/ee_position': 400,
                                 '/demo/reference': 2}
    joints = contents.topics['/joint_states']
    assert joints.msgtype == JOINT_STATE
    assert joints.timestamps_ns == [T0 + i * PERIOD for i in range(400)]
    assert [m.header.frame_id for m in joints.messages] == [f'seq{i:07d}' for i in range(400)]
    np.testing.assert_array_equal(np.array([m.position for m in joints.messages]), sent['q'])
    np.testing.assert_allclose(joints.times()[1] - joints.times()[0], 1e-3, atol=1e-6)


def test_bare_mcap_file_reads_like_its_folder(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=100)
    assert read_bag(bag / 'demo.mcap').counts() == read_bag(bag).counts()


def test_zstd_chunks_round_trip_smaller_and_recover_after_a_cut(tmp_path):
    plain, packed = tmp_path / 'plain', tmp_path / 'packed'
    write_demo_bag(plain, count=3000, flush_every=1000)
    write_demo_bag(packed, count=3000, flush_every=1000, compression='zstd')
    assert (packed / 'packed.mcap').stat().st_size < 0.7 * (plain / 'plain.mcap').stat().st_size
    assert read_bag(packed).counts() == read_bag(plain).counts()
    with (packed / 'packed.mcap').open('rb') as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    assert len(chunks) == 3
    data = (packed / 'packed.mcap').read_bytes()
    (packed / 'metadata.yaml').unlink()
    (packed / 'packed.mcap').write_bytes(data[:chunks[2].chunk_start_offset + 100])
    contents = read_bag(packed)
    assert contents.recovered
    assert contents.counts()['/joint_states'] == 2000


def test_unknown_compression_is_refused(tmp_path):
    with pytest.raises(BagError, match='compression must be one of none, zstd'):
        BagWriter(tmp_path / 'bag', compression='lz4')


def test_writer_refuses_to_overwrite(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=10)
    before = sorted(p.name for p in bag.iterdir())
    with pytest.raises(BagError, match='exists already; refusing to overwrite'):
        BagWriter(bag).open()
    assert sorted(p.name for p in bag.iterdir()) == before


def test_unknown_types_are_registered_from_msg_files(tmp_path):
    definitions = {
        'test_msgs/msg/Sample': 'std_msgs/Header header\ntest_msgs/Inner inner\n',
        'test_msgs/msg/Inner': 'float64 value\nuint32[] counts\n',
    }
    typestore = jazzy_typestore()
    register_message_type(typestore, 'test_msgs/msg/Sample', definitions.__getitem__)
    assert 'test_msgs/msg/Inner' in typestore.fielddefs
    msg = typestore.types['test_msgs/msg/Sample'](
        header=typestore.types['std_msgs/msg/Header'](
            stamp=typestore.types['builtin_interfaces/msg/Time'](sec=1, nanosec=2),
            frame_id='f'),
        inner=typestore.types['test_msgs/msg/Inner'](value=2.5,
                                                     counts=np.array([3, 4], np.uint32)))
    bag = tmp_path / 'custom'
    with BagWriter(bag, typestore=typestore) as writer:
        connection = writer.add_topic('/sample', 'test_msgs/msg/Sample')
        writer.write(connection, T0, typestore.serialize_cdr(msg, 'test_msgs/msg/Sample'))
    # A fresh Jazzy typestore learns the type from the bag's own definition.
    back = read_bag(bag).topics['/sample'].messages[0]
    assert back.inner.value == 2.5
    assert list(back.inner.counts) == [3, 4]


def test_unknown_type_without_definition_is_a_clear_error(tmp_path):
    with BagWriter(tmp_path / 'bag') as writer, pytest.raises(BagError,
                                                              match='no message definition'):
        register_message_type(writer.typestore, 'nope_msgs/msg/Missing', {}.__getitem__)


def test_flush_makes_everything_before_it_survive_a_kill(tmp_path):
    bag = tmp_path / 'live'
    writer = BagWriter(bag).open()
    connection = writer.add_topic('/joint_states', JOINT_STATE)
    for i in range(1500):
        writer.write(connection, T0 + i * PERIOD, joint_state_bytes(i, [0.1, 0.2]))
        if i == 999:
            writer.flush()
    # What is on disk now is what a SIGKILL would leave: copy it, without metadata.yaml.
    killed = tmp_path / 'killed'
    killed.mkdir()
    shutil.copy(bag / 'live.mcap', killed / 'killed.mcap')
    writer.close()
    contents = read_bag(killed)
    assert contents.recovered
    frames = [m.header.frame_id for m in contents.topics['/joint_states'].messages]
    assert frames == [f'seq{i:07d}' for i in range(1000)]


def test_missing_metadata_of_a_closed_bag_reads_everything(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=300)
    (bag / 'metadata.yaml').unlink()
    contents = read_bag(bag)
    assert not contents.recovered
    assert contents.counts()['/joint_states'] == 300


def test_missing_metadata_and_cut_file_recovers_up_to_last_chunk(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=3000, flush_every=1000)
    data = (bag / 'demo.mcap').read_bytes()
    (bag / 'metadata.yaml').unlink()
    cut = data.find(b'seq0002500')  # inside the third chunk
    assert cut > 0
    (bag / 'demo.mcap').write_bytes(data[:cut])
    contents = read_bag(bag)
    assert contents.recovered
    assert contents.counts()['/joint_states'] == 2000
    demo = read_demonstration(bag)
    assert demo.recovered
    assert demo.times.shape == (2000,)


def test_demonstration_prefers_ee_position_and_holds_the_reference(tmp_path):
    bag = tmp_path / 'demo'
    sent = write_demo_bag(bag, count=500)
    demo = read_demonstration(bag)
    assert demo.position_source == '/ee_position'
    np.testing.assert_array_equal(demo.positions, np.column_stack([sent['xy'], np.zeros(500)]))
    assert demo.times[0] == 0.0
    np.testing.assert_allclose(np.diff(demo.times), 1e-3, atol=1e-9)
    # Before the first reference (sample 10) the first one applies; the second from 250 on.
    np.testing.assert_array_equal(demo.references[:250], np.tile([*sent['x_r'][0], 0], (250, 1)))
    np.testing.assert_array_equal(demo.references[250:], np.tile([*sent['x_r'][1], 0], (250, 1)))


def test_demonstration_from_joint_states_uses_forward_kinematics(tmp_path):
    bag = tmp_path / 'demo'
    sent = write_demo_bag(bag, count=200, points=False)
    demo = read_demonstration(bag, l1=0.35, l2=0.30)
    assert (demo.position_source, demo.kinematics) == ('/joint_states',
                                                       "the SCARA's, l1=0.35 l2=0.3 m")
    assert (demo.robot, demo.reach) == ('', None)
    np.testing.assert_allclose(demo.positions[:, :2], sent['xy'], atol=1e-12)
    assert not demo.positions[:, 2].any()
    longer = read_demonstration(bag, l1=0.5, l2=0.30)
    assert not np.allclose(longer.positions, demo.positions)


def test_path_that_does_not_exist(tmp_path):
    with pytest.raises(BagError, match='bag path does not exist'):
        read_bag(tmp_path / 'nowhere')


@pytest.mark.skipif(os.geteuid() == 0, reason='root reads every file')
def test_path_that_cannot_be_read(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=10)
    bag.chmod(0)
    try:
        with pytest.raises(BagError, match='not readable'):
            read_bag(bag)
    finally:
        bag.chmod(0o755)


def test_folder_that_is_not_a_bag(tmp_path):
    (tmp_path / 'notes.txt').write_text('hello')
    with pytest.raises(BagError, match='is not a bag: no metadata.yaml and no .mcap'):
        read_bag(tmp_path)


def test_file_that_is_not_mcap(tmp_path):
    fake = tmp_path / 'fake.mcap'
    fake.write_text('this is text, not a bag\n')
    with pytest.raises(BagError, match='not an MCAP file'):
        read_bag(fake)
    other = tmp_path / 'notes.txt'
    other.write_text('hello')
    with pytest.raises(BagError, match='not an MCAP file'):
        read_bag(other)


def test_metadata_that_is_not_rosbag2(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=10)
    (bag / 'metadata.yaml').write_text('hello: 1\n')
    with pytest.raises(BagError, match='is not a bag: invalid metadata.yaml'):
        read_bag(bag)


def test_bag_without_messages_is_empty(tmp_path):
    bag = tmp_path / 'empty'
    with BagWriter(bag) as writer:
        writer.add_topic('/ee_position', POINT_STAMPED)
    with pytest.raises(BagError, match='is empty: it holds no messages'):
        read_bag(bag)
    with pytest.raises(BagError, match='is empty'):
        read_demonstration(bag)


def test_bag_without_reference_names_the_missing_topic(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=50, reference=False)
    with pytest.raises(BagError, match='has no /demo/reference messages'):
        read_demonstration(bag)


def test_bag_without_positions_names_both_topics(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=50, joints=False, points=False)
    with pytest.raises(BagError, match='neither /ee_position nor /joint_states'):
        read_demonstration(bag)


def test_bag_of_other_topics_lists_what_it_has(tmp_path):
    bag = tmp_path / 'other'
    with BagWriter(bag) as writer:
        connection = writer.add_topic('/target', POINT_STAMPED)
        writer.write(connection, T0, point_bytes(0.1, 0.2))
    with pytest.raises(BagError, match=r'has none of the topics .* \(it has /target\)'):
        read_demonstration(bag)


def test_truncated_bag_with_metadata(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=500)
    data = (bag / 'demo.mcap').read_bytes()
    (bag / 'demo.mcap').write_bytes(data[:len(data) // 2])
    with pytest.raises(BagError, match='is truncated or corrupt'):
        read_bag(bag)


def test_killed_before_the_first_flush(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=500)
    data = (bag / 'demo.mcap').read_bytes()
    (bag / 'metadata.yaml').unlink()
    (bag / 'demo.mcap').write_bytes(data[:200])
    with pytest.raises(BagError, match='truncated: no complete MCAP chunk'):
        read_bag(bag)


def test_corrupt_message_names_topic_and_index(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=300)
    data = bytearray((bag / 'demo.mcap').read_bytes())
    at = data.find(b'seq0000123')
    data[at - 4:at] = (2**31 - 16).to_bytes(4, 'little')  # absurd string length
    (bag / 'demo.mcap').write_bytes(bytes(data))
    with pytest.raises(BagError, match=r'is corrupt: message \d+ on /joint_states'):
        read_bag(bag)


def test_corrupt_summary(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=300)
    data = bytearray((bag / 'demo.mcap').read_bytes())
    data[-300:-100] = b'\xff' * 200
    (bag / 'demo.mcap').write_bytes(bytes(data))
    with pytest.raises(BagError, match='is truncated or corrupt'):
        read_bag(bag)


def test_non_finite_positions_are_rejected(tmp_path):
    bag = tmp_path / 'nan'
    with BagWriter(bag) as writer:
        ee = writer.add_topic('/ee_position', POINT_STAMPED)
        ref = writer.add_topic('/demo/reference', POINT_STAMPED)
        writer.write(ref, T0, point_bytes(0.0, 0.0))
        writer.write(ee, T0 + 1, point_bytes(float('nan'), 0.0))
    with pytest.raises(BagError, match='non-finite'):
        read_demonstration(bag)


def test_link_lengths_must_be_positive(tmp_path):
    with pytest.raises(BagError, match='link lengths'):
        read_demonstration(tmp_path, l1=0.0)


def test_error_reasons_are_one_line():
    assert str(BagError('a\nb\n  c')) == 'a b c'


# -- the raw CDR fast path against rosbags' deserialiser ---------------------------------------

FIXTURE_BAGS = sorted((Path(__file__).resolve().parents[4] / 'bags' / 'fixtures').glob('*/'))


def assert_same_demonstration(bag, **kwargs):
    fast = read_demonstration(bag, fast=True, **kwargs)
    reference = read_demonstration(bag, fast=False, **kwargs)
    np.testing.assert_array_equal(fast.times, reference.times)
    np.testing.assert_array_equal(fast.positions, reference.positions)
    np.testing.assert_array_equal(fast.references, reference.references)
    assert (fast.position_source, fast.recovered) == (reference.position_source,
                                                      reference.recovered)
    return fast


@pytest.mark.parametrize('bag', FIXTURE_BAGS, ids=[b.name for b in FIXTURE_BAGS])
def test_fast_reader_equals_rosbags_on_the_fixture_bags(bag):
    assert_same_demonstration(bag)
    # The joint states of the same bags, through the forward kinematics.
    demo = assert_same_demonstration(bag, position_topic='/none')
    assert demo.position_source == '/joint_states' and demo.times.size > 1000


def test_fast_reader_equals_rosbags_on_a_crash_recovered_bag(tmp_path):
    bag = tmp_path / 'demo'
    write_demo_bag(bag, count=3000, flush_every=1000)
    data = (bag / 'demo.mcap').read_bytes()
    (bag / 'metadata.yaml').unlink()
    (bag / 'demo.mcap').write_bytes(data[:data.find(b'seq0002500')])
    for topic in ('/ee_position', '/none'):
        demo = assert_same_demonstration(bag, position_topic=topic)
        assert demo.recovered and demo.times.shape == (2000,)


def test_messages_written_out_of_time_order_are_read_in_time_order(tmp_path):
    """A reliable stream repaired under load reaches the recorder in order but with a later
    receive time for the repaired message: the bag's stamps are then out of order."""
    q = np.column_stack([np.linspace(0.1, 0.5, 40), np.linspace(1.0, 0.4, 40)])
    order = np.arange(40)
    order[[10, 11, 12]] = [12, 10, 11]  # message 12 arrives... stamped before 10 and 11
    bag = tmp_path / 'repaired'
    with BagWriter(bag) as writer:
        js = writer.add_topic('/joint_states', JOINT_STATE)
        ref = writer.add_topic('/demo/reference', POINT_STAMPED)
        writer.write(ref, T0, point_bytes(0.4, 0.2))
        for i in order:
            writer.write(js, T0 + int(i) * PERIOD, joint_state_bytes(int(i), q[i]))
    demo = assert_same_demonstration(bag)
    np.testing.assert_allclose(np.diff(demo.times), 1e-3, atol=1e-9)
    np.testing.assert_allclose(demo.positions[:, :2], forward_kinematics(q, 0.35, 0.30))


def test_messages_of_the_same_size_with_other_names_take_the_reference_path(tmp_path):
    """Joint names swapped: every byte count equal, only the checked name bytes differ."""
    q = np.column_stack([np.linspace(0.1, 0.5, 30), np.linspace(1.0, 0.4, 30)])
    bag = tmp_path / 'swapped'
    with BagWriter(bag) as writer:
        js = writer.add_topic('/joint_states', JOINT_STATE)
        ref = writer.add_topic('/demo/reference', POINT_STAMPED)
        writer.write(ref, T0, point_bytes(0.4, 0.2))
        for i, row in enumerate(q):
            names, position = (['joint2', 'joint1'], row[::-1]) if i % 7 == 3 else (
                ['joint1', 'joint2'], row)
            msg = TYPES.types[JOINT_STATE](
                header=TYPES.types['std_msgs/msg/Header'](
                    stamp=TYPES.types['builtin_interfaces/msg/Time'](sec=0, nanosec=0),
                    frame_id='base'),
                name=names, position=np.array(position), velocity=np.zeros(2),
                effort=np.zeros(2))
            writer.write(js, T0 + i * PERIOD, bytes(TYPES.serialize_cdr(msg, JOINT_STATE)))
    demo = assert_same_demonstration(bag)
    np.testing.assert_allclose(demo.positions[:, :2], forward_kinematics(q, 0.35, 0.30))


def test_messages_of_another_layout_take_the_reference_path(tmp_path):
    """Frame ids and joint lists of other lengths or orders: read right, one by one."""
    q = np.array([[0.1 * i, -0.2 * i] for i in range(6)])
    bag = tmp_path / 'mixed'
    with BagWriter(bag) as writer:
        js = writer.add_topic('/joint_states', JOINT_STATE)
        ref = writer.add_topic('/demo/reference', POINT_STAMPED)
        writer.write(ref, T0, point_bytes(0.4, 0.2, frame='a_much_longer_frame'))
        for i, row in enumerate(q):
            names, position = ['joint1', 'joint2'], list(row)
            if i == 2:
                names, position = ['joint2', 'wrist', 'joint1'], [row[1], 9.0, row[0]]
            if i == 4:
                names, position = [], list(row)
            msg = TYPES.types[JOINT_STATE](
                header=TYPES.types['std_msgs/msg/Header'](
                    stamp=TYPES.types['builtin_interfaces/msg/Time'](sec=0, nanosec=0),
                    frame_id='x' * i),
                name=names, position=np.array(position), velocity=np.zeros(0),
                effort=np.zeros(0))
            writer.write(js, T0 + i * PERIOD, bytes(TYPES.serialize_cdr(msg, JOINT_STATE)))
    demo = assert_same_demonstration(bag)
    np.testing.assert_allclose(demo.positions[:, :2], forward_kinematics(q, 0.35, 0.30))


def rosbags_messages(bag: Path) -> dict[str, tuple[list[int], list[bytes]]]:
    """{topic: (timestamps ns, raw CDR)} through rosbags' own reader (the reference)."""
    messages: dict[str, tuple[list[int], list[bytes]]] = {}
    with Reader(bag) as reader:
        for connection, stamp, data in reader.messages():
            stamps, payloads = messages.setdefault(connection.topic, ([], []))
            stamps.append(stamp)
            payloads.append(bytes(data))
    return messages


@pytest.mark.parametrize('bag', FIXTURE_BAGS, ids=[b.name for b in FIXTURE_BAGS])
def test_mcap_walk_reads_what_rosbags_reads(bag):
    kinds = {JOINT_STATE, POINT_STAMPED}
    contents = read_bag(bag, raw_types=kinds)
    reference = rosbags_messages(bag)
    assert set(contents.topics) == set(reference)
    for topic, (stamps, payloads) in reference.items():
        series = contents.topics[topic]
        assert series.timestamps_ns == stamps, topic
        kept = series.raw if series.msgtype in kinds else [
            bytes(TYPES.serialize_cdr(m, series.msgtype)) for m in series.messages]
        assert [bytes(p) for p in kept] == payloads, topic


def test_mcap_walk_reads_zstd_chunks_as_rosbags_reads_them(tmp_path):
    bag = tmp_path / 'zstd'
    write_demo_bag(bag, count=500, flush_every=100, compression='zstd')
    contents = read_bag(bag, raw_types={JOINT_STATE, POINT_STAMPED})
    reference = rosbags_messages(bag)
    for topic, (stamps, payloads) in reference.items():
        # The walk's table of payloads, not rosbags' list of them.
        assert isinstance(contents.topics[topic].raw, PayloadTable), topic
        assert contents.topics[topic].timestamps_ns == stamps
        assert [bytes(p) for p in contents.topics[topic].raw] == payloads


def test_a_zstd_chunk_that_does_not_inflate_to_its_size_is_refused_in_one_line(tmp_path):
    bag = tmp_path / 'zstd'
    write_demo_bag(bag, count=500, flush_every=100, compression='zstd')
    mcap = bag / 'zstd.mcap'
    with mcap.open('rb') as stream:
        first = make_reader(stream).get_summary().chunk_indexes[0]
    data = bytearray(mcap.read_bytes())
    # The chunk record's uncompressed size: after its opcode, length, start and end time.
    size_at = first.chunk_start_offset + 9 + 16
    size = int.from_bytes(data[size_at:size_at + 8], 'little')
    data[size_at:size_at + 8] = (size + 1).to_bytes(8, 'little')
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagError, match='is truncated or corrupt: .*does not inflate') as error:
        read_bag(bag)
    assert '\n' not in str(error.value)

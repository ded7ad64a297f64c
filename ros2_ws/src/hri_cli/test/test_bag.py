"""Unit tests of the `ros2 bag` stand-in (hri_cli.bag) without ROS.

Nothing here calls rclpy.init(): the tests cover the bag summary and its text, the playback QoS
and timing, and info failing in one line. tests/test_ros2_cli.py plays and records against
live nodes.
"""

from datetime import UTC
from pathlib import Path

import pytest

pytest.importorskip('rclpy')
pytest.importorskip('rosbags')

from rclpy.qos import (  # noqa: E402
    DurabilityPolicy,
    HistoryPolicy,
    ReliabilityPolicy,
)
from rosbags.interfaces import (  # noqa: E402
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader  # noqa: E402

from hri_cli import bag  # noqa: E402
from hri_cli.bag import (  # noqa: E402
    BagSummary,
    TopicSummary,
    format_bag_info,
    format_file_size,
    format_seconds,
    format_time_point,
    playback_offset,
    playback_qos,
    qos_overrides,
    read_bag_summary,
)

REPO_ROOT = Path(__file__).resolve().parents[4]
FOLLOW_BAG = REPO_ROOT / 'bags' / 'fixtures' / 'follow'


def test_bag_errors_are_one_line_and_exit_1(tmp_path, capsys):
    assert bag.main(['info', str(tmp_path / 'none')]) == 1
    assert capsys.readouterr().err == f'bag path does not exist: {tmp_path / "none"}\n'
    (tmp_path / 'metadata.yaml').write_text('rosbag2_bagfile_information: {version: 8}\n')
    assert bag.main(['info', str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f'cannot read bag {tmp_path}: ') and err.count('\n') == 1


# --------------------------------------------------------------------------------------------
# bag info and play


@pytest.mark.parametrize(('size', 'text'), [
    (0, '0 B'), (1023, '1023 B'), (1024, '1.0 KiB'), (885240, '864.5 KiB'),
    (3 * 1024**2 + 1, '3.0 MiB'), (5 * 1024**3, '5.0 GiB'), (2 * 1024**5, '2048.0 TiB'),
])
def test_file_sizes_as_rosbag2_prints_them(size, text):
    assert format_file_size(size) == text


def test_durations_and_time_points_to_the_nanosecond():
    assert format_seconds(11_113_467_132) == '11.113467132'
    assert format_seconds(5) == '0.000000005'
    assert format_time_point(1_795_437_796_407_210_834, UTC) == (
        'Nov 23 2026 12:43:16.407210834 (1795437796.407210834)')
    assert format_time_point(1_704_067_200_000_000_001, UTC) == (
        'Jan  1 2024 00:00:00.000000001 (1704067200.000000001)')


def test_bag_info_text_is_rosbag2s():
    summary = BagSummary(
        files=('a.mcap', 'b.mcap'), size_bytes=2048, storage_id='mcap', ros_distro='',
        start_ns=1_704_067_200_000_000_000, duration_ns=1_500_000_000, message_count=30,
        topics=(TopicSummary('/z', 'std_msgs/msg/String', 10),
                TopicSummary('/a', 'sensor_msgs/msg/JointState', 20)))
    assert format_bag_info(summary, UTC) == '\n'.join([
        '',
        'Files:             a.mcap',
        '                   b.mcap',
        'Bag size:          2.0 KiB',
        'Storage id:        mcap',
        'ROS Distro:        unknown',
        'Duration:          1.500000000s',
        'Start:             Jan  1 2024 00:00:00.000000000 (1704067200.000000000)',
        'End:               Jan  1 2024 00:00:01.500000000 (1704067201.500000000)',
        'Messages:          30',
        'Topic information: Topic: /a | Type: sensor_msgs/msg/JointState | Count: 20 | '
        'Serialization Format: cdr',
        '                   Topic: /z | Type: std_msgs/msg/String | Count: 10 | '
        'Serialization Format: cdr',
        'Service:           0',
        'Service information: ',
    ])


@pytest.mark.skipif(not FOLLOW_BAG.is_dir(), reason='bags/fixtures/follow is not there')
def test_the_summary_of_the_follow_fixture_counts_what_rosbags_reads():
    summary = read_bag_summary(FOLLOW_BAG)
    counts: dict[str, int] = {}
    with Reader(FOLLOW_BAG) as reader:
        for connection, _, _ in reader.messages():
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
        stamps = [stamp for _, stamp, _ in reader.messages()]
    assert {t.name: t.count for t in summary.topics} == counts
    assert summary.message_count == sum(counts.values())
    assert (summary.start_ns, summary.start_ns + summary.duration_ns) == (stamps[0],
                                                                          stamps[-1])
    assert summary.files == ('follow.mcap',)
    assert summary.size_bytes == (FOLLOW_BAG / 'follow.mcap').stat().st_size
    assert (summary.storage_id, summary.ros_distro) == ('mcap', 'rosbags')
    assert read_bag_summary(FOLLOW_BAG / 'follow.mcap').topics == summary.topics


def recorded_offer(reliability: QosReliability, durability: QosDurability) -> Qos:
    """An offer as rosbags reads it from metadata.yaml (history unknown, depth 0)."""
    forever = QosTime(sec=9223372036, nsec=854775807)
    return Qos(history=QosHistory.UNKNOWN, depth=0, reliability=reliability,
               durability=durability, deadline=forever, lifespan=forever,
               liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=forever,
               avoid_ros_namespace_conventions=False)


def test_playback_qos_takes_the_recorded_reliability_and_durability_with_depth_10():
    def policies(profile):
        return profile.reliability, profile.durability, profile.depth

    reliable, volatile = ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE
    assert policies(playback_qos([])) == (reliable, volatile, 10)
    assert policies(playback_qos([recorded_offer(QosReliability.BEST_EFFORT,
                                                 QosDurability.TRANSIENT_LOCAL)])) == (
        ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.TRANSIENT_LOCAL, 10)
    assert policies(playback_qos([recorded_offer(QosReliability.RELIABLE,
                                                 QosDurability.VOLATILE)] * 2)) == (
        reliable, volatile, 10)
    disagreeing = [recorded_offer(QosReliability.BEST_EFFORT, QosDurability.VOLATILE),
                   recorded_offer(QosReliability.RELIABLE, QosDurability.VOLATILE)]
    assert policies(playback_qos(disagreeing)) == (reliable, volatile, 10)
    unknown = [recorded_offer(QosReliability.SYSTEM_DEFAULT, QosDurability.UNKNOWN)]
    assert policies(playback_qos(unknown)) == (reliable, volatile, 10)


def test_qos_overrides_take_rosbag2s_policy_names_and_refuse_anything_else():
    overrides = qos_overrides({'/joint_states': {'history': 'keep_last', 'depth': 10000},
                               '/demo/reference': {'history': 'keep_all',
                                                   'reliability': 'best_effort',
                                                   'durability': 'transient_local'}})
    assert overrides == {
        '/joint_states': {'history': HistoryPolicy.KEEP_LAST, 'depth': 10000},
        '/demo/reference': {'history': HistoryPolicy.KEEP_ALL,
                            'reliability': ReliabilityPolicy.BEST_EFFORT,
                            'durability': DurabilityPolicy.TRANSIENT_LOCAL}}
    assert qos_overrides({}) == {}
    with pytest.raises(ValueError, match='must map topic names'):
        qos_overrides(['/joint_states'])
    with pytest.raises(ValueError, match="/a: depth must be an integer >= 1, got 0"):
        qos_overrides({'/a': {'depth': 0}})
    with pytest.raises(ValueError, match='depth must be an integer'):
        qos_overrides({'/a': {'depth': True}})
    with pytest.raises(ValueError, match="history must be one of keep_last, keep_all, got 'all'"):
        qos_overrides({'/a': {'history': 'all'}})
    with pytest.raises(ValueError, match="unsupported QoS policy 'deadline'"):
        qos_overrides({'/a': {'deadline': {'sec': 1, 'nsec': 0}}})
    with pytest.raises(ValueError, match='expected a topic name mapped to QoS policies'):
        qos_overrides({'/a': 'reliable'})


def test_playback_offsets_are_the_recorded_offsets_divided_by_the_rate():
    start = 1_795_437_796_407_210_834
    assert playback_offset(start, start, 1.0) == 0.0
    assert playback_offset(start + 2_000_000_000, start, 1.0) == pytest.approx(2.0)
    assert playback_offset(start + 2_000_000_000, start, 4.0) == pytest.approx(0.5)
    assert playback_offset(start + 1_000_000, start, 0.5) == pytest.approx(0.002)
    with pytest.raises(ValueError, match='rate must be > 0'):
        playback_offset(start, start, 0.0)

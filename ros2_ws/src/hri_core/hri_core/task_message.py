"""A task record as the TaskParameters message, and back.

The learner publishes learned tasks on /hri/task and the event manager takes them from there;
both use these conversions (and `topics.TASK`), so that the two ends cannot drift apart.
"""

from hri_interfaces.msg import TaskParameters

from hri_core.task_file import TaskRecord


def task_message(record: TaskRecord, stamp=None) -> TaskParameters:
    """The TaskParameters message of a task record (`stamp`: builtin_interfaces/Time)."""
    msg = TaskParameters(name=record.name, s=int(record.s), a1=float(record.a1),
                         a2=float(record.a2), d1=float(record.d1), d2=float(record.d2),
                         n=int(record.n), cost=float(record.cost),
                         iterations=int(record.iterations), k=float(record.k))
    if stamp is not None:
        msg.header.stamp = stamp
    return msg


def task_record(msg: TaskParameters) -> TaskRecord:
    """The task record of a TaskParameters message; ValueError with the reason if invalid."""
    return TaskRecord(name=msg.name, s=int(msg.s), a1=msg.a1, a2=msg.a2, d1=msg.d1,
                      d2=msg.d2, n=int(msg.n), cost=msg.cost, iterations=int(msg.iterations),
                      k=msg.k)

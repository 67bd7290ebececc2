"""Records shared by the bag readers: one raw message, one topic, and what a damaged file gave back."""

from __future__ import annotations

from typing import NamedTuple

__all__ = ['BagMessage', 'BagTopic', 'FileRecovery']


class BagMessage(NamedTuple):
    """One serialised message as stored in a bag.

    Attributes:
        topic: topic name.
        msgtype: rosbags type name (``sensor_msgs/msg/Image``).
        log_time_ns: the recorder's receive time, nanoseconds.
        data: the CDR bytes.
    """

    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes


class BagTopic(NamedTuple):
    """A topic of a bag: name and rosbags type name."""

    topic: str
    msgtype: str


class FileRecovery(NamedTuple):
    """What was read back from a damaged storage file (a truncated MCAP, a sqlite3 file with broken pages).

    Attributes:
        path: the storage file.
        reason: why the normal reader refused it (its error message).
        messages: messages recovered.
        bytes_read: the file is readable up to this byte (end of the last whole record / page used).
        bytes_total: the file's size.
        lost_records: records (chunks, pages, messages) that were found but could not be read.
    """

    path: str
    reason: str
    messages: int
    bytes_read: int
    bytes_total: int
    lost_records: int

    def describe(self) -> str:
        """One line for the log: how much was recovered."""
        lost = f', {self.lost_records} damaged record(s) skipped' if self.lost_records else ''
        return (f'{self.path}: damaged ({self.reason}); recovered {self.messages} message(s), readable up to byte '
                f'{self.bytes_read} of {self.bytes_total}{lost}')

"""Reading rosbag2 recordings, including damaged ones (a recorder that lost power): ROS-free, rosbags + mcap.

- :func:`open_bag`: a bag directory or file, read by rosbags when it is sound, by recovery when it is not.
- :class:`McapRecovery`: an MCAP without footer / summary, cut in a chunk, read record by record.
- :class:`SqliteRecovery`: a sqlite3 file with missing pages, read leaf page by leaf page.
"""

from fruitnerfpp_ros.core.bags.mcap_recovery import McapRecovery
from fruitnerfpp_ros.core.bags.reader import BagSource, open_bag, storage_files
from fruitnerfpp_ros.core.bags.records import BagMessage, BagTopic, FileRecovery
from fruitnerfpp_ros.core.bags.sqlite_recovery import SqliteRecovery

__all__ = ['BagMessage', 'BagSource', 'BagTopic', 'FileRecovery', 'McapRecovery', 'SqliteRecovery', 'open_bag',
           'storage_files']

"""rosbag2-compatible MCAP bags, with no ROS: write, read a torn file, reindex.

``metadata`` (the bag directory: ``metadata.yaml``, its files, the run records),
``writer`` (:class:`BagWriter`, durable, chunks closed every ``flush_period``), ``chunks``
(the writer's chunks below the mcap writer's API: message records in bulk, a chunk
detached and written apart), ``reader`` (:func:`read_bag`, every complete record of a torn
file) and ``reindex`` (finish a torn bag in place).
"""

from rigidrot_ros.bag.metadata import (bag_files, BagError, qos_yaml, run_from_string,
                                       RUN_RECORD, STRING_TYPE)
from rigidrot_ros.bag.reader import BagContents, read_bag
from rigidrot_ros.bag.reindex import reindex
from rigidrot_ros.bag.writer import BagWriter

__all__ = ['BagWriter', 'BagError', 'read_bag', 'BagContents', 'qos_yaml', 'RUN_RECORD',
           'bag_files', 'reindex', 'run_from_string', 'STRING_TYPE']

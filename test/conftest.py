"""Session-wide test setup: an isolated ROS 2 graph and the shared (expensive) fixtures.

ROS: every test session picks a random ``ROS_DOMAIN_ID`` and limits discovery to localhost, before anything
imports rclpy, so concurrent test runs on one machine never see each other's nodes.
"""

from __future__ import annotations

import os
import random

os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(1, 101)))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('AMENT_PREFIX_PATH', os.environ.get('VIRTUAL_ENV', ''))
# Keep the numba JIT cache of fast-hdbscan between sessions; 2-core CI machine: no oversubscription.
os.environ.setdefault('OMP_NUM_THREADS', '2')

pytest_plugins = ['test.shared_fixtures']

"""ament_python package definition for fruitnerfpp_ros (colcon and pip both read it)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'fruitnerfpp_ros'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench']),
    package_data={PACKAGE: ['py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', glob('config/*.yaml')),
        (f'share/{PACKAGE}/launch', glob('launch/*.launch.py')),
        (f'share/{PACKAGE}/rviz', glob('rviz/*.rviz')),
        (f'share/{PACKAGE}/foxglove', glob('foxglove/*.json')),
    ],
    # Python dependencies live in requirements.txt (ranges) and constraints-cpu.txt (exact CPU pins);
    # on a robot, rclpy and the message packages come from the ROS 2 installation.
    install_requires=['setuptools'],
    # `pip install .[scale]`: segments of a row as Ray tasks (fruitnerfpp orchard); without it they run in-process
    extras_require={'scale': ['ray>=2.9']},
    zip_safe=False,
    maintainer='fruitnerfpp_ros maintainers',
    maintainer_email='maintainers@fruitnerfpp.invalid',
    description='FruitNeRF++ fruit counting for ROS 2 Jazzy',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'fruitnerfpp = fruitnerfpp_ros.cli.main:main',
            'fruit_counter = fruitnerfpp_ros.nodes.fruit_counter:main',
            'orchard_sim = fruitnerfpp_ros.nodes.orchard_sim:main',
            'bag_replay = fruitnerfpp_ros.cli.replay:main',
        ],
    },
)

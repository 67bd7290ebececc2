"""FruitNeRF++ fruit counting for ROS 2: a ROS-free core (``core``) and a thin ROS layer (``nodes``)."""

__version__ = '0.1.0'

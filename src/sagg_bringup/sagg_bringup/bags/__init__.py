"""The bags: recording topics into mcap rosbag2 bags, reading and recovering them, the recorded
topic set, ``sagg replay`` and ``sagg relearn``."""

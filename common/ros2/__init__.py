"""ovis as ROS 2 sees it: standard messages (CDR), type hashes and definitions, and how
ovis's floor frame maps to a ROS frame. Pure: no Zenoh, no processes."""

"""ovis as ROS 2 sees it: its messages as standard ROS 2 messages in CDR, with their type
hashes and definitions (``convert``; built on ``cdr``, and ``obstacles`` for the
per-frame ones), and how ovis's floor frame maps to a REP 103 frame, with the accuracy
of a pose there (``floor``); a stream of them with the visual topics' rates (``stream``)
and a rosbag2 bag of them (``bag``); the rmw_zenoh wire layout they travel in (``wire``:
keys, attachments, liveliness tokens) and which topic has which QoS (``topics``); camera
images received from ROS 2 as frames (``images``). Pure: no Zenoh, no processes.
May import: ``config``, ``camera``, ``calibration``, ``messages``, ``fusion``, ``vision``.
"""

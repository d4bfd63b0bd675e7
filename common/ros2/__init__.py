"""ROS 2 without ROS 2 installed: ovis's messages as standard ROS 2 messages in CDR
(``convert``, through rosbags) and the rmw_zenoh wire layout they travel in (``wire``:
keys, attachments, liveliness tokens), so that a ROS 2 graph sees ovis as a node.
May import: ``config``, ``camera``, ``vision``, ``world``, ``calibration``, ``messages``.
"""

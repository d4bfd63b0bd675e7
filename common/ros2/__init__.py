"""ovis as ROS 2 sees it: its messages as standard ROS 2 messages in CDR, with their type
hashes and definitions (``convert``), and how ovis's floor frame maps to a REP 103 frame,
with the accuracy of a pose there (``floor``); the rmw_zenoh wire layout they travel in
(``wire``: keys, attachments, liveliness tokens) and which topic has which QoS
(``topics``); camera images received from ROS 2 as frames (``images``). Pure: no Zenoh,
no processes.
May import: ``config``, ``camera``, ``calibration``, ``messages``, ``fusion``, ``vision``.
"""

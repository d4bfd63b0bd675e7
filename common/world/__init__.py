"""From blobs to the floor: robot vs obstacles and identities (``pose``), the unmarked
robot's heading and velocity over frames (``unmarked``), the motion planner's distance
and angle (``planner``, paper §5.2), and one frame → robot, obstacles and planner inputs
(``detection``).
May import: ``config``, ``camera``, ``vision``.
"""

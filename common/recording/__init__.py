"""Recording sessions to MCAP files and replaying them: the channels' schemas
(``schemas``), the Foxglove views of frames and obstacles (``foxglove``), the file
writer and reader (``session``) and the replay's pacing and frame selection
(``pacing``).
May import: ``config``, ``atomic``, ``camera``, ``vision``, ``world``, ``calibration``,
``sim``, ``messages``.
"""

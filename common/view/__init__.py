"""What the live web view (``ovis view``) shows, as pure logic: a frame downscaled and
JPEG-encoded with what was detected drawn on it (``picture``), the objects of an
obstacle message and the camera's footprint on the floor (``scene``), the map's grid
step (``grid``), how current each stream is — live, stalled, late or a replay
(``freshness``) — and the health of every stage (``health``). The server that sends
them to browsers is in ``ovis.services.view``.
May import: ``config``, ``camera``, ``calibration``, ``messages``.
"""

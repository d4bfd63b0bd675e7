"""What a running stage computes and keeps, without the bus: the per-message steps of
the frame path (``stages``), a stage's counters and status (``counters``), the stream's
health (``health``), the capture's pacing (``pacing``), the calibrator's kept frames and
replies (``recalibration``), the supervisor's restart rule (``restarts``) and which
cameras a stage process serves with each one's configuration (``hosting``). The
services in ``ovis.services`` wire these to Zenoh.
May import: ``config``, ``atomic``, ``camera``, ``vision``, ``world``, ``calibration``,
``sim``, ``capture``, ``messages``, ``trust``.
"""

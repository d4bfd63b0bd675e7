"""Robots driven to their goals among moving obstacles on what ovis sees (the paper's
§7 (1): its vision coupled with a motion planner; docs/navigation.md).

The scenarios of the paper's two cases (``scenarios``); what a planner is given, from
ovis's detections or from the physics truth (``observe``); the genetic-fuzzy planner
of Pratihar, Deb & Ghosh (1999) on the paper's distance and angle of the most critical
obstacle (``critical``, ``fuzzy``), the dynamic window baseline (``dwa``) and the
straight-to-goal driver behind one interface (``planners``, with the shared heading
control of ``steering``); the robot's own side: wheel speeds within its limits, the
watchdog and the frame-age rule (``base``); the planner tuned by ovis's GA on a fast
kinematic simulation (``training``, ``tuning``); runs in the physical world in
lock-step simulated time (``episode``) and their figures (``report``, ``plots``).
May import: ``config``, ``atomic``, ``camera``, ``vision``, ``world``, ``calibration``,
``sim``, ``physical``.
"""

"""Frame sources for the capture service (``sources``): the simulated arena, a folder of
images, a video file, a camera or a network stream; and the wait between attempts to
reopen one that failed (``backoff``).
May import: ``config``, ``atomic``, ``camera``, ``sim``, ``vision``.
"""

"""Frame sources for the capture service (``sources``): the simulated arena, a folder of
images, a video file or a camera.
May import: ``config``, ``atomic``, ``camera``, ``sim``, ``vision``.
"""

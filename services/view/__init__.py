"""``ovis view``: a web page that shows what ovis sees, live.

``feed`` follows each arena on the bus (a subscriber like any other: it adds no work to
the frame path), ``pictures`` turns its newest frame into a JPEG with the detections
drawn on it, ``server`` serves the page (``static/``) and pushes updates to browsers
over a WebSocket (Starlette on uvicorn).
"""

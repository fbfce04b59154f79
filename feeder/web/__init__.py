"""The operator's console in the browser (docs/console.md): an ASGI app and its static page,
a client of the daemon's request handler.

``server`` (uvicorn on its own thread, started by ``feeder daemon --http``) serves ``app``
(the routes), guarded by ``security`` (token, Origin, rate limit), with ``requests`` (bodies
checked, jogs), ``camera`` (live JPEG frames) and ``static/`` (the page).
"""

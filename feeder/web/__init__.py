"""The operator's console in the browser (docs/console.md): an ASGI app and its static page,
a client of the daemon's request handler."""

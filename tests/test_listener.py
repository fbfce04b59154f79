"""The tests' helper servers end their accepting threads on close (tests/listener.py)."""

from __future__ import annotations

import socket
import threading

from listener import Listener


def test_close_ends_the_accepting_thread_and_refuses_later_connections() -> None:
    accepted: list[socket.socket] = []
    arrived = threading.Event()

    def on_connect(conn: socket.socket) -> None:
        accepted.append(conn)
        arrived.set()

    before = threading.active_count()
    listener = Listener(socket.create_server(("127.0.0.1", 0)), on_connect)
    port = listener.port
    with socket.create_connection(("127.0.0.1", port), timeout=2.0):
        assert arrived.wait(2.0)
    listener.close()
    assert threading.active_count() == before  # blocked in accept() it would still count
    assert len(accepted) == 1
    for conn in accepted:
        conn.close()
    try:
        socket.create_connection(("127.0.0.1", port), timeout=2.0).close()
    except ConnectionRefusedError:
        return
    raise AssertionError("a closed listener still accepts")

"""Serve one viewer page on localhost (``http.server``, no dependency).

The page is held in memory and served at ``/`` and ``/index.html``; anything else is 404. The
server binds 127.0.0.1 only, so the page is not reachable from other machines.
"""

from __future__ import annotations

from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

HOST = "127.0.0.1"


def make_server(page: bytes, port: int = 0) -> ThreadingHTTPServer:
    """A server for ``page`` on ``127.0.0.1:port`` (0: a free port; see :func:`server_url`).

    Call ``serve_forever()`` to serve, ``shutdown()`` from another thread and ``server_close()`` to stop.
    Raises ``OSError`` when the port cannot be bound.
    """

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            if self.path.split("?", 1)[0] not in ("/", "/index.html"):
                self.send_error(404, "only / is served")
                return
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(page)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(page)

        def log_message(self, format: str, *args: object) -> None:  # quiet: no line per request
            pass

    server = ThreadingHTTPServer((HOST, port), Handler)
    server.daemon_threads = True
    return server


def server_url(server: ThreadingHTTPServer) -> str:
    """``http://127.0.0.1:PORT/`` of a server made by :func:`make_server`."""
    return f"http://{HOST}:{server.server_address[1]}/"

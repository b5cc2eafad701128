"""`leaderboard serve`: preview the rendered site with Python's http.server.

Binds to localhost by default: a preview, not a production web server.
"""

from __future__ import annotations

import functools
import os
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path


class _Handler(SimpleHTTPRequestHandler):
    extensions_map = {**SimpleHTTPRequestHandler.extensions_map, ".js": "text/javascript",
                      ".md": "text/markdown; charset=utf-8"}

    def log_message(self, fmt, *args) -> None:  # one short line per request
        print(f"{self.address_string()} {fmt % args}", flush=True)


def make_server(directory: str | os.PathLike, port: int = 8000,
                host: str = "127.0.0.1") -> ThreadingHTTPServer:
    """An HTTP server for a rendered site (``port=0`` picks a free port: ``server_port``)."""
    d = Path(directory)
    if not (d / "index.html").is_file():
        raise ValueError(f"{d}: no index.html (run `leaderboard render --out {d}` first)")
    return ThreadingHTTPServer((host, port), functools.partial(_Handler, directory=str(d)))


def serve(directory: str | os.PathLike, port: int = 8000, host: str = "127.0.0.1") -> None:
    try:
        server = make_server(directory, port, host)
    except OSError as exc:
        raise ValueError(f"cannot listen on {host}:{port} ({exc.strerror or exc})") from None
    print(
        f"serving {directory} at http://{host}:{server.server_port}/ (Ctrl-C to stop)", flush=True
    )
    with server:
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass

"""`leaderboard serve`: preview the rendered site with Python's http.server.

Binds to localhost by default: a preview, not a production web server. Symbolic links are
never followed (a request through one is answered 404, a site folder that is one is refused):
http.server would serve a link's target, anywhere on the disk.
"""

from __future__ import annotations

import functools
import os
from http import HTTPStatus
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path


def through_link(root: str, path: str) -> bool:
    """Whether ``path`` (inside ``root``, as ``translate_path`` makes it) or any folder between
    ``root`` and it is a symbolic link; for a folder, also its index file."""
    rel = os.path.relpath(path, root)
    current = root
    for part in [] if rel == os.curdir else rel.split(os.sep):
        current = os.path.join(current, part)
        if os.path.islink(current):
            return True
    return os.path.isdir(path) and any(
        os.path.islink(os.path.join(path, index)) for index in ("index.html", "index.htm")
    )


class _Handler(SimpleHTTPRequestHandler):
    extensions_map = {
        **SimpleHTTPRequestHandler.extensions_map,
        ".js": "text/javascript",
        ".md": "text/markdown; charset=utf-8",
    }

    def send_head(self):
        """As http.server's, but 404 for anything reached through a symbolic link."""
        if through_link(os.path.abspath(self.directory), self.translate_path(self.path)):
            self.send_error(HTTPStatus.NOT_FOUND, "File not found")
            return None
        return super().send_head()

    def log_message(self, fmt, *args) -> None:  # one short line per request
        print(f"{self.address_string()} {fmt % args}", flush=True)


def make_server(
    directory: str | os.PathLike, port: int = 8000, host: str = "127.0.0.1"
) -> ThreadingHTTPServer:
    """An HTTP server for a rendered site (``port=0`` picks a free port: ``server_port``)."""
    d = Path(directory)
    if d.is_symlink():
        raise ValueError(f"{d}: a symbolic link; serve a real site folder (its target)")
    if not (d / "index.html").is_file():
        raise ValueError(f"{d}: no index.html (run `leaderboard render --out {d}` first)")
    return ThreadingHTTPServer(
        (host, port), functools.partial(_Handler, directory=str(d.absolute()))
    )


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

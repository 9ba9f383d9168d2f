"""The local page of ``resection link --serve``: link a frame's targets by clicking.

A :class:`LinkServer` serves one :class:`~resection.markers.link_session.LinkSession` from the
standard library's :class:`http.server.ThreadingHTTPServer`:

* it binds to ``127.0.0.1`` only, on a free port unless one is given;
* every request must carry the session's random token (``?token=`` in the URL, or the
  ``X-Link-Token`` header for the page's requests) and a ``Host`` header naming the
  loopback address (a page of another site cannot reach it through DNS rebinding); others
  get ``403``;
* the page (``resection/markers/link_page/``: plain HTML, CSS and JavaScript, an SVG overlay, no
  build step, nothing fetched from the network) comes from the package; the only files
  read are those the session was opened with, and no path ever arrives from the browser;
* JSON endpoints: ``GET /api/session``, ``/api/candidates``, ``/api/plan``, ``/api/frame``
  (the frame as uint16), ``POST /api/solve`` and ``/api/save`` with ``{"links": [[id,
  candidate], ...]}`` (``"quit": true`` with a save: stop the server once it is written);
* at most :data:`MAX_CONNECTIONS` connections are served at once (more: 503 and closed);
* a request is read within :data:`REQUEST_TIMEOUT` seconds (a body shorter than its
  ``Content-Length``, an idle connection: closed, 408 when a reply can still be sent),
  a body is at most 1 MiB of JSON, nested at most a few levels (deeper: 400, never a
  traceback).

:func:`serve_links` starts it (and a browser only when asked); :meth:`LinkServer.url` is
the address to open.
"""

from __future__ import annotations

import hmac
import json
import secrets
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, urlsplit

from resection.errors import InputError, SolveError
from resection.markers.link_session import LinkSession

__all__ = ["LinkServer", "serve_links", "PAGE_FILES"]

#: The page's files (package data in ``resection/markers/link_page/``) and their content types.
PAGE_FILES = {"index.html": "text/html; charset=utf-8",
              "link.js": "text/javascript; charset=utf-8",
              "link.css": "text/css; charset=utf-8"}
_MAX_BODY = 1 << 20  # bytes of a POST body
_MAX_DEPTH = 8  # nesting of a POST body: {"links": [[id, candidate], ...]} is 3
#: Seconds a connection may take to send a request, or stay idle between requests.
REQUEST_TIMEOUT = 30.0
#: Connections served at once (a page opens a few): more are answered 503 and closed.
MAX_CONNECTIONS = 32
_BAD_BODY = "expected a JSON body {\"links\": [...]}"
_HOSTS = ("127.0.0.1", "localhost")


def _page_file(name: str) -> bytes:
    return resources.files("resection.markers").joinpath("link_page", name).read_bytes()


def _depth_ok(text: bytes, limit: int = _MAX_DEPTH) -> bool:
    """Whether the JSON text nests no deeper than ``limit`` (brackets outside strings),
    told before parsing: a deep body would exhaust the parser's recursion."""
    import re

    import numpy as np

    bare = re.sub(rb'"(?:[^"\\]|\\.)*"', b"", text)  # strings out, escaped quotes too
    c = np.frombuffer(bare, np.uint8)
    step = (np.isin(c, (0x5B, 0x7B)).astype(np.int64)  # [ {
            - np.isin(c, (0x5D, 0x7D)))  # ] }
    return step.size == 0 or int(np.cumsum(step).max()) <= limit


class _Handler(BaseHTTPRequestHandler):
    server: LinkServer  # type: ignore[assignment]
    protocol_version = "HTTP/1.1"

    @property
    def timeout(self) -> float:  # read by StreamRequestHandler.setup: the socket's timeout
        return self.server.request_timeout

    def log_message(self, format, *args):  # noqa: A002 - the base class's name
        if self.server.verbose:
            super().log_message(format, *args)

    # ---------------------------------------------------------------- replies
    def _send(self, status: int, body: bytes, ctype: str, extra: dict | None = None):
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Content-Security-Policy",
                         "default-src 'self'; img-src 'self' data: blob:; "
                         "connect-src 'self'; style-src 'self'; script-src 'self'")
        for k, v in (extra or {}).items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, obj, status: int = 200):
        self._send(status, json.dumps(obj, allow_nan=False).encode(), "application/json")

    def _error(self, status: int, message: str):
        self._json({"error": message}, status)

    # ---------------------------------------------------------------- checks
    def _allowed(self) -> bool:
        """Loopback host header and the session's token, else 403."""
        host = (self.headers.get("Host") or "").rsplit(":", 1)[0].strip("[]")
        query = parse_qs(urlsplit(self.path).query)
        token = self.headers.get("X-Link-Token") or (query.get("token") or [""])[0]
        if host not in _HOSTS or not hmac.compare_digest(token.encode(),
                                                         self.server.token.encode()):
            self._error(HTTPStatus.FORBIDDEN, "forbidden: this page answers only on "
                        "127.0.0.1 with its token (the address printed by resection link "
                        "--serve)")
            return False
        return True

    # ---------------------------------------------------------------- methods
    def do_GET(self):  # noqa: N802 - http.server's name
        if not self._allowed():
            return
        s = self.server.session
        route = urlsplit(self.path).path
        if route in ("/", "/index.html"):
            html = _page_file("index.html").replace(b"__TOKEN__",
                                                    self.server.token.encode())
            self._send(200, html, PAGE_FILES["index.html"])
        elif route.lstrip("/") in PAGE_FILES:
            name = route.lstrip("/")
            self._send(200, _page_file(name), PAGE_FILES[name])
        elif route == "/api/session":
            self._json(s.info())
        elif route == "/api/candidates":
            self._json(s.candidates_json())
        elif route == "/api/plan":
            self._json(s.plan())
        elif route == "/api/frame":
            data, lo, hi = s.frame_u16()
            self._send(200, data, "application/octet-stream",
                       {"X-Frame-Low": repr(lo), "X-Frame-High": repr(hi)})
        else:
            self._error(HTTPStatus.NOT_FOUND, f"no such page: {route}")

    def do_POST(self):  # noqa: N802
        if not self._allowed():
            return
        route = urlsplit(self.path).path
        if route not in ("/api/solve", "/api/save"):
            self._error(HTTPStatus.NOT_FOUND, f"no such endpoint: {route}")
            return
        text = (self.headers.get("Content-Length") or "").strip()
        n = int(text) if text.isdigit() else -1
        if not 0 < n <= _MAX_BODY:
            self.close_connection = True  # the body, if any, is not read
            self._error(HTTPStatus.BAD_REQUEST if n <= _MAX_BODY
                        else HTTPStatus.REQUEST_ENTITY_TOO_LARGE,
                        f"{_BAD_BODY}: Content-Length {text!r:.40} is not a size of 1 to "
                        f"{_MAX_BODY} bytes")
            return
        try:
            raw = self.rfile.read(n)
        except TimeoutError:
            self.close_connection = True
            self._error(HTTPStatus.REQUEST_TIMEOUT, f"the body did not arrive within "
                        f"{self.server.request_timeout:g} s")
            return
        if len(raw) < n:  # the client closed its side early: nobody to answer
            self.close_connection = True
            return
        try:
            if not _depth_ok(raw):
                raise ValueError
            body = json.loads(raw)
            links = body["links"]
            if not isinstance(links, list):
                raise TypeError
            quit_ = body.get("quit", False) is True
        except (ValueError, KeyError, TypeError, AttributeError, RecursionError):
            self._error(HTTPStatus.BAD_REQUEST, _BAD_BODY)
            return
        try:
            with self.server.lock:  # one solve at a time: the session is shared
                if route == "/api/solve":
                    self._json(self.server.session.solve(links))
                    return
                reply = self.server.session.save(links)
                if quit_:
                    reply["quit"] = True
                self._json(reply)
        except (InputError, SolveError, OSError) as exc:
            self._error(HTTPStatus.CONFLICT if isinstance(exc, SolveError)
                        else HTTPStatus.BAD_REQUEST, str(exc).splitlines()[0])
            return
        if quit_:  # saved and answered: stop serving (shutdown waits for this loop)
            self.server.saved_and_quit = True
            threading.Thread(target=self.server.shutdown, daemon=True).start()


class LinkServer(ThreadingHTTPServer):
    """An HTTP server of one linking session, on ``127.0.0.1`` only.

    Parameters
    ----------
    session : LinkSession
    port : int
        0 (default): a free port.
    token : str, optional
        The secret the URL carries (default: 32 random URL-safe characters).
    verbose : bool
        Log each request to stderr.
    request_timeout : float
        Seconds a connection may take to send a request or stay idle
        (default :data:`REQUEST_TIMEOUT`).
    """

    daemon_threads = True
    #: connections the system queues before they are accepted (socketserver's default 5
    #: dropped some of a burst on a loaded machine: each is accepted, then served or 503)
    request_queue_size = 2 * MAX_CONNECTIONS
    allow_reuse_address = False

    def __init__(self, session: LinkSession, port: int = 0, *, token: str | None = None,
                 verbose: bool = False, request_timeout: float = REQUEST_TIMEOUT):
        if not isinstance(session, LinkSession):
            raise InputError("LinkServer: session must be a LinkSession")
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise InputError(f"--port: {port!r:.40} is not a port number (0 to 65535; 0: a "
                             "free one)")
        self.session = session
        self.token = token or secrets.token_urlsafe(24)
        self.verbose = verbose
        self.request_timeout = float(request_timeout)
        self.saved_and_quit = False
        self.lock = threading.Lock()
        self._slots = threading.BoundedSemaphore(MAX_CONNECTIONS)
        try:
            super().__init__(("127.0.0.1", port), _Handler)
        except OSError as exc:  # port taken, or not ours to take
            raise InputError(f"port {port}: cannot listen on 127.0.0.1 "
                             f"({exc.strerror or exc}); give another --port, or 0 for a free "
                             "one") from None

    def process_request(self, request, client_address):
        """Serve the connection on a thread of its own, or answer 503 when
        :data:`MAX_CONNECTIONS` are open already (slow clients cannot take every thread)."""
        if not self._slots.acquire(blocking=False):
            try:
                request.sendall(b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\n"
                                b"Connection: close\r\n\r\n")
            except OSError:
                pass
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def process_request_thread(self, request, client_address):
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()

    @property
    def url(self) -> str:
        """The page's address, token included."""
        return f"http://127.0.0.1:{self.server_address[1]}/?token={self.token}"

    def run(self, *, open_browser: bool = False) -> bool:
        """Serve until the page's Save and quit (returns True) or an interrupt (Ctrl+C:
        the :class:`KeyboardInterrupt` goes on to the caller, whose command line exits
        with status 130), then close; ``open_browser`` opens the page in the default
        browser first (:mod:`webbrowser`)."""
        if open_browser:
            import webbrowser

            webbrowser.open(self.url)
        try:
            self.serve_forever()
        finally:
            self.server_close()
        return self.saved_and_quit


def serve_links(session: LinkSession, *, port: int = 0, open_browser: bool = False,
                verbose: bool = False) -> LinkServer:
    """Serve ``session`` on ``127.0.0.1`` from a daemon thread and return the server at once
    (its :attr:`~LinkServer.url` is the page; ``shutdown()`` then ``server_close()`` stop
    it). ``open_browser`` opens the page in the default browser."""
    server = LinkServer(session, port, verbose=verbose)
    if open_browser:
        import webbrowser

        webbrowser.open(server.url)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server

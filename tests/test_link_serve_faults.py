"""``resection link --serve`` against bad requests and interrupts (issue 34 item 18): a port
out of range is one line; a bad Content-Length, a deeply nested body and a body shorter
than it says are answered (400/408) without a traceback and without holding a thread;
Save and quit stops the server; Ctrl+C exits 130. Raw sockets, not a client library, so
that the requests can be as broken as a sweep makes them."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from scipy.spatial import cKDTree

from resection.errors import InputError
from resection.io.cameras import read_camera, write_camera
from resection.markers.link_server import LinkServer
from resection.markers.link_session import open_session
from scenes.real_traits import real_traits, write_scene

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
START = ("T01", "T04", "T09", "T14")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    s = real_traits(scale=1.0)
    folder = tmp_path_factory.mktemp("link_faults")
    paths = write_scene(s, folder)
    paths["intrinsics"] = str(folder / "internal.json")
    write_camera(paths["intrinsics"], s.cameras[0], format="upsp", intrinsics_only=True)
    assert read_camera(paths["intrinsics"]).width == 320
    return s, paths


def _session(paths, tmp_path):
    return open_session(paths["image0"], paths["markers"], paths["intrinsics"], diameter=5.0,
                        save_links=tmp_path / "links.csv", save_camera=tmp_path / "cam.json")


def _serve(ses, **kw):
    server = LinkServer(ses, 0, **kw)
    errors = []

    def handle_error(request, client_address):  # a traceback in a handler: recorded
        errors.append(sys.exc_info()[1])

    server.handle_error = handle_error
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, errors


def _raw(port, data: bytes, *, wait: float = 10.0) -> bytes:
    """Send ``data`` on a fresh connection and return what comes back until the server
    closes it or ``wait`` seconds pass."""
    with socket.create_connection(("127.0.0.1", port), timeout=wait) as c:
        c.sendall(data)
        out = b""
        try:
            while chunk := c.recv(65536):
                out += chunk
        except TimeoutError:
            pass
    return out


def _post(port, token, body: bytes, length: str | None = None, path="/api/solve") -> bytes:
    n = str(len(body)) if length is None else length
    head = (f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Link-Token: {token}\r\n"
            f"Content-Type: application/json\r\nContent-Length: {n}\r\n"
            "Connection: close\r\n\r\n").encode()
    return _raw(port, head + body)


@pytest.mark.parametrize("port", [70000, -1, 65536])
def test_port_out_of_range_is_one_line(scene, tmp_path, port):
    _, paths = scene
    with pytest.raises(InputError, match=r"--port: .* not a port number \(0 to 65535"):
        LinkServer(_session(paths, tmp_path), port)


def test_bad_length_deep_json_and_short_body_are_answered(scene, tmp_path):
    _, paths = scene
    server, errors = _serve(_session(paths, tmp_path), request_timeout=1.0)
    port, tok = server.server_address[1], server.token
    try:
        for length in ("abc", "-5", "1e3", ""):
            reply = _post(port, tok, b'{"links": []}', length=length)
            assert reply.startswith(b"HTTP/1.1 400"), (length, reply[:80])
            assert b"Content-Length" in reply
        reply = _post(port, tok, b"{}", length=str(10**9))
        assert reply.startswith(b"HTTP/1.1 413")
        deep = b'{"links": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
        reply = _post(port, tok, deep)
        assert reply.startswith(b"HTTP/1.1 400") and b"links" in reply
        # brackets inside strings are no nesting: a plain body with them is read
        ok = _post(port, tok, json.dumps({"links": [], "note": '[[[[[[[[[[[[\\"['}).encode())
        assert ok.startswith(b"HTTP/1.1 200") or ok.startswith(b"HTTP/1.1 409"), ok[:60]
        # a body shorter than its Content-Length: 408 after the timeout, thread freed
        t0 = time.monotonic()
        reply = _post(port, tok, b'{"links": [', length="200")
        assert reply.startswith(b"HTTP/1.1 408"), reply[:80]
        assert time.monotonic() - t0 < 5.0
        # an idle connection that never sends a request is closed after the timeout
        t0 = time.monotonic()
        assert _raw(port, b"", wait=10.0) == b""
        assert time.monotonic() - t0 < 5.0
        # and the server still answers
        good = _post(port, tok, json.dumps({"links": []}).encode())
        assert good.startswith(b"HTTP/1.1 200")
        assert errors == []
    finally:
        server.shutdown()
        server.server_close()


def _truth(session, s):
    d, j = cKDTree(session.candidates.uv).query(np.nan_to_num(s.uv[0], nan=-1e6))
    return {k: int(j[i]) for i, k in enumerate(s.marker_ids) if d[i] < 1.0}


def _command(paths, tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([ROOT, os.environ.get("PYTHONPATH",
                                                                              "")])}
    cmd = [sys.executable, "-m", "resection.cli", "link", "--serve", paths["image0"],
           "--markers", paths["markers"], "--camera", paths["intrinsics"], "--diameter", "5",
           "--save-links", str(tmp_path / "l.csv"), "--pose", str(tmp_path / "c.json")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    lines = [proc.stdout.readline() for _ in range(2)]
    url = lines[1].split()[-1]
    assert url.startswith("http://127.0.0.1:"), lines
    port = int(url.split(":")[2].split("/")[0])
    return proc, port, url.split("token=")[1]


def test_ctrl_c_exits_130_with_one_line(scene, tmp_path):
    _, paths = scene
    proc, _, _ = _command(paths, tmp_path)
    proc.send_signal(2)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130
    assert len(err.strip().splitlines()) == 1 and "interrupted" in err


def test_save_and_quit_stops_the_server(scene, tmp_path):
    s, paths = scene
    (tmp_path / "a").mkdir()
    truth = _truth(_session(paths, tmp_path / "a"), s)
    proc, port, tok = _command(paths, tmp_path)
    try:
        body = json.dumps({"links": [[k, truth[k]] for k in START], "quit": True}).encode()
        reply = _post(port, tok, body, path="/api/save")
        assert reply.startswith(b"HTTP/1.1 200"), reply[:200]
        assert b'"quit": true' in reply
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "saved; server stopped" in out
    assert (tmp_path / "l.csv").is_file() and (tmp_path / "c.json").is_file()


def test_connections_beyond_the_limit_are_refused_not_queued(scene, tmp_path):
    """Slow clients cannot hold every thread: beyond MAX_CONNECTIONS open connections a new
    one is answered 503 at once; once they close, the server answers again."""
    from resection.markers.link_server import MAX_CONNECTIONS

    _, paths = scene
    server, errors = _serve(_session(paths, tmp_path), request_timeout=5.0)
    port, tok = server.server_address[1], server.token
    held = [socket.create_connection(("127.0.0.1", port)) for _ in range(MAX_CONNECTIONS)]
    try:
        deadline = time.monotonic() + 20.0
        while server._slots._value > 0 and time.monotonic() < deadline:
            time.sleep(0.02)  # every held connection taken by its thread (a loaded machine)
        assert server._slots._value == 0
        t0 = time.monotonic()
        assert _raw(port, b"", wait=3.0).startswith(b"HTTP/1.1 503")
        assert time.monotonic() - t0 < 2.0
    finally:
        for c in held:
            c.close()
    try:
        deadline = time.monotonic() + 5.0
        while True:  # the threads notice the closed connections
            reply = _post(port, tok, json.dumps({"links": []}).encode())
            if reply.startswith(b"HTTP/1.1 200") or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        assert reply.startswith(b"HTTP/1.1 200"), reply[:60]
        assert errors == []
    finally:
        server.shutdown()
        server.server_close()

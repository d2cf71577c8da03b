"""The load generator: it stops with the reason when the service fails its warm-up, instead of waiting forever; it
says when its timed part starts; and it reads the CPU a process tree has used."""

import json
import os
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from tools import loadtest


class _Failing(BaseHTTPRequestHandler):
    """GET /model answers an envelope; every POST /predict a 500 (as a broken model would)."""

    def do_GET(self):
        self._send(200, json.dumps({"envelope": {"displacement_mm": [0, 5], "angle_deg": [-10, 10]}}).encode())

    def do_POST(self):
        self.rfile.read(int(self.headers["content-length"]))
        self._send(500, b'{"detail": "model.onnx takes no materials_std input"}')

    def _send(self, status, body):
        self.send_response(status)
        self.send_header("content-length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


@pytest.fixture
def failing_url():
    server = ThreadingHTTPServer(("127.0.0.1", 0), _Failing)
    server.protocol_version = "HTTP/1.1"
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()


def test_a_failing_warm_up_ends_the_run_with_the_reply(failing_url):
    raised = []

    def drive():
        try:
            loadtest.run(failing_url, concurrency=4, duration_s=1, fmt="binary", warmup=2)
        except loadtest.WarmUpFailed as exc:
            raised.append(str(exc))

    worker = threading.Thread(target=drive, daemon=True)
    worker.start()
    worker.join(20)
    assert not worker.is_alive(), "the load generator hung on a failed warm-up"
    assert raised and "HTTP 500: " in raised[0] and "materials_std" in raised[0]


def test_the_cli_says_so_and_exits_2(failing_url, capsys):
    assert loadtest.main(["--url", failing_url, "--concurrency", "2", "--duration", "1"]) == 2
    assert "error: a warm-up request" in capsys.readouterr().err


class _Ok(_Failing):
    def do_POST(self):
        self.rfile.read(int(self.headers["content-length"]))
        self._send(200, b"\0" * 12)


def test_on_start_runs_once_after_the_warm_up_and_before_the_timed_requests():
    server = ThreadingHTTPServer(("127.0.0.1", 0), _Ok)
    server.protocol_version = "HTTP/1.1"
    threading.Thread(target=server.serve_forever, daemon=True).start()
    calls = []
    try:
        result = loadtest.run(f"http://127.0.0.1:{server.server_address[1]}", concurrency=2, duration_s=0.3,
                              fmt="binary", warmup=3, on_start=lambda: calls.append(time.perf_counter()))
    finally:
        server.shutdown()
    assert len(calls) == 1 and result.errors == 0 and len(result.latencies_ms) > 2


BURN = """
import sys, time
t0 = time.process_time()
while time.process_time() - t0 < 0.3:
    pass
print("burnt", flush=True)
sys.stdin.read()
"""


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc")
def test_cpu_seconds_counts_the_processes_below_the_one_named():
    before = loadtest.cpu_seconds(os.getpid())
    child = subprocess.Popen([sys.executable, "-c", BURN], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "burnt"
        tree, alone = loadtest.cpu_seconds(os.getpid()), loadtest.cpu_seconds(child.pid)
    finally:
        child.communicate("")
    assert sum(alone) >= 0.3
    # this process's own time only grows; the child's 0.3 s is in the tree. The times come in 10 ms ticks, whose
    # difference as floats may fall a rounding error short (33.91 - 33.61 = 0.2999...): compare to the tick
    assert round(sum(tree) - sum(before), 2) >= 0.3
    assert loadtest.cpu_seconds(2**22 + 12345) is None  # no such process

"""The emergency stop's own port (service.runtime.stop_port), on its own: a real socket, a recorded
press in place of the bench. What it answers to whom, and that no client can hold it up.
The whole path through the engine process is in tests/system/test_engine_process.py."""

from __future__ import annotations

import hashlib
import socket
import threading

import httpx
import pytest

from service.runtime.stop_port import MAX_CONNECTIONS, STOP_PATH, StopPort, StopTokens

OPERATE, READ, ADMIN = "evc_operate-token", "evc_read-token", "evc_admin-token"


def _digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


class _Presses:
    """The bench's stop, recorded: how often, and what it answers."""

    def __init__(self):
        self.count, self.fail = 0, False

    def __call__(self) -> dict:
        self.count += 1
        if self.fail:
            raise RuntimeError("DAQ write failed")
        return {"stopped": True, "door": "stop port", "output_v": {"y": 0.0}}


@pytest.fixture
def port():
    tokens = StopTokens()
    tokens.replace(
        {
            _digest(OPERATE): ("tok_op", "operator", "operate"),
            _digest(READ): ("tok_rd", "viewer", "read"),
            _digest(ADMIN): ("tok_ad", "admin", "admin"),
        },
        auth_off=False,
    )
    presses = _Presses()
    served = StopPort("127.0.0.1", 0, press=presses, tokens=tokens).start()
    served.presses_seen, served.tokens_held = presses, tokens
    with httpx.Client(base_url=f"http://127.0.0.1:{served.port}", timeout=10) as client:
        served.client = client
        yield served
    served.close()


def _bearer(token: str) -> dict:
    return {"Authorization": f"Bearer {token}"}


def test_an_operate_or_admin_token_presses_the_stop_once(port):
    for token, presses in ((OPERATE, 1), (ADMIN, 2)):
        answer = port.client.post(STOP_PATH, headers=_bearer(token))
        assert answer.status_code == 200 and answer.json()["stopped"] is True
        assert answer.headers["connection"] == "close"
        assert port.presses_seen.count == presses


@pytest.mark.parametrize(
    "headers, status, field",
    [
        ({}, 401, "authorization"),
        ({"Authorization": "Basic abc"}, 401, "authorization"),
        ({"Authorization": "Bearer evc_nobody"}, 401, "authorization"),
        (_bearer(READ), 403, "scope"),
    ],
)
def test_without_a_valid_operate_token_nothing_is_pressed(port, headers, status, field):
    answer = port.client.post(STOP_PATH, headers=headers)
    assert answer.status_code == status and answer.json()["field"] == field
    assert port.presses_seen.count == 0
    if status == 401:
        assert answer.headers["www-authenticate"] == "Bearer"
    if status == 403:
        assert "'operate' scope" in answer.json()["detail"] and "tok_rd" in answer.json()["detail"]


def test_another_benchs_id_is_refused_before_anything_moves():
    tokens, press = StopTokens(), _Presses()
    tokens.replace({_digest(OPERATE): ("tok_op", "operator", "operate")}, auth_off=False)
    served = StopPort("127.0.0.1", 0, press=press, tokens=tokens, bench_id="bench-a").start()
    try:
        url = f"http://127.0.0.1:{served.port}{STOP_PATH}"
        wrong = httpx.post(url, params={"bench_id": "bench-b"}, headers=_bearer(OPERATE))
        assert wrong.status_code == 409 and wrong.json()["field"] == "bench_id" and press.count == 0
        assert "bench-a" in wrong.json()["detail"]
        right = httpx.post(url, params={"bench_id": "bench-a"}, headers=_bearer(OPERATE))
        assert right.status_code == 200 and right.json()["bench_id"] == "bench-a" and press.count == 1
        assert httpx.post(url, headers=_bearer(OPERATE)).status_code == 200  # no id asked: this bench
    finally:
        served.close()


def test_a_revoked_token_is_refused_once_the_list_says_so(port):
    assert port.client.post(STOP_PATH, headers=_bearer(OPERATE)).status_code == 200
    port.tokens_held.replace({_digest(ADMIN): ("tok_ad", "admin", "admin")}, auth_off=False)
    assert port.client.post(STOP_PATH, headers=_bearer(OPERATE)).status_code == 401
    assert port.presses_seen.count == 1


def test_before_the_service_sent_its_tokens_the_port_says_use_the_route():
    press = _Presses()
    served = StopPort("127.0.0.1", 0, press=press, tokens=StopTokens()).start()
    try:
        answer = httpx.post(f"http://127.0.0.1:{served.port}{STOP_PATH}", headers=_bearer(OPERATE))
        assert answer.status_code == 503 and "service's port" in answer.json()["detail"] and press.count == 0
    finally:
        served.close()


def test_auth_off_accepts_any_request():
    tokens, press = StopTokens(), _Presses()
    tokens.replace({}, auth_off=True)
    served = StopPort("127.0.0.1", 0, press=press, tokens=tokens).start()
    try:
        assert httpx.post(f"http://127.0.0.1:{served.port}{STOP_PATH}").status_code == 200 and press.count == 1
    finally:
        served.close()


def test_other_paths_methods_and_the_browser_preflight(port):
    assert port.client.post("/api/bench/reset", headers=_bearer(OPERATE)).status_code == 404
    got = port.client.get(STOP_PATH, headers=_bearer(OPERATE))
    assert got.status_code == 405 and got.headers["allow"] == "POST, OPTIONS"
    preflight = port.client.options(
        STOP_PATH,
        headers={
            "Origin": "http://127.0.0.1:8000",
            "Access-Control-Request-Method": "POST",
            "Access-Control-Request-Headers": "authorization",
        },
    )
    assert preflight.status_code == 204
    assert preflight.headers["access-control-allow-origin"] == "http://127.0.0.1:8000"
    assert "authorization" in preflight.headers["access-control-allow-headers"].lower()
    assert "POST" in preflight.headers["access-control-allow-methods"]
    pressed = port.client.post(STOP_PATH, headers={**_bearer(OPERATE), "Origin": "http://127.0.0.1:8000"})
    assert pressed.headers["access-control-allow-origin"] == "http://127.0.0.1:8000"
    assert port.presses_seen.count == 1


def _raw(port_number: int, data: bytes) -> bytes:
    with socket.create_connection(("127.0.0.1", port_number), timeout=10) as sock:
        sock.sendall(data)
        answer = b""
        while chunk := sock.recv(4096):
            answer += chunk
    return answer


@pytest.mark.parametrize(
    "request_bytes, status",
    [
        (b"garbage\r\n\r\n", b"400"),
        (b"POST /api/bench/stop HTTP/1.1\r\nContent-Length: x\r\n\r\n", b"400"),
        (b"POST /api/bench/stop HTTP/1.1\r\nContent-Length: 99999999\r\n\r\n", b"413"),
        (b"POST /api/bench/stop HTTP/1.1\r\nX-Pad: " + b"a" * 9000, b"431"),
    ],
)
def test_malformed_requests_get_4xx_and_press_nothing(port, request_bytes, status):
    answer = _raw(port.port, request_bytes)
    assert answer.split(b" ")[1] == status, answer[:200]
    assert port.presses_seen.count == 0
    assert port.client.post(STOP_PATH, headers=_bearer(OPERATE)).status_code == 200  # still serving


def test_a_hand_typed_request_with_bare_line_feeds_is_answered(port):
    answer = _raw(port.port, f"POST {STOP_PATH} HTTP/1.1\nHost: x\nAuthorization: Bearer {OPERATE}\n\n".encode())
    assert answer.startswith(b"HTTP/1.1 200") and port.presses_seen.count == 1


def test_a_body_sent_in_pieces_is_read_before_the_answer(port):
    head = (
        f"POST {STOP_PATH} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {OPERATE}\r\n"
        "Content-Type: application/json\r\nContent-Length: 20\r\n\r\n"
    ).encode()
    with socket.create_connection(("127.0.0.1", port.port), timeout=10) as sock:
        sock.sendall(head + b'{"why": ')
        sock.settimeout(0.3)
        with pytest.raises(socket.timeout):  # no answer before the whole body arrived
            sock.recv(100)
        sock.settimeout(10)
        sock.sendall(b'"a test"}   ')  # the 20th byte
        answer = sock.recv(4096)
    assert answer.startswith(b"HTTP/1.1 200") and port.presses_seen.count == 1


def test_idle_and_slow_clients_do_not_hold_the_stop_up(port):
    # More half-sent requests than the port keeps: each new one drops the oldest, and a stop still lands.
    idle = [socket.create_connection(("127.0.0.1", port.port), timeout=10) for _ in range(MAX_CONNECTIONS + 6)]
    try:
        for sock in idle:
            sock.sendall(b"POST /api/bench/stop HTTP/1.1\r\nAuthorization: Bearer ")
        answer = port.client.post(STOP_PATH, headers=_bearer(OPERATE))
        assert answer.status_code == 200 and port.presses_seen.count == 1
    finally:
        for sock in idle:
            sock.close()


def test_a_failing_stop_answers_503_and_the_port_lives_on(port):
    port.presses_seen.fail = True
    answer = port.client.post(STOP_PATH, headers=_bearer(OPERATE))
    assert answer.status_code == 503 and "DAQ write failed" in answer.json()["detail"]
    port.presses_seen.fail = False
    assert port.client.post(STOP_PATH, headers=_bearer(OPERATE)).status_code == 200
    assert port.presses_seen.count == 2


def test_presses_from_many_threads_are_each_answered(port):
    results: list[int] = []

    def press() -> None:
        results.append(
            httpx.post(f"http://127.0.0.1:{port.port}{STOP_PATH}", headers=_bearer(OPERATE), timeout=10).status_code
        )

    threads = [threading.Thread(target=press) for _ in range(12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert results == [200] * 12 and port.presses_seen.count == 12


def test_the_client_presses_the_port_and_falls_back_when_it_is_another_benchs():
    """Client.stop_bench: the stop port of the bench GET /api/bench names; when that port stops another
    bench (409) the service's own route. The service here is a stand-in answering those two routes."""
    from service.frontends.client import Client

    tokens, press = StopTokens(), _Presses()
    tokens.replace({_digest(OPERATE): ("tok_op", "operator", "operate")}, auth_off=False)
    served = StopPort("127.0.0.1", 0, press=press, tokens=tokens, bench_id="bench-a").start()
    routed: list[str] = []

    def service(bench_id: str):
        def answer(request: httpx.Request) -> httpx.Response:
            routed.append(f"{request.method} {request.url.path}")
            if request.url.path == "/api/bench":
                return httpx.Response(200, json={"engine": {"stop_port": served.port}, "bench_id": bench_id})
            return httpx.Response(200, json={"stopped": True, "door": "service route"})

        return httpx.MockTransport(answer)

    try:
        for bench_id, door, presses in (("bench-a", "stop port", 1), ("bench-b", "service route", 1)):
            routed.clear()
            http = httpx.Client(base_url="http://127.0.0.1:1", transport=service(bench_id))
            with Client(http=http, token=OPERATE) as client:
                assert client.stop_bench()["door"] == door and press.count == presses
            assert ("POST /api/bench/stop" in routed) == (door == "service route")
    finally:
        served.close()


def test_serve_refuses_a_stop_port_it_cannot_have_in_one_line(tmp_path, monkeypatch):
    from service.frontends import cli
    from service.frontends.cli_tokens import stop_port_refusal
    from service.runtime.settings import Settings

    settings = Settings(data_dir=tmp_path, port=8123, stop_port=8123)
    assert "the service's own --port" in stop_port_refusal(settings)
    with socket.create_server(("127.0.0.1", 0)) as held:
        taken = held.getsockname()[1]
        assert f"127.0.0.1:{taken} cannot listen" in stop_port_refusal(Settings(data_dir=tmp_path, stop_port=taken))
    assert stop_port_refusal(Settings(data_dir=tmp_path, stop_port=0)) is None
    assert cli.main(["serve", "--data-dir", str(tmp_path), "--stop-port", "70000"]) == 2
    monkeypatch.setenv("EVCBENCH_STOP_PORT", "abc")
    assert cli.main(["serve", "--data-dir", str(tmp_path)]) == 2


def test_a_stop_neither_door_takes_is_an_error_naming_both():
    """The port does not know the token yet (401) and the service does not answer (hung): the client
    says so within its timeouts instead of waiting for the service's minute."""
    from service.frontends.client import Client, StopNotDelivered

    served = StopPort("127.0.0.1", 0, press=_Presses(), tokens=StopTokens(), bench_id="bench-a").start()
    served.tokens.replace({}, auth_off=False)

    def hung_service(request: httpx.Request) -> httpx.Response:
        if request.url.path == "/api/bench":
            return httpx.Response(200, json={"engine": {"stop_port": served.port}, "bench_id": "bench-a"})
        raise httpx.ReadTimeout("timed out", request=request)

    try:
        http = httpx.Client(base_url="http://127.0.0.1:1", transport=httpx.MockTransport(hung_service))
        with Client(http=http, token=OPERATE) as client:
            with pytest.raises(StopNotDelivered) as refused:
                client.stop_bench()
        detail = refused.value.detail
        assert detail.startswith("could not reach the service at http://127.0.0.1:1: no answer within 10 s; ")
        assert "stop port: 401: unknown or revoked API token" in detail
        assert detail.endswith("the outputs were NOT commanded to 0 V by this call") and "503" not in detail
    finally:
        served.close()


def test_stop_without_a_service_says_it_reached_nothing_and_fails(tmp_path, monkeypatch, capsys):
    """``evcbench stop`` with nothing listening: connection refused, no stop port known, no HTTP status
    invented; exit code 3, within the connect attempt (no 10 s wait)."""
    from service.frontends import cli

    with socket.create_server(("127.0.0.1", 0)) as gone:
        port = gone.getsockname()[1]  # closed on leaving: nothing listens there
    monkeypatch.setenv("EVCBENCH_DATA_DIR", str(tmp_path))  # no stop_port.json there
    assert cli.main(["stop", "--url", f"http://127.0.0.1:{port}", "--token", OPERATE]) == 3
    err = capsys.readouterr().err
    assert err.strip() == (
        f"error: emergency stop not delivered: could not reach the service at http://127.0.0.1:{port}: "
        "could not connect (connection refused); no stop port known: "
        "the outputs were NOT commanded to 0 V by this call"
    ), err


def test_a_port_stop_logs_the_jobs_it_cancelled_in_words(store, caplog):
    """The web process's log line after a stop-port press names the jobs, never Python values."""
    from service.runtime.jobs import JobManager
    from service.runtime.stop_port_link import StopPortLink
    from tests.support.api_client import job_running, wait_job

    manager, gate = JobManager(store, workers=1), threading.Event()
    link = StopPortLink(bench=None, store=store, jobs=manager, auth_off=True)
    try:
        with caplog.at_level("WARNING", logger="evcbench.safety"):
            link._cancel_jobs("emergency stop")
            holder = manager.submit("sweep", None, lambda ctx: {"held": gate.wait(10)}, needs_bench=True)
            wait_job(manager.get, holder["id"], until=job_running())
            queued = [manager.submit("sweep", None, lambda ctx: {}, needs_bench=True)["id"] for _ in range(2)]
            link._cancel_jobs("emergency stop")
        idle, busy = [r.getMessage() for r in caplog.records if r.name == "evcbench.safety"]
        assert idle == "emergency stop (stop port): outputs at 0 V, no bench job was running, none queued"
        assert busy == (
            f"emergency stop (stop port): outputs at 0 V, running bench job {holder['id']} cancelled, "
            f"queued {queued[0]}, {queued[1]} cancelled"
        )
    finally:
        gate.set()
        manager.shutdown()

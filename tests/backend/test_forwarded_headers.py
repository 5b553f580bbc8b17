"""Who is asking (issue 33, item 3): `X-Forwarded-For` is believed only from a proxy the operator names.

Before, uvicorn's default believed it from 127.0.0.1, so anyone on the machine could forge the address the audit
trail records ("a console without login (6.6.6.6)") and the login throttle counts by. Checked against real
`isorig serve` processes, without and with `--forwarded-allow-ips 127.0.0.1`."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import httpx
import pytest
from conftest import AUTH, sine_test
from pydantic import ValidationError
from served import ENV, free_port, serve, stop, wait_up

from backend.settings import Settings

LONG = sine_test(speed=1.0, profile={"frequency_hz": 0.5, "cycles": 100, "taper_cycles": 1})
WRONG = {"name": "admin", "password": "not-the-password"}


def throttled_from(http: httpx.Client, forged: str) -> int:
    """Wrong passwords for one name, sent as from ``forged``, until the throttle's wait is at least 4 s (each
    failure past the free ones doubles it); the last wait, s."""
    wait = 0
    for _ in range(20):
        r = http.post("/api/session", json=WRONG, headers={"X-Forwarded-For": forged})
        if r.status_code == 429:
            wait = int(r.headers["Retry-After"])
            if wait >= 4:
                return wait
            time.sleep(wait)  # admitted after it, the next wrong password doubles the wait
        else:
            assert r.status_code == 401, r.text
    raise AssertionError(f"no wait of 4 s or more after 20 guesses (last {wait} s)")


@pytest.mark.slow  # a real service: scripts/test.sh --quick leaves it out
@pytest.mark.parametrize("trusted", [None, "127.0.0.1"], ids=["no-proxy-named", "proxy-127.0.0.1"])
def test_forwarded_for_is_believed_only_from_a_named_proxy(tmp_path, trusted):
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    server = serve(port, "--data-dir", str(tmp_path), *(["--forwarded-allow-ips", trusted] if trusted else []))
    seen = "6.6.6.6" if trusted else "127.0.0.1"
    try:
        wait_up(server, base)
        with httpx.Client(base_url=base, timeout=30) as http:
            # the audit trail: an anonymous abort names the address it came from
            test_id = http.post("/api/tests?start=true", json=LONG, headers=AUTH).json()["id"]
            r = http.post(f"/api/tests/{test_id}/abort", headers={"X-Forwarded-For": "6.6.6.6"})
            assert r.status_code in (200, 202), r.text
            messages = [e["message"] for e in http.get(f"/api/tests/{test_id}").json()["events"]]
            assert f"abort requested by a console without login ({seen})" in messages, messages
            # the login throttle: guesses "from 6.6.6.6" slow 127.0.0.1 itself unless the proxy is named, and
            # then another forwarded address is another client
            throttled_from(http, "6.6.6.6")
            other = http.post("/api/session", json=WRONG, headers={"X-Forwarded-For": "7.7.7.7"})
            assert other.status_code == (401 if trusted else 429), other.text
    finally:
        stop(server)


def test_the_setting_takes_addresses_and_networks_only():
    assert Settings().proxy_options() == {"proxy_headers": False, "forwarded_allow_ips": ""}
    s = Settings(forwarded_allow_ips="127.0.0.1, ::1 10.1.2.3/8")
    assert s.proxy_options() == {"proxy_headers": True, "forwarded_allow_ips": "127.0.0.1,::1,10.0.0.0/8"}
    for bad in ("*", "proxy.lab", "10.0.0.0/33"):
        with pytest.raises(ValidationError, match="is not an IP address or network"):
            Settings(forwarded_allow_ips=bad)


@pytest.mark.slow  # a real `isorig serve`: scripts/test.sh --quick leaves it out
def test_serve_refuses_a_proxy_that_is_not_an_address(tmp_path):
    done = subprocess.run([sys.executable, "-m", "isorig", "serve", "--data-dir", str(tmp_path),
                           "--forwarded-allow-ips", "*"], capture_output=True, text=True, timeout=60,
                          env={**os.environ, **ENV})
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert "forwarded_allow_ips: '*' is not an IP address or network" in done.stderr, done.stderr
    assert not (tmp_path / "isorig.db").exists()  # refused before anything is made

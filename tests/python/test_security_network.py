"""A single-machine batch listens on loopback only: the sockets of a running local Ray (GCS, raylet, object
store, driver, workers) are listed from /proc while a task runs, and none is reachable from another machine."""

from __future__ import annotations

import ipaddress
from pathlib import Path

import pytest

from m3c.pipeline.batch import start_local_ray

# /proc/net/tcp* state 0A is LISTEN; an unconnected UDP socket (07) takes datagrams from anywhere.
LISTENING = {"tcp": "0A", "tcp6": "0A", "udp": "07", "udp6": "07"}


def _address(hex_address: str, family: str) -> ipaddress._BaseAddress:
    raw = bytes.fromhex(hex_address)
    if family.endswith("6"):  # four little-endian 32-bit words
        raw = b"".join(raw[i:i + 4][::-1] for i in range(0, 16, 4))
        address = ipaddress.IPv6Address(raw)
        return address.ipv4_mapped or address
    return ipaddress.IPv4Address(raw[::-1])


def socket_tables() -> dict[str, str]:
    return {family: (Path("/proc/net") / family).read_text() for family in LISTENING
            if (Path("/proc/net") / family).is_file()}


def listening_sockets(tables: dict[str, str] | None = None) -> set[tuple[str, str, int]]:
    """(protocol, address, port) of every listening socket of this network namespace."""
    found = set()
    for family, text in (tables or socket_tables()).items():
        state = LISTENING[family]
        for line in text.splitlines()[1:]:
            fields = line.split()
            if fields[3] != state:
                continue
            host, port = fields[1].split(":")
            found.add((family, str(_address(host, family)), int(port, 16)))
    return found


def test_address_decoding():
    assert str(_address("0100007F", "tcp")) == "127.0.0.1"
    assert str(_address("00000000000000000000000000000000", "tcp6")) == "::"
    assert str(_address("0000000000000000FFFF00000100007F", "tcp6")) == "127.0.0.1"


@pytest.mark.slow
def test_local_ray_listens_on_loopback_only():
    ray = pytest.importorskip("ray", reason="needs Ray (pip install 'm3c[batch]')")
    if ray.is_initialized():
        pytest.skip("a Ray instance of another test is running in this process")
    before = listening_sockets()
    start_local_ray(num_cpus=1, logging_level="WARNING", log_to_driver=False)
    try:
        def tables_seen_by_a_worker():  # self-contained: the worker cannot import this test module
            from pathlib import Path as P

            return {f: (P("/proc/net") / f).read_text() for f in ("tcp", "tcp6", "udp", "udp6")
                    if (P("/proc/net") / f).is_file()}

        tables_seen_by_a_worker.__module__ = "__main__"
        seen = ray.get(ray.remote(tables_seen_by_a_worker).remote())
        during = listening_sockets(seen) | listening_sockets()
        gcs = ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()
    new = during - before
    assert new, "a running Ray opened no listening socket: the listing is broken"
    exposed = sorted(s for s in new if not ipaddress.ip_address(s[1]).is_loopback)
    assert not exposed, f"Ray listens beyond loopback: {exposed}"
    assert gcs.startswith("127.0.0.1:")

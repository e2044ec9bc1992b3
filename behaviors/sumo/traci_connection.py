"""Reaching a SUMO another program runs: its address as --connect takes it, connecting with retries,
how a closed connection shows, and SUMO's time options read back."""

from __future__ import annotations

import contextlib
import sys
from dataclasses import dataclass
from typing import Any

from behaviors.errors import BehaveError

CONNECT_RETRIES = 30
"""Tries, a second apart, to reach SUMO's port: SUMO may still be loading its net when behave starts."""


@dataclass(frozen=True)
class Address:
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.host}:{self.port}"


def parse_address(text: str) -> Address:
    """HOST:PORT (an IPv6 host in brackets, [::1]:8813) as given to --connect."""
    host, sep, port = text.strip().rpartition(":")
    host = host.removeprefix("[").removesuffix("]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise BehaveError(f"--connect takes HOST:PORT (as localhost:8813), got '{text}'")
    return Address(host, int(port))


def sumo_seconds(text: str) -> float:
    """A time option as SUMO gives it back: seconds, or its clock format [DD:]HH:MM:SS[.S]."""
    fields = text.strip().split(":")
    try:
        return sum(
            float(f) * unit for f, unit in zip(reversed(fields), (1.0, 60.0, 3600.0, 86400.0), strict=False)
        )
    except ValueError:
        return -1.0  # unreadable: no end of SUMO's own that behave would keep to


class ConnectionClosed(Exception):
    """SUMO closed this client's connection (it ended, or was stopped), or the network dropped it."""


def connection_closed(exc: BaseException) -> bool:
    """Whether `exc` says the connection to SUMO is gone (as opposed to an error in a command)."""
    if isinstance(exc, ConnectionClosed | OSError):
        return True
    return type(exc).__name__ == "FatalTraCIError"


def connect(address: Address, retries: int = CONNECT_RETRIES) -> Any:
    """A traci connection to the SUMO at `address`; BehaveError if it cannot be reached."""
    import traci

    try:
        with contextlib.redirect_stdout(sys.stderr):  # traci prints its retries
            return traci.connect(address.port, host=address.host, numRetries=retries)
    except Exception as exc:  # socket errors, traci's FatalTraCIError after the retries
        raise BehaveError(
            f"could not join SUMO at {address}: {exc} (is SUMO running with --remote-port {address.port}?)"
        ) from None

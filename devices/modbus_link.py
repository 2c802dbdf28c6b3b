"""What the Modbus TCP drivers (dispenser, thermometer) share about their connection.

pymodbus bounds a connect by the same ``timeout`` as one reply. A reply's bound is a device
question (how long a PLC may think); a connect's is the controller's own: on loopback the
handshake is the kernel's at once, but asyncio finishes it over several turns of the loop, so a
controller held for a moment (the machine's cores busy, a long callback) missed a 0.5 s bound
and read a live PLC as down (a clean-clone CI run, 2026-12-05: ``LinkDown: cannot connect``, the
simulated PLC listening in the same process). So the connect gets a bound of its own.
"""
from __future__ import annotations

from pydantic import Field
from pymodbus.client import AsyncModbusTcpClient

CONNECT_TIMEOUT_S = 3.0


def connect_timeout_field():
    return Field(CONNECT_TIMEOUT_S, gt=0, le=60,
                 description="wall seconds to wait for the TCP connection (a reply waits timeout_s)")


async def connect_within(client: AsyncModbusTcpClient, seconds: float) -> bool:
    """``client.connect()`` bounded by ``seconds`` instead of the client's reply timeout."""
    # pymodbus 3.x reads one bound for both, from its transaction manager's copy of the client's
    # parameters: lend it the connect's for the connect (tests/devices hold the loop to check this)
    params = client.ctx.comm_params
    reply_s, params.timeout_connect = params.timeout_connect, seconds
    try:
        return await client.connect()
    finally:
        params.timeout_connect = reply_s

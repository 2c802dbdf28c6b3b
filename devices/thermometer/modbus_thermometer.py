"""A multi-channel water temperature transmitter over Modbus TCP (pymodbus 3.16's async client).

Register map: input registers (FC4), one per channel, from ``first_register`` (default 1): channel ``c``
is register ``first_register + c``. Each holds a signed 16-bit temperature in tenths of a degree
Celsius (215 = 21.5 °C, -12 = -1.2 °C), the common convention of PT100/NTC input modules, with
two reserved codes: 0x7FFF (32767) an open probe (broken wire), 0x8000 (-32768) a shorted probe.
A value outside ``span_c`` is reported as a ``range`` fault: no fish farm's water is 90 °C, and a
transmitter set for another sensor type reads nonsense rather than an error.

Every configured channel is read in one request (the span from the lowest to the highest), so
the probes are one snapshot. Errors: no connection -> LinkDown; no reply -> DeviceTimeout;
an exception response or a short reply -> ProtocolError. The client does not reconnect in the
background: the next read does.
"""
from __future__ import annotations

from pydantic import Field, field_validator
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from devices.base import Section
from devices.errors import DeviceTimeout, LinkDown, ProtocolError
from devices.modbus_link import connect_timeout_field, connect_within
from devices.thermometer import ProbeReading, Thermometer

OPEN, SHORT = 0x7FFF, 0x8000
MAX_CHANNELS = 64


def check_probes(probes: dict[str, int]) -> dict[str, int]:
    """Probe name -> channel: at least one, each channel on the transmitter, none shared (the
    simulated transmitter's section checks the same)."""
    if not probes:
        raise ValueError("at least one probe")
    for name, channel in probes.items():
        if not 0 <= channel < MAX_CHANNELS:
            raise ValueError(f"probe {name!r}: channel {channel} outside 0..{MAX_CHANNELS - 1}")
    seen: dict[int, str] = {}
    for name, channel in probes.items():
        if channel in seen:
            raise ValueError(f"probes {seen[channel]!r} and {name!r} share channel {channel}")
        seen[channel] = name
    return probes


class Config(Section):
    host: str = Field("127.0.0.1", min_length=1)
    port: int = Field(502, ge=1, le=65535)
    unit: int = Field(1, ge=0, le=247)
    first_register: int = Field(1, ge=0, le=65535 - MAX_CHANNELS, description="input register of channel 0")
    probes: dict[str, int] = Field(description="probe name -> channel (0-based); a tank id, or 'supply'")
    span_c: tuple[float, float] = Field((-10.0, 45.0), description="readings outside are a 'range' fault")
    timeout_s: float = Field(1.0, gt=0, le=60, description="wall seconds to wait for one reply")
    retries: int = Field(1, ge=0, le=10)
    connect_timeout_s: float = connect_timeout_field()

    @field_validator("probes")
    @classmethod
    def _channels(cls, probes: dict[str, int]) -> dict[str, int]:
        return check_probes(probes)

    @field_validator("span_c")
    @classmethod
    def _span(cls, span: tuple[float, float]) -> tuple[float, float]:
        if not span[0] < span[1]:
            raise ValueError("span_c must be [low, high] with low < high")
        return span


def decode(word: int, span_c: tuple[float, float]) -> tuple[float | None, str | None]:
    """One channel's register as (celsius, fault)."""
    if word == OPEN:
        return None, "open"
    if word == SHORT:
        return None, "short"
    celsius = (word - 65536 if word >= 32768 else word) / 10.0
    if not span_c[0] <= celsius <= span_c[1]:
        return None, "range"
    return celsius, None


def encode(celsius: float | None, fault: str | None = None) -> int:
    """The register a transmitter shows for ``celsius`` (or a fault): the sim's side of decode."""
    if fault == "open":
        return OPEN
    if fault == "short":
        return SHORT
    tenths = max(-32767, min(32766, round(celsius * 10)))
    return tenths & 0xFFFF


class ModbusThermometer(Thermometer):
    Config = Config

    def __init__(self, name: str, config: Config, clock):
        super().__init__(name, config, clock)
        self._client: AsyncModbusTcpClient | None = None
        lo, hi = min(config.probes.values()), max(config.probes.values())
        self._first, self._count = config.first_register + lo, hi - lo + 1

    async def _open(self) -> None:
        await self._connected()

    async def _close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    async def _connected(self) -> AsyncModbusTcpClient:
        cfg = self.config
        if self._closed:
            raise LinkDown(self.name, "thermometer link is closed")
        if self._client is None:
            self._client = AsyncModbusTcpClient(cfg.host, port=cfg.port, timeout=cfg.timeout_s,
                                                retries=cfg.retries, reconnect_delay=0, name=self.name)
        if not self._client.connected and not await connect_within(self._client, cfg.connect_timeout_s):
            raise LinkDown(self.name, f"cannot connect to {cfg.host}:{cfg.port}")
        return self._client

    async def _read(self) -> dict[str, ProbeReading]:
        words = await self._registers()
        lo = self._first - self.config.first_register
        out = {}
        for name, channel in self.config.probes.items():
            celsius, fault = decode(words[channel - lo], self.config.span_c)
            out[name] = ProbeReading(name, celsius, fault)
        return out

    async def _registers(self) -> list[int]:
        client = await self._connected()
        what = f"read of input registers {self._first}..{self._first + self._count - 1}"
        try:
            reply = await client.read_input_registers(self._first, count=self._count, device_id=self.config.unit)
        except ConnectionException as exc:
            self._drop()
            raise LinkDown(self.name, f"{what}: connection lost ({exc})") from None
        except ModbusIOException:
            connected = client.connected
            self._drop()            # a late answer must not be read as the next request's
            if not connected:
                raise LinkDown(self.name, f"{what}: connection lost") from None
            raise DeviceTimeout(self.name, f"{what}: no reply within {self.config.timeout_s} s") from None
        except ModbusException as exc:
            self._drop()
            raise ProtocolError(self.name, f"{what}: {exc}") from None
        if reply.isError():
            raise ProtocolError(self.name, f"{what}: Modbus exception {reply.exception_code:#04x}")
        if len(reply.registers) != self._count:
            raise ProtocolError(self.name, f"{what}: {len(reply.registers)} registers in the reply")
        return list(reply.registers)

    def _drop(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

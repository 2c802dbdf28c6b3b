"""A Modbus TCP client that is not pymodbus: raw sockets and the MBAP header by hand (Modbus
Application Protocol v1.1b3, sections 4.1 and 6). Tests use it to check the server independently."""
from __future__ import annotations

import socket
import struct


class Mbap:
    def __init__(self, port: int, unit: int = 1, host: str = "127.0.0.1", timeout: float = 5.0):
        self.sock = socket.create_connection((host, port), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.unit, self.tid = unit, 0

    def close(self) -> None:
        self.sock.close()

    def _recv(self, n: int) -> bytes:
        buf = b""
        while len(buf) < n:
            chunk = self.sock.recv(n - len(buf))
            if not chunk:
                raise ConnectionError("closed by the server")
            buf += chunk
        return buf

    def call(self, fc: int, body: bytes, unit: int | None = None) -> tuple[int, bytes]:
        """One request; (function code of the reply, its data). A code >= 0x80 is an exception."""
        self.tid = (self.tid + 1) & 0xFFFF
        pdu = bytes([fc]) + body
        self.sock.sendall(struct.pack(">HHHB", self.tid, 0, len(pdu) + 1, self.unit if unit is None else unit) + pdu)
        tid, pid, length, _ = struct.unpack(">HHHB", self._recv(7))
        assert (tid, pid) == (self.tid, 0)
        data = self._recv(length - 1)
        return data[0], data[1:]

    def read(self, table: str, address: int, count: int = 1):
        """Words (registers) or 0/1 (bits); an int exception code when refused."""
        fc = {"coil": 1, "discrete input": 2, "holding register": 3, "input register": 4}[table]
        got, data = self.call(fc, struct.pack(">HH", address, count))
        if got & 0x80:
            return ("exception", data[0])
        if fc in (1, 2):
            return [(data[1 + i // 8] >> (i % 8)) & 1 for i in range(count)]
        return list(struct.unpack(f">{count}H", data[1:1 + 2 * count]))

    def write(self, table: str, address: int, values: list[int], single: bool | None = None):
        """FC 5/6 for one value (unless single=False), 15/16 for several; None when accepted."""
        if single is None:
            single = len(values) == 1
        if table == "coil":
            if single:
                got, data = self.call(5, struct.pack(">HH", address, 0xFF00 if values[0] else 0))
            else:
                packed = bytearray((len(values) + 7) // 8)
                for i, v in enumerate(values):
                    packed[i // 8] |= (1 if v else 0) << (i % 8)
                got, data = self.call(15, struct.pack(">HHB", address, len(values), len(packed)) + bytes(packed))
        elif single:
            got, data = self.call(6, struct.pack(">HH", address, values[0]))
        else:
            got, data = self.call(16, struct.pack(f">HHB{len(values)}H", address, len(values), 2 * len(values),
                                                  *values))
        return ("exception", data[0]) if got & 0x80 else None


def f32_words(x: float, word_order: str) -> list[int]:
    hi, lo = struct.unpack(">HH", struct.pack(">f", x))
    return [hi, lo] if word_order == "big" else [lo, hi]


def words_f32(words: list[int], word_order: str) -> float:
    hi, lo = words if word_order == "big" else words[::-1]
    return struct.unpack(">f", struct.pack(">HH", hi, lo))[0]

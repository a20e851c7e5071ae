"""ModbusServer: the process image for HMIs and SCADA over Modbus TCP (pymodbus 3.16).

OpenPLC-compatible map (what HMIs built for OpenPLC expect):

    coils             0..8191  FC1 read, FC5/FC15 write   %QX0.0..%QX1023.7 (as last copied out)
    discrete inputs   0..8191  FC2 read only              %IX0.0..%IX1023.7 (as the program saw them)
    input registers   0..1023  FC4 read only              %IW0..%IW1023
    holding registers 0..1023  FC3 read, FC6/FC16 write   %QW0..%QW1023
    holding registers 1024..2047                          %MW0..%MW1023

The server runs pymodbus' asyncio server in its own thread. Reads are answered from the
process image under its lock (never a half-copied image); writes are queued into the
runtime's quiet point with ``write_many``, so a multi-register write lands in one cycle and
never mid-scan. Addresses beyond the map get exception 2, function codes other than the
eight above exception 1, a failing callback exception 4; the read-only areas have no write
function at all. Binds 127.0.0.1 unless told otherwise. Any unit id is answered.

pymodbus' own register memory is only a scratch buffer: its documented SimDevice ``action``
hook fills it from the image before a reply is built and receives every write. (Checked
against pymodbus 3.16.1, whose simulator API is marked experimental; re-check on upgrade.)
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable, Sequence

from pymodbus.constants import ExcCodes
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from plc_runtime import ConfigError, PlcError, ProcessImage

log = logging.getLogger(__name__)

ReadFn = Callable[[str, int, int], Sequence[int] | Sequence[bool]]
WriteFn = Callable[[str, int, list], "ExcCodes | None"]

N_COILS = 8192
N_DISCRETE = 8192
N_INPUT_REGS = 1024
N_HOLDING = 2048  # 0..1023 "hr" (%QW), 1024..2047 "mw" (%MW)
MW_BASE = 1024
SUPPORTED_FCS = frozenset({1, 2, 3, 4, 5, 6, 15, 16})


def _bits_to_regs(bits: Sequence[bool]) -> list[int]:
    """Pack bits into 16-bit words, bit 0 of the word = first bit (pymodbus layout)."""
    regs = []
    for i in range(0, len(bits), 16):
        word = 0
        for j, bit in enumerate(bits[i : i + 16]):
            if bit:
                word |= 1 << j
        regs.append(word)
    return regs


def _make_unsupported_pdu(fc: int) -> type[ModbusPDU]:
    """A request class that answers ILLEGAL FUNCTION (01) for function code fc."""

    async def datastore_update(self, context, device_id):  # noqa: ARG001
        return ExceptionResponse(self.function_code, ExcCodes.ILLEGAL_FUNCTION)

    # decode() is inherited (no-op): the TCP framer delimits frames with the MBAP length.
    return type(
        f"Unsupported{fc}",
        (ModbusPDU,),
        {"function_code": fc, "datastore_update": datastore_update},
    )


# Every function code 1..127 except the 8 supported ones. Overrides pymodbus' built-in
# FC7/8/11/12/17/20/21/22/23/24/43 handlers and the unknown-FC path (see notes in report).
_UNSUPPORTED_PDUS = [_make_unsupported_pdu(fc) for fc in range(1, 128) if fc not in SUPPORTED_FCS]


class _ModbusThread:
    """The pymodbus TCP server in a thread with its own event loop; start()/stop() from sync code."""

    def __init__(self, read: ReadFn, write: WriteFn, host: str = "127.0.0.1", port: int = 502):
        self._read = read
        self._write = write
        self.host = host
        self.requested_port = port
        self.port: int | None = None  # actual bound port after start()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_evt: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._last_rx_fc = 0
        self._bad_coil_value = False

    # ---------------------------------------------------------------- callbacks
    def _read_bits(self, area: str, address: int, count: int) -> list[bool]:
        vals = [bool(v) for v in self._read(area, address, count)]
        if len(vals) != count:
            raise ValueError(f"read({area!r}, {address}, {count}) returned {len(vals)} values")
        return vals

    def _read_regs(self, address: int, count: int, fc: int) -> list[int]:
        """Read holding (fc 3) or input (fc 4) registers, splitting hr/mw for holding."""
        if fc == 4:
            parts = [("ir", address, count)]
        else:
            end = address + count
            parts = []
            if address < MW_BASE:
                parts.append(("hr", address, min(end, MW_BASE) - address))
            if end > MW_BASE:
                lo = max(address, MW_BASE)
                parts.append(("mw", lo - MW_BASE, end - lo))
        out: list[int] = []
        for area, addr, cnt in parts:
            vals = [int(v) for v in self._read(area, addr, cnt)]
            if len(vals) != cnt or any(not 0 <= v <= 0xFFFF for v in vals):
                raise ValueError(f"read({area!r}, {addr}, {cnt}) returned bad data")
            out.extend(vals)
        return out

    def _write_regs(self, address: int, values: list[int]) -> ExcCodes | None:
        end = address + len(values)
        if address < MW_BASE:
            n = min(end, MW_BASE) - address
            if rc := self._write("hr", address, values[:n]):
                return rc
        if end > MW_BASE:
            lo = max(address, MW_BASE)
            return self._write("mw", lo - MW_BASE, values[lo - address :])
        return None

    async def _action(
        self,
        fc: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values,
    ) -> ExcCodes | None:
        """SimDevice action: called by pymodbus after its range check, before it
        builds the response / stores the write into `registers` (its scratch buffer).

        For coil/discrete blocks pymodbus passes: address = requested bit address,
        count = number of 16-bit words spanned, start_address/registers in words.
        """
        try:
            if set_values is not None:  # FC5/FC15/FC6/FC16 write
                if fc == 5 and self._bad_coil_value:
                    return ExcCodes.ILLEGAL_VALUE
                vals = list(set_values)
                if fc in (5, 15):
                    return self._write("coil", address, [bool(v) for v in vals])
                return self._write_regs(address, [int(v) for v in vals])
            if fc in (5, 6):
                # Read-back that pymodbus does to build the FC5/FC6 echo response:
                # the scratch buffer already holds the value just written; don't
                # overwrite it with the (not yet applied) PLC value.
                return None
            if fc in (1, 2):
                area = "coil" if fc == 1 else "di"
                word0 = address // 16
                bits = self._read_bits(area, word0 * 16, count * 16)
                i = word0 - start_address
                registers[i : i + count] = _bits_to_regs(bits)
            else:  # FC3 / FC4
                i = address - start_address
                registers[i : i + count] = self._read_regs(address, count, fc)
            return None
        except Exception:  # pylint: disable=broad-except
            log.exception("modbus callback failed (fc=%s address=%s)", fc, address)
            return ExcCodes.DEVICE_FAILURE

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        """trace_packet hook: fix pymodbus' reply to undecodable requests.

        pymodbus 3.16 answers a request it cannot decode (count out of range, e.g.
        FC1 count=0/2001, FC3 count=126) with function code 0x80 + code 01 instead of
        (fc | 0x80) + code 03. The reply is sent synchronously inside the same receive
        callback, so the last received function code belongs to that request.
        """
        if not sending:
            if len(data) >= 8:
                self._last_rx_fc = data[7]  # MBAP(7 bytes) + function code
            # FC5 allows only 0xFF00 (on) and 0x0000 (off); pymodbus takes any other value as
            # "on": remember it so the action can refuse the write with exception 3.
            self._bad_coil_value = (
                len(data) >= 12 and data[7] == 5 and data[10:12] not in (b"\xff\x00", b"\x00\x00")
            )
        elif len(data) == 9 and data[7] == 0x80 and 0 < self._last_rx_fc < 0x80:
            fc = self._last_rx_fc
            code = ExcCodes.ILLEGAL_VALUE if fc in SUPPORTED_FCS else ExcCodes.ILLEGAL_FUNCTION
            data = data[:7] + bytes((fc | 0x80, code))
        return data

    # ---------------------------------------------------------------- device
    def _build_device(self) -> SimDevice:
        return SimDevice(
            id=0,  # 0 = catch-all: answers every device/unit id (0..255)
            simdata=(
                # BITS: pass a list, NOT count=8192 (pymodbus 3.16 then builds a
                # count*count list while validating: ~0.5 GB RAM and ~1.5 s).
                [SimData(0, values=[False] * N_COILS, datatype=DataType.BITS)],
                [SimData(0, values=[False] * N_DISCRETE, datatype=DataType.BITS)],
                [SimData(0, count=N_HOLDING, values=0, datatype=DataType.REGISTERS)],
                [SimData(0, count=N_INPUT_REGS, values=0, datatype=DataType.REGISTERS)],
            ),
            action=self._action,
        )

    # ---------------------------------------------------------------- thread
    def start(self, timeout: float = 5.0) -> int:
        """Start the server thread; returns the bound port once listening."""
        if self._thread is not None:
            raise RuntimeError("already started")
        self._ready.clear()
        self._error = None
        self._thread = threading.Thread(target=self._thread_main, name="modbus-tcp", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            self.stop()
            raise TimeoutError("modbus server did not start")
        if self._error is not None:
            self._thread.join()
            self._thread = None
            raise RuntimeError(f"modbus server failed to start: {self._error}") from self._error
        return self.port  # type: ignore[return-value]

    def stop(self, timeout: float = 5.0) -> None:
        """Shut the server down and join the thread. Idempotent."""
        thread, loop, evt = self._thread, self._loop, self._stop_evt
        if thread is None:
            return
        if loop is not None and evt is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(evt.set)
            except RuntimeError:  # loop already closed
                pass
        thread.join(timeout)
        if thread.is_alive():
            raise TimeoutError("modbus server thread did not stop")
        self._thread = self._loop = self._stop_evt = None
        self.port = None

    def _thread_main(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # pylint: disable=broad-except
            self._error = exc
        finally:
            self._ready.set()  # unblock start() on any failure

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop_evt = asyncio.Event()
        server = ModbusTcpServer(  # must be created inside the running loop
            self._build_device(),
            address=(self.host, self.requested_port),
            custom_pdu=_UNSUPPORTED_PDUS,
            trace_packet=self._trace_packet,
        )
        # background=True: returns once listening; raises RuntimeError if bind fails
        await server.serve_forever(background=True)
        listener = server.transport  # asyncio.Server
        self.port = listener.sockets[0].getsockname()[1]
        self._ready.set()
        try:
            await self._stop_evt.wait()
        finally:
            await server.shutdown()  # closes listener + all client connections
            await listener.wait_closed()
            for _ in range(3):  # let transports' close callbacks run
                await asyncio.sleep(0)


class ModbusServer:
    """An IoDriver that serves the image over Modbus TCP while the runtime runs."""

    def __init__(self, host: str = "127.0.0.1", port: int = 502, name: str = "modbus") -> None:
        self.name = name
        self.host, self.requested_port = host, port
        self.port: int | None = None
        self._server: _ModbusThread | None = None
        self.counters = {"reads": 0, "writes": 0, "failures": 0}

    def open(self, image: ProcessImage) -> None:
        for area, needed in (("I", 2048), ("Q", 2048), ("M", 2048)):
            if image.sizes[area] < needed:
                raise ConfigError(
                    f"ModbusServer needs at least {needed} bytes of area {area}, image has {image.sizes[area]}"
                )
        self._image = image
        self._words = {
            "ir": image.inputs.view("<u2"),
            "hr": image.published_outputs.view("<u2"),
            "mw": image.markers.view("<u2"),
        }
        self._bits = {"coil": image.published_outputs.bytes, "di": image.inputs.bytes}
        server = _ModbusThread(self._read, self._write, self.host, self.requested_port)
        try:
            self.port = server.start()
        except (RuntimeError, TimeoutError, OSError) as exc:
            raise ConfigError(
                f"Modbus server on {self.host}:{self.requested_port}: {exc}"
            ) from None
        self._server = server

    def close(self) -> None:
        if self._server is not None:
            self._server.stop()
            self._server = None
            self.port = None

    def read_inputs(self, image: ProcessImage, now_ns: int) -> None:
        pass  # requests are served by the server thread; writes arrive via the quiet point

    def write_outputs(self, image: ProcessImage, now_ns: int) -> None:
        pass

    def stats(self) -> dict[str, object]:
        return {**self.counters, "address": f"{self.host}:{self.port}"}

    # ----- called in the server thread -----------------------------------------------
    def _read(self, area: str, address: int, count: int) -> list:
        self.counters["reads"] += 1
        with self._image._lock:  # the same lock that guards copy-in and copy-out
            if area in self._bits:
                raw = self._bits[area]
                return [
                    bool((int(raw[(a >> 3)]) >> (a & 7)) & 1)
                    for a in range(address, address + count)
                ]
            return self._words[area][address : address + count].tolist()

    def _write(self, area: str, address: int, values: list) -> ExcCodes | None:
        self.counters["writes"] += 1
        if area == "coil":
            refs = {f"%QX{a >> 3}.{a & 7}": bool(v) for a, v in enumerate(values, start=address)}
        else:
            prefix = "%QW" if area == "hr" else "%MW"
            refs = {f"{prefix}{a}": int(v) for a, v in enumerate(values, start=address)}
        try:
            self._image.write_many(refs)  # applied together at the next quiet point
        except PlcError:
            self.counters["failures"] += 1
            return ExcCodes.ILLEGAL_VALUE
        return None

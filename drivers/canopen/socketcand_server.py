"""A python-can bus that is a small socketcand server on 127.0.0.1: the transport of the simulated
CANopen drive in its own process (``hil drive-sim``). Every other process reaches the drive with
python-can's own socketcand interface; nothing leaves the machine.

No thread of its own: :meth:`SocketcandServerBus.recv` (the drive's thread) accepts, answers the
handshake and parses the frames; :meth:`SocketcandServerBus.send` writes to every client. A
malformed command is dropped, as a bus drops a bad frame, and no client can grow a buffer without
limit (``MAX_COMMAND``).
"""
from __future__ import annotations

import select
import socket
import threading
import time
from collections import deque

import can

__all__ = ["SocketcandServerBus", "LOOPBACK"]

# -- the separate-process transport: a socketcand-protocol server on the loopback address ------------
LOOPBACK = ("127.0.0.1", "localhost", "::1")
JOIN_GRACE = 0.05        # s after a client's "< ok >" to raw mode before frames reach it (see _command)


class SocketcandServerBus(can.BusABC):
    """A python-can bus that *is* a small socketcand server (raw mode) on 127.0.0.1: the simulated
    drive uses it as its bus, and every other process reaches the drive with python-can's own
    socketcand interface (``interface="socketcand", host="127.0.0.1", port=..., channel=...``).
    Frames a client sends go to the drive and to the other clients, as on one CAN bus. Only the
    loopback address is served: nothing leaves the machine.

    No thread of its own: :meth:`recv` (the drive's thread) waits in one ``select`` on the
    listening socket and the clients, accepts, answers the handshake and parses the frames
    there, so that a SYNC reaches the drive with no hand-over between threads. :meth:`send`
    writes to every client at once (a lock keeps frames whole when a fault timer sends too)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 29536, channel: str = "can0", **kwargs):
        if host not in LOOPBACK:
            raise ValueError(f"the simulated drive serves 127.0.0.1 only, not {host!r}")
        self._pending: deque = deque()
        self._conns: dict = {}                 # socket -> its unparsed text
        self._clients: list = []               # sockets in raw mode: they get every frame
        self._joins: dict = {}                 # a client just in raw mode -> when frames start to reach it
        self._clients_lock = threading.Lock()
        self._held: list | None = None         # frames held back by hold() until release()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.bind(("127.0.0.1", int(port)))
        self._sock.listen(4)
        self.port = self._sock.getsockname()[1]
        self.channel = channel
        self.channel_info = f"socketcand server {channel}@127.0.0.1:{self.port}"
        self._t0 = time.time()
        self._closed = False
        super().__init__(channel=channel, **kwargs)

    def _accept(self) -> None:
        try:
            conn, _ = self._sock.accept()
        except OSError:
            return
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            conn.sendall(b"< hi >")
        except OSError:
            conn.close()
            return
        self._conns[conn] = ""

    def _drop(self, conn) -> None:
        self._conns.pop(conn, None)
        with self._clients_lock:
            if conn in self._clients:
                self._clients.remove(conn)
            self._joins.pop(conn, None)
        conn.close()

    # the longest command a client may send (a "< send 1FFFFFFF 8 FF FF FF FF FF FF FF FF >" is 46
    # characters): input beyond it without a closing ">" is dropped, so a client cannot grow the
    # buffer without limit, and each received chunk is scanned once
    MAX_COMMAND = 256

    def _read(self, conn) -> None:
        """What one client sent: the handshake (open, rawmode) and its frames; a malformed command
        is ignored (the client stays connected, as on a bus where a bad frame is dropped)."""
        try:
            data = conn.recv(4096)
        except OSError:
            data = b""
        if not data:
            self._drop(conn)
            return
        buf = self._conns[conn] + data.decode("ascii", "replace")
        pos = 0
        try:
            while True:
                end = buf.find(">", pos)
                if end < 0:
                    break
                start = buf.find("<", pos, end)
                body, pos = (buf[start + 1:end] if start >= 0 else ""), end + 1
                self._command(conn, body.split(), conn in self._clients)
        except OSError:
            self._drop(conn)
            return
        buf = buf[pos:]
        if len(buf) > self.MAX_COMMAND:          # no ">" in sight: not a command, drop it
            start = buf.rfind("<")
            buf = buf[start:] if 0 <= start and len(buf) - start <= self.MAX_COMMAND else ""
        self._conns[conn] = buf

    def _command(self, conn, cmd, ready: bool) -> bool:
        """One socketcand command of a client; a malformed one is ignored (the client stays
        connected, as on a bus where a bad frame is dropped). Returns whether it is in raw mode."""
        if not cmd:
            return ready
        if cmd[0] == "open":
            conn.sendall(b"< ok >")
        elif cmd[0] == "rawmode":
            conn.sendall(b"< ok >")
            with self._clients_lock:
                if conn not in self._clients:
                    self._clients.append(conn)
                    # python-can's client reads the "< ok >" of its handshake with one recv and wants
                    # it alone: a heartbeat written right after it, in the same segment, failed its
                    # connect ('hil status' now and then). Frames reach a new client after a moment,
                    # or from its first frame on, as a node joining a bus misses the frames before it
                    # is on it
                    self._joins[conn] = time.monotonic() + JOIN_GRACE
            return True
        elif cmd[0] == "send" and ready and len(cmd) >= 3:
            if self._joins:             # it sends: its handshake is behind it, the answers must reach it
                with self._clients_lock:
                    self._joins.pop(conn, None)
            try:
                can_id, n = int(cmd[1], 16), int(cmd[2], 16)
                if not (0 <= can_id <= 0x1FFFFFFF and 0 <= n <= 8 and len(cmd) == 3 + n):
                    return ready
                payload = bytes(int(b, 16) for b in cmd[3:3 + n])
            except ValueError:          # not hexadecimal, or a byte beyond 0xFF
                return ready
            msg = can.Message(arbitration_id=can_id, data=payload, is_extended_id=len(cmd[1]) > 3,
                              timestamp=time.time(), is_rx=True, channel=self.channel)
            self._pending.append(msg)
            self._broadcast(msg, skip=conn)
        return ready

    def _broadcast(self, msg, skip=None):
        cid = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
        line = f"< frame {cid} {time.time() - self._t0:.6f} {bytes(msg.data).hex().upper()} >".encode()
        with self._clients_lock:
            if self._held is not None and skip is None:
                self._held.append(line)
                return
            self._write(line, skip)

    def _write(self, data: bytes, skip=None) -> None:
        if self._joins:
            now = time.monotonic()
            for c in [c for c, t in self._joins.items() if t <= now]:
                del self._joins[c]
        for c in self._clients:
            if c is not skip and c not in self._joins:
                try:
                    c.sendall(data)
                except OSError:
                    pass

    def send(self, msg, timeout=None):
        self._broadcast(msg)

    def hold(self) -> None:
        """From now on the frames sent are held until :meth:`release`, which writes them to each
        client at once: the drive's whole answer to a SYNC in one TCP segment (one wake-up of the
        host, as the frames of one answer follow each other on a CAN bus)."""
        with self._clients_lock:
            self._held = []

    def release(self) -> None:
        with self._clients_lock:
            held, self._held = self._held, None
            if held:
                self._write(b"".join(held))

    def _recv_internal(self, timeout):
        if self._pending:
            return self._pending.popleft(), False
        t_end = None if timeout is None else time.perf_counter() + timeout
        while not self._closed:
            left = None if t_end is None else max(0.0, t_end - time.perf_counter())
            try:
                ready, _, _ = select.select([self._sock, *self._conns], [], [], left)
            except (OSError, ValueError):         # closed meanwhile
                break
            for s in ready:
                if s is self._sock:
                    self._accept()
                elif s in self._conns:
                    self._read(s)
            if self._pending:
                return self._pending.popleft(), False
            if t_end is not None and time.perf_counter() >= t_end:
                break
        return None, False

    def shutdown(self):
        self._closed = True
        try:
            self._sock.close()
        except OSError:
            pass
        for c in list(self._conns):
            try:
                c.close()
            except OSError:
                pass
        self._conns = {}
        with self._clients_lock:
            self._clients = []
            self._joins = {}
        super().shutdown()

"""The ``[serial]`` section's keys (:data:`SECTION`, :func:`field`), beside the backend that reads
them (:mod:`drivers.serial.backend`). ``hil.config`` lists the section with the others and
validates it; the reference in the docs is generated from this table. A light module: the config
loader imports it, not the backend."""
from __future__ import annotations

from drivers.schema import Field

__all__ = ["SECTION", "field"]

# The [serial] section (drivers.serial.backend reads it): the fixed keys; serial.commands.<op>
# and serial.replies.<op> are one per operation of the command set
SECTION = {
    "serial.port": Field("str", "serial port (/dev/ttyUSB0, COM3, /dev/pts/N of hil serial-sim, or a pyserial URL)",
                         default=""),
    "serial.baudrate": Field("int", "baud rate, one of the standard rates (50 ... 4000000)", default=115200,
                             positive=True),
    "serial.parity": Field("str", "parity", default="N", choices=("N", "E", "O")),
    "serial.stopbits": Field("int", "stop bits", default=1, nonnegative=True),
    "serial.mode": Field("str", "position: the drive closes both loops (set_position); velocity: the host closes "
                         "the position loop (set_speed)", default="position", choices=("position", "velocity")),
    "serial.cycle_time": Field("time", "exchange period; default control.position_period", default=None,
                               positive=True),
    "serial.timeout": Field("time", "reply timeout of one attempt in the cycle", default=None, positive=True),
    "serial.retries": Field("int", "retries of a cyclic transaction (within serial.budget)", default=2,
                            nonnegative=True),
    "serial.budget": Field("time", "time budget of one cyclic transaction; default half the cycle", default=None,
                           positive=True),
    "serial.setup_timeout": Field("time", "reply timeout of open/enable/disable commands", default=None,
                                  positive=True),
    "serial.watchdog": Field("time", "drive watchdog armed at open (0: none)", default=None, nonnegative=True),
    "serial.line_ending": Field("str", "line ending of commands and replies (\\r, \\n, \\r\\n, CR, LF, CRLF)",
                                default="\r"),
    "serial.checksum": Field("str", "line checksum", default="none", choices=("none", "sum8", "xor8")),
    "serial.checksum_separator": Field("str", "character before the checksum's two hex digits", default="*"),
    "serial.max_reply": Field("int", "longest reply line accepted (bytes)", default=128, nonnegative=True,
                              maximum=4096),
    "serial.scale_position": Field("dimensionless", "drive position counts per metre (load side)", default=None,
                                   positive=True),
    "serial.scale_speed": Field("dimensionless", "velocity mode: drive speed units per controller speed unit "
                                "(rad/s of the motor, or m/s)", default=None, positive=True),
    "serial.scale_output": Field("dimensionless", "drive torque units per N*m (or per V)", default=None,
                                 positive=True),
}


def field(key: str) -> Field | None:
    """Fields of the ``[serial]`` keys: the fixed ones, and a command template and a reply pattern
    per operation of the command set."""
    if key in SECTION:
        return SECTION[key]
    parts = key.split(".")
    if len(parts) == 3 and parts[1] == "commands":
        return Field("str", f"template of the {parts[2]} command")
    if len(parts) == 3 and parts[1] == "replies":
        return Field("str", f"regular expression of the reply to {parts[2]}")
    return None

"""The ``[canopen]`` section's keys (:data:`SECTION`), beside the backend that reads them
(:mod:`drivers.canopen.section` reads them once into its settings; the simulated drive reads them
too). ``hil.config`` lists the section with the others and validates it; the reference in the docs
is generated from this table. A light module: the config loader imports it, not the backend."""
from __future__ import annotations

from drivers.schema import Field

__all__ = ["SECTION"]

# The [canopen] section (drivers.canopen.section reads it into the backend's settings; the
# simulated drive reads it too)
SECTION = {
    "canopen.interface": Field("str", "python-can interface (socketcan, pcan, kvaser, slcan, socketcand, virtual...)",
                               default="virtual"),
    "canopen.channel": Field("str", "python-can channel (can0, /dev/ttyACM0, a virtual channel name...)",
                             default="hil"),
    "canopen.bitrate": Field("int", "CAN bit rate (bit/s)", default=1000000, nonnegative=True),
    "canopen.host": Field("str", "socketcand server address (127.0.0.1 only for the simulated drive)",
                          default="127.0.0.1"),
    "canopen.port": Field("int", "socketcand server port", default=29536, nonnegative=True),
    "canopen.node_id": Field("int", "the drive's node id (1..127)", default=1, positive=True, maximum=127),
    "canopen.host_node_id": Field("int", "the node id of the host's heartbeat (1..127)", default=127, positive=True,
                                  maximum=127),
    "canopen.eds": Field("str", "object dictionary of the drive (EDS); default drivers/canopen/eds/cia402_generic.eds",
                         default=""),
    "canopen.mode": Field("str", "mode of operation: csp (the drive closes both loops), csv (velocity), cst "
                          "(torque: the host closes both)", default="csp", choices=("csp", "csv", "cst")),
    "canopen.counts_per_rev": Field("int", "motor encoder counts per motor revolution (0x608F)", default=1048576,
                                    positive=True),
    "canopen.gear_motor_revs": Field("int", "gear ratio: motor revolutions (0x6091.1)", default=1, positive=True),
    "canopen.gear_shaft_revs": Field("int", "gear ratio: screw revolutions (0x6091.2)", default=1, positive=True),
    "canopen.rated_torque": Field("torque", "motor rated torque (0x6076); torques go in per mille of it",
                                  default=10.0, positive=True),
    "canopen.tip_sensor": Field("bool", "the drive sends a tool-tip position 0x60E4.2 (a second encoder input)",
                                default=True),
    "canopen.tip_node_id": Field("int", "node id of a separate tool-tip sensor (CiA 406-like encoder, position "
                                 "0x6004 in TPDO1 on every SYNC); 0: none (the tip is the drive's 0x60E4.2 "
                                 "where canopen.tip_sensor, else not measured)", default=0, nonnegative=True,
                                 maximum=127),
    "canopen.tip_eds": Field("str", "object dictionary of the tip sensor node; default "
                             "drivers/canopen/eds/tip_encoder_cia406.eds", default=""),
    "canopen.heartbeat": Field("time", "drive's heartbeat producer time (0x1017)", default=0.1, positive=True),
    "canopen.heartbeat_timeout": Field("time", "host: the drive's heartbeat is lost after this", default=0.35,
                                       positive=True),
    "canopen.host_heartbeat": Field("time", "host's heartbeat period", default=0.1, positive=True),
    "canopen.drive_heartbeat_timeout": Field("time", "drive: the host's heartbeat is lost after this (0x1016)",
                                             default=0.35, positive=True),
    "canopen.abort_option": Field("int", "0x6007, the drive's action when the host's heartbeat or SYNC is lost: "
                                  "0 none, 1 fault, 2 disable voltage, 3 quick stop", default=3, nonnegative=True,
                                  maximum=3),
    "canopen.sync_timeout": Field("time", "drive: the SYNC is lost after this long without one (SYNC consumer: "
                                  "0x1006 x the loss limit 0x2003 in cycles, rounded up); then 0x6007 acts; 0: off",
                                  default=0.1, nonnegative=True),
    "canopen.quick_stop_deceleration": Field("acceleration", "drive: quick-stop deceleration (0x6085); default: "
                                             "what the drive derives (the simulated drive: 80 % of what "
                                             "the torque limit gives the axis)", default=None, positive=True),
    "canopen.following_error_window": Field("length", "drive-side following-error window (0x6065) on the motor "
                                            "position; default 1.5 x limits.following_error_table", default=None,
                                            positive=True),
    "canopen.following_error_timeout": Field("time", "drive-side following-error time out (0x6066)",
                                             default=0.01, nonnegative=True),
    "canopen.pdo_timeout": Field("time", "lockstep: how long the SDO barrier after a SYNC may take before the "
                                 "drive counts as gone (a loaded machine: generous)", default=5.0, positive=True),
    "canopen.pdo_miss_limit": Field("int", "consecutive cycles without TPDO before 'lost communication'",
                                    default=2, positive=True),
    "canopen.lockstep": Field("bool", "drive time advances with SYNC only (a simulated drive in this process)",
                              default=False),
    "canopen.switch_interval": Field("time", "real-time runs: the interpreter's thread switch interval at most this "
                                     "(process-wide; Python's default 5 ms delays the receive threads)",
                                     default=1e-4, positive=True),
    "canopen.connect_timeout": Field("time", "socketcand: how long the server may take to accept and greet",
                                     default=2.0, positive=True),
    "canopen.sdo_timeout": Field("time", "SDO response timeout", default=0.5, positive=True),
    "canopen.stop_timeout": Field("time", "how long the host keeps the SYNC going while the drive finishes a "
                                  "quick stop", default=2.0, positive=True),
}

"""CiA 402 (IEC 61800-7-201) device control written as data: the states and how the statusword
shows them, the controlword commands and how a drive recognises them, the transitions of the
power state machine, the host's way up to Operation Enabled, and the emergency (EMCY) error
codes and how they read.

Both sides read these tables: the host backend (drivers.canopen) to drive a real or simulated
drive up and down, the simulated drive (drivers.canopen.drive_sim) to answer. They agree with
``canopen.profiles.p402.State402`` (checked in tests/test_canopen.py).
"""
from __future__ import annotations

__all__ = ["STATES", "STATUSWORD", "COMMANDS", "COMMAND_RECOGNITION", "TRANSITIONS", "NEXT_TO_ENABLE",
           "MODES", "MODE_CLOSES", "HOMING_MODE", "state_from_statusword", "command_from_controlword", "next_state",
           "statusword_for", "SW_BITS", "CW_BITS", "EMCY_CODES", "emcy_text"]

# --- states and the statusword (mask, value) -----------------------------------------------------
STATUSWORD = {
    "NOT READY TO SWITCH ON": (0x4F, 0x00),
    "SWITCH ON DISABLED": (0x4F, 0x40),
    "READY TO SWITCH ON": (0x6F, 0x21),
    "SWITCHED ON": (0x6F, 0x23),
    "OPERATION ENABLED": (0x6F, 0x27),
    "QUICK STOP ACTIVE": (0x6F, 0x07),
    "FAULT REACTION ACTIVE": (0x4F, 0x0F),
    "FAULT": (0x4F, 0x08),
}
STATES = tuple(STATUSWORD)

SW_BITS = {"ready_to_switch_on": 0, "switched_on": 1, "operation_enabled": 2, "fault": 3, "voltage_enabled": 4,
           "quick_stop": 5, "switch_on_disabled": 6, "warning": 7, "remote": 9, "target_reached": 10,
           "internal_limit": 11, "setpoint_acknowledge": 12, "following_error": 13}
CW_BITS = {"switch_on": 0, "enable_voltage": 1, "quick_stop": 2, "enable_operation": 3, "fault_reset": 7,
           "halt": 8}

# --- controlword commands: the value the host sends, and (mask, value) the drive recognises ------
COMMANDS = {
    "SHUTDOWN": 0x06,
    "SWITCH ON": 0x07,
    "DISABLE VOLTAGE": 0x00,
    "QUICK STOP": 0x02,
    "DISABLE OPERATION": 0x07,
    "ENABLE OPERATION": 0x0F,
    "FAULT RESET": 0x80,
}
# checked in this order (the first match wins); FAULT RESET acts on the rising edge of bit 7
COMMAND_RECOGNITION = (
    ("FAULT RESET", 0x80, 0x80),
    ("DISABLE VOLTAGE", 0x82, 0x00),
    ("QUICK STOP", 0x86, 0x02),
    ("SHUTDOWN", 0x87, 0x06),
    ("SWITCH ON", 0x8F, 0x07),          # DISABLE OPERATION from OPERATION ENABLED
    ("ENABLE OPERATION", 0x8F, 0x0F),
)

# --- transitions: (state, command) -> next state (numbers as in CiA 402 Figure "state machine") ---
TRANSITIONS = {
    ("SWITCH ON DISABLED", "SHUTDOWN"): "READY TO SWITCH ON",                 # 2
    ("READY TO SWITCH ON", "SWITCH ON"): "SWITCHED ON",                       # 3
    ("SWITCHED ON", "ENABLE OPERATION"): "OPERATION ENABLED",                 # 4
    ("OPERATION ENABLED", "SWITCH ON"): "SWITCHED ON",                        # 5 (disable operation)
    ("SWITCHED ON", "SHUTDOWN"): "READY TO SWITCH ON",                        # 6
    ("READY TO SWITCH ON", "DISABLE VOLTAGE"): "SWITCH ON DISABLED",          # 7
    ("READY TO SWITCH ON", "QUICK STOP"): "SWITCH ON DISABLED",               # 7
    ("OPERATION ENABLED", "SHUTDOWN"): "READY TO SWITCH ON",                  # 8
    ("OPERATION ENABLED", "DISABLE VOLTAGE"): "SWITCH ON DISABLED",           # 9
    ("SWITCHED ON", "DISABLE VOLTAGE"): "SWITCH ON DISABLED",                 # 10
    ("SWITCHED ON", "QUICK STOP"): "SWITCH ON DISABLED",                      # 10
    ("OPERATION ENABLED", "QUICK STOP"): "QUICK STOP ACTIVE",                 # 11
    ("QUICK STOP ACTIVE", "DISABLE VOLTAGE"): "SWITCH ON DISABLED",           # 12
    ("QUICK STOP ACTIVE", "ENABLE OPERATION"): "OPERATION ENABLED",           # 16
    ("FAULT", "FAULT RESET"): "SWITCH ON DISABLED",                           # 15
}

# the host's next command on the way to OPERATION ENABLED, from each state
NEXT_TO_ENABLE = {
    "NOT READY TO SWITCH ON": None,            # wait: the drive leaves it by itself (transition 1)
    "SWITCH ON DISABLED": "SHUTDOWN",
    "READY TO SWITCH ON": "SWITCH ON",
    "SWITCHED ON": "ENABLE OPERATION",
    "OPERATION ENABLED": None,
    "QUICK STOP ACTIVE": "DISABLE VOLTAGE",    # through SWITCH ON DISABLED: a fresh enable
    "FAULT REACTION ACTIVE": None,             # wait for FAULT
    "FAULT": "FAULT RESET",
}

# --- modes of operation (0x6060) and the loops the drive closes in each ----------------------------
MODES = {"csp": 8, "csv": 9, "cst": 10}
HOMING_MODE = 6                       # homing mode (methods 35/37: the present position is home)
MODE_CLOSES = {"csp": "both", "csv": "velocity", "cst": "none"}


def state_from_statusword(sw: int) -> str:
    for state, (mask, value) in STATUSWORD.items():
        if sw & mask == value:
            return state
    return "NOT READY TO SWITCH ON"


def statusword_for(state: str, extra: int = 0) -> int:
    """The statusword a drive shows in ``state`` (voltage enabled and remote set where they apply)."""
    value = STATUSWORD[state][1]
    if state in ("READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED", "QUICK STOP ACTIVE"):
        value |= 1 << SW_BITS["voltage_enabled"]
    return value | (1 << SW_BITS["remote"]) | extra


def command_from_controlword(cw: int, previous_cw: int = 0) -> str | None:
    """The command a controlword carries (FAULT RESET only on the rising edge of bit 7)."""
    for name, mask, value in COMMAND_RECOGNITION:
        if cw & mask == value:
            if name == "FAULT RESET":
                if previous_cw & 0x80:
                    continue
            return name
    return None


def next_state(state: str, cw: int, previous_cw: int = 0) -> str:
    """The drive side: the state after receiving ``cw`` in ``state`` (unchanged where no transition)."""
    cmd = command_from_controlword(cw, previous_cw)
    if cmd is None:
        return state
    if cmd == "FAULT RESET" and state != "FAULT":
        # bit 7 set outside FAULT: the other bits still command
        cmd = command_from_controlword(cw & ~0x80, 0)
    return TRANSITIONS.get((state, cmd), state)


# --- emergency (EMCY) error codes (CiA 301 / CiA 402): those the simulated drive sends -------------
EMCY_CODES = {
    0x2310: "continuous overcurrent",
    0x3210: "DC link overvoltage",
    0x4310: "drive overtemperature",
    0x7305: "incremental encoder 1 broken",
    0x8130: "life guard / heartbeat error (host heartbeat lost)",
    0x8611: "following error (drive-side window 0x6065)",
    0x8612: "reference limit (software position limit 0x607D)",
    0x8100: "communication error",
}
EMCY_GROUPS = {0x1: "generic", 0x2: "current", 0x3: "voltage", 0x4: "temperature", 0x5: "device hardware",
               0x6: "device software", 0x7: "additional modules", 0x8: "monitoring", 0x9: "external error",
               0xF: "additional functions", 0xFF: "device specific"}


def emcy_text(code: int) -> str:
    """What an EMCY error code (or 0x603F) means: the code's own text, else its group's."""
    if code in EMCY_CODES:
        return EMCY_CODES[code]
    return EMCY_GROUPS.get(code >> 12, "unknown") + " error"

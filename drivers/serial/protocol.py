"""The command set of an ASCII serial drive, described in configuration, and its reply parser.

A command set is data (the ``[serial]`` section of the axis configuration, see
``config/serial_ascii_example.toml`` and the README (Serial drives)):

* ``serial.commands.<op>``: the template of each operation, a Python format string whose fields
  are whole numbers in drive units: ``{position}`` (counts), ``{speed}`` (counts/s),
  ``{output}`` (torque units), ``{ms}`` (watchdog time in milliseconds);
* ``serial.replies.<op>``: a regular expression the whole reply line must match (``fullmatch``);
  named groups carry values: ``echo`` (must equal the value sent, so that a setpoint counts only
  once the drive has confirmed it), ``x_motor``, ``x_table``, ``v_motor``, ``output``, ``fault``
  (0 = no fault), ``name``; ``serial.replies.error`` matches the drive's refusal (``code``);
* ``serial.line_ending``, ``serial.checksum`` (``none`` | ``sum8`` | ``xor8``: two upper-case
  hex digits of the 8-bit sum / xor of the line's bytes, after ``serial.checksum_separator``),
  ``serial.max_reply`` (bytes).

Operations: ``identify``, ``watchdog``, ``clear_fault`` (optional), ``enable``, ``disable``,
``quick_stop``, ``set_position`` (position mode) or ``set_speed`` (velocity mode), ``read``.

:func:`CommandSet.parse` never raises anything but :class:`ReplyError` (and its subclasses), whatever
the bytes; it bounds the line length before any regular expression sees it.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

from drivers.errors import ConfigError

__all__ = ["CommandSet", "ReplyError", "ChecksumError", "GarbledReply", "UnexpectedReply", "DriveRefused",
           "OPERATIONS", "checksum", "FEEDBACK_GROUPS", "UnsafeCommand", "VALUE_FIELD", "template_fields"]

OPERATIONS = ("identify", "watchdog", "clear_fault", "enable", "disable", "quick_stop", "set_position",
              "set_speed", "set_output", "read")
FEEDBACK_GROUPS = ("x_motor", "x_table", "v_motor", "output", "fault")
CHECKSUMS = ("none", "sum8", "xor8")
_INT = re.compile(r"[+-]?[0-9]{1,12}\Z")
# the value each operation carries (its one template field); the others carry none
VALUE_FIELD = {"set_position": "position", "set_speed": "speed", "set_output": "output", "watchdog": "ms"}


# the fields a command template may hold, the format specs they may carry (sign, zero padding,
# width, decimal), and the longest template and reply pattern taken from a configuration
FIELDS = ("position", "speed", "output", "ms")
_SPEC = re.compile(r"[+ -]?0?[0-9]{0,2}d?\Z")
MAX_TEMPLATE = 256
MAX_PATTERN = 512


def _check_template(op: str, tpl, line_ending: bytes = b"\r") -> None:
    """A command template holds only the named fields with a decimal format spec: no attribute
    or index access (``{position.__class__}``, ``{position[0]}``), no conversion (``!r``), no
    nested field; ``str.format`` then cannot reach anything but the integers it is given.

    And it is one command: printable ASCII only. A line ending or any other control character
    inside a template (``"RD\\rPT 50000000"``) would make every use of it send a second, hidden
    command; the fields' decimal specs then cannot put one in either (sign, digits, spaces)."""
    import string
    if not isinstance(tpl, str) or len(tpl) > MAX_TEMPLATE:
        raise ValueError(f"serial.commands.{op}: expected a template of at most {MAX_TEMPLATE} characters")
    if not tpl.strip():
        raise ValueError(f"serial.commands.{op}: empty (a command needs at least one printable character)")
    for i, ch in enumerate(tpl):
        if not " " <= ch <= "~":
            what = "the line ending" if ch.encode("utf-8") in line_ending else \
                ("a control character" if ord(ch) < 0x20 or ord(ch) == 0x7F else "a non-ASCII character")
            raise ValueError(f"serial.commands.{op}: {what} {ch!r} at position {i}: a command is one line of "
                             f"printable ASCII (anything after a line ending would be sent as another command)")
    try:
        parts = list(string.Formatter().parse(tpl))
    except ValueError as exc:
        raise ValueError(f"serial.commands.{op}: not a template ({exc}; write a literal brace as {{{{ or }}}})") from None
    for _, name, spec, conversion in parts:
        if name is None:
            continue
        if name not in FIELDS:
            raise ValueError(f"serial.commands.{op}: unknown field {{{name}}} (known: position, speed, output, "
                             f"ms; no attribute or index access)")
        if conversion is not None or not _SPEC.match(spec or ""):
            raise ValueError(f"serial.commands.{op}: field {{{name}}} with "
                             f"{'!' + conversion if conversion else ':' + spec!s}: only a decimal format spec "
                             f"(sign, zero padding, width, d) is allowed")


def template_fields(tpl: str) -> list[str]:
    """The names of the fields of a (checked) command template, in order."""
    import string
    return [name for _, name, _, _ in string.Formatter().parse(tpl) if name is not None]


class ReplyError(Exception):
    """A reply that cannot be accepted (retry, then fault)."""


class GarbledReply(ReplyError):
    """Not a line of printable ASCII (noise, a partial line, bytes of another baud rate)."""


class ChecksumError(ReplyError):
    """The line's checksum is missing or wrong."""


class UnexpectedReply(ReplyError):
    """A well-formed line that is not the reply to this command (or echoes another value)."""


class DriveRefused(ReplyError):
    """The drive answered with its error reply (``serial.replies.error``)."""

    def __init__(self, msg: str, code: str = ""):
        super().__init__(msg)
        self.code = code


def checksum(kind: str, body: bytes) -> str:
    if kind == "sum8":
        return f"{sum(body) & 0xFF:02X}"
    if kind == "xor8":
        x = 0
        for b in body:
            x ^= b
        return f"{x:02X}"
    return ""


# the line endings a command set may use, as written in TOML or spelled out
_EOL_NAMES = {"CR": "\r", "LF": "\n", "CRLF": "\r\n", "LFCR": "\n\r", "\\r": "\r", "\\n": "\n",
              "\\r\\n": "\r\n", "\\n\\r": "\n\r"}


def _decode_eol(text) -> bytes:
    """``line_ending`` as written in TOML ("\\r"), spelled out ("CR", "LF", "CRLF") or escaped as
    in a TOML literal string ('\\r'); what it must be is :func:`_check_eol`'s."""
    if not isinstance(text, str):
        raise ValueError(f"serial.line_ending: expected a string (\\r, \\n, \\r\\n, CR, LF, CRLF), got {text!r}")
    text = _EOL_NAMES.get(text.upper() if text.isalpha() else text, text)
    try:
        return text.encode("ascii")
    except UnicodeEncodeError:
        raise ValueError(f"serial.line_ending: expected one or two ASCII control characters (\\r, \\n, "
                         f"\\r\\n, CR, LF, CRLF), got {text[:20]!r}") from None


def _check_eol(eol: bytes) -> None:
    """One or two control characters: never empty (a line would never end), never printable (a
    digit or letter in a reply would end the line there, and a command could hold it)."""
    if not eol:
        raise ValueError("serial.line_ending: empty: expected one or two control characters (\\r, \\n, \\r\\n, "
                         "CR, LF, CRLF)")
    if len(eol) > 2 or any(b >= 0x20 for b in eol):
        raise ValueError(f"serial.line_ending: expected one or two control characters (\\r, \\n, \\r\\n, CR, "
                         f"LF, CRLF), got {eol[:20].decode('ascii', 'replace')!r}")


class UnsafeCommand(ValueError):
    """A command that cannot be sent as one line (a value that is no finite whole number, a byte
    that is not printable ASCII): refused before anything is written."""


@dataclass
class CommandSet:
    commands: dict[str, str]
    replies: dict[str, str]
    line_ending: bytes = b"\r"
    checksum: str = "none"
    checksum_separator: str = "*"
    max_reply: int = 128
    _re: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        if self.checksum not in CHECKSUMS:
            raise ValueError(f"serial.checksum: expected one of {', '.join(CHECKSUMS)}, got {self.checksum!r}")
        _check_eol(self.line_ending)
        sep = self.checksum_separator
        if self.checksum != "none" and (not isinstance(sep, str) or len(sep) != 1 or not "!" <= sep <= "~"
                                        or sep.isalnum()):
            raise ValueError(f"serial.checksum_separator: expected one printable character that is no letter or "
                             f"digit (the checksum's hex digits follow it), got {sep!r}")
        if isinstance(self.max_reply, bool) or not isinstance(self.max_reply, int) or not \
                1 <= self.max_reply <= 4096:
            raise ValueError(f"serial.max_reply: expected a whole number of bytes 1..4096, got {self.max_reply!r}")
        for op, tpl in self.commands.items():
            if op not in OPERATIONS:
                raise ValueError(f"serial.commands.{op}: unknown operation (known: {', '.join(OPERATIONS)})")
            _check_template(op, tpl, self.line_ending)
            self._check_fields(op, tpl)
        for op, pat in self.replies.items():
            if op not in OPERATIONS and op != "error":
                raise ValueError(f"serial.replies.{op}: unknown operation (known: {', '.join(OPERATIONS)}, error)")
            if not isinstance(pat, str) or len(pat) > MAX_PATTERN:
                raise ValueError(f"serial.replies.{op}: expected a regular expression of at most {MAX_PATTERN} "
                                 f"characters")
            try:
                self._re[op] = re.compile(pat)
            except (re.error, RecursionError, OverflowError) as exc:
                raise ValueError(f"serial.replies.{op}: not a regular expression ({exc})") from None
        for op, tpl in self.commands.items():
            if op not in self.replies:
                raise ValueError(f"serial.commands.{op} has no serial.replies.{op}: every command must be confirmed")
            if template_fields(tpl) and "echo" not in self._re[op].groupindex:
                raise ValueError(f"serial.replies.{op}: no (?P<echo>...) group: {op} carries a value, and it counts "
                                 f"only once the drive confirms it (e.g. {tpl.split('{')[0]}(?P<echo>-?[0-9]+))")

    @staticmethod
    def _check_fields(op: str, tpl: str) -> None:
        """The one value an operation carries, in its own field; the others carry none."""
        names = template_fields(tpl)
        want = VALUE_FIELD.get(op)
        if want is None and names:
            raise ValueError(f"serial.commands.{op}: {op} carries no value, got the field {{{names[0]}}}")
        if want is not None and names != [want]:
            got = ", ".join("{" + n + "}" for n in names) or "none"
            raise ValueError(f"serial.commands.{op}: expected the one field {{{want}}}, got {got}")

    # -- building ------------------------------------------------------------------------------
    @classmethod
    def from_config(cls, cfg) -> "CommandSet":
        commands = cfg.section("serial.commands") if hasattr(cfg, "section") else cfg.get("commands", {})
        replies = cfg.section("serial.replies") if hasattr(cfg, "section") else cfg.get("replies", {})
        commands = {k: v for k, v in commands.items() if v is not None}
        replies = {k: v for k, v in replies.items() if v is not None}
        try:
            return cls(commands, replies, _decode_eol(cfg.get("serial.line_ending", "\r")),
                       cfg.get("serial.checksum", "none"), cfg.get("serial.checksum_separator", "*"),
                       int(cfg.get("serial.max_reply", 128)))
        except ValueError as exc:        # the message names the key; the error names the file too
            raise ConfigError(f"{getattr(cfg, 'source', '<config>')}: {exc}") from None

    def has(self, op: str) -> bool:
        return op in self.commands

    def groups(self, op: str) -> set[str]:
        """The names of the groups the reply pattern of ``op`` carries."""
        pat = self._re.get(op)
        return set(pat.groupindex) if pat is not None else set()

    def body(self, op: str, **values) -> str:
        """The command's text; a value that is no finite number is refused (:class:`UnsafeCommand`)."""
        ints = {}
        for k, v in values.items():
            try:
                ints[k] = int(v)
            except (TypeError, ValueError, OverflowError):
                raise UnsafeCommand(f"serial {op}: {k} = {v!r} is not a finite number; not sent") from None
        return self.commands[op].format(**ints)

    def frame(self, text: str) -> bytes:
        """A line (command or reply) with its checksum and line ending. Refuses (:class:`UnsafeCommand`)
        any text that is not one line of printable ASCII: no template or value can make one line two."""
        try:
            raw = text.encode("ascii")
        except UnicodeEncodeError:
            raise UnsafeCommand(f"non-ASCII text in a line: {text[:40]!r}; not sent") from None
        if any(b < 0x20 or b > 0x7E for b in raw):
            raise UnsafeCommand(f"control character in a line: {text[:40]!r}; not sent")
        if self.checksum != "none":
            raw += (self.checksum_separator + checksum(self.checksum, raw)).encode("ascii")
        return raw + self.line_ending

    def encode(self, op: str, **values) -> bytes:
        return self.frame(self.body(op, **values))

    # -- parsing -------------------------------------------------------------------------------
    def unframe(self, line: bytes) -> str:
        """The text of one received line (line ending stripped or absent), checksum verified."""
        if line.endswith(self.line_ending):
            line = line[:-len(self.line_ending)]
        if len(line) > self.max_reply:
            raise GarbledReply(f"reply longer than {self.max_reply} bytes")
        if any(b < 0x20 or b > 0x7E for b in line):
            raise GarbledReply(f"non-printable bytes in reply {line[:40]!r}")
        text = line.decode("ascii")
        if self.checksum != "none":
            body, sep, cs = text.rpartition(self.checksum_separator)
            if not sep:
                raise ChecksumError(f"reply without checksum: {text[:40]!r}")
            want = checksum(self.checksum, body.encode("ascii"))
            if cs.upper() != want:
                raise ChecksumError(f"checksum {cs[:8]!r} != {want} in {text[:40]!r}")
            text = body
        return text

    def parse(self, op: str, line: bytes, sent: dict | None = None) -> dict[str, str]:
        """The named groups of the reply to ``op``; ``sent`` holds the values the command carried,
        checked against the reply's ``echo`` group. Raises only :class:`ReplyError`."""
        try:
            text = self.unframe(bytes(line))
        except ReplyError:
            raise
        except Exception as exc:       # never anything else, whatever the bytes
            raise GarbledReply(f"unreadable reply ({type(exc).__name__})") from None
        err = self._re.get("error")
        if err is not None and err.fullmatch(text):
            m = err.fullmatch(text)
            raise DriveRefused(f"drive refused {op}: {text!r}", m.groupdict().get("code") or "")
        pat = self._re.get(op)
        if pat is None:
            raise UnexpectedReply(f"no reply pattern for {op}")
        m = pat.fullmatch(text)
        if m is None:
            raise UnexpectedReply(f"unexpected reply to {op}: {text[:60]!r}")
        groups = {k: v for k, v in m.groupdict().items() if v is not None}
        for k in FEEDBACK_GROUPS + ("echo",):
            if k in groups and not _INT.match(groups[k]):
                raise UnexpectedReply(f"{k} = {groups[k][:20]!r} in the reply to {op} is not a whole number")
        if "echo" in groups and sent:
            value = next(iter(sent.values()))
            if int(groups["echo"]) != int(value):
                raise UnexpectedReply(f"{op}: drive confirmed {groups['echo']} but {int(value)} was sent")
        return groups


# -- a simulated drive's side: commands as patterns, replies rendered from their patterns -------------
def command_pattern(template: str) -> re.Pattern:
    """A command template as a regular expression (the simulated drive recognises commands so)."""
    import string
    out = []
    for literal, name, spec, _ in string.Formatter().parse(template):
        out.append(re.escape(literal))
        if name is not None:
            # a format spec may pad with spaces or zeros and show the sign
            pad = " *" if spec else ""
            out.append(f"{pad}(?P<{name}>[+-]?[0-9]{{1,14}})")
    return re.compile("".join(out))


_GROUP_START = re.compile(r"\(\?P<([A-Za-z_][A-Za-z0-9_]*)>")
_ESCAPED = re.compile(r"\\(.)")


def render_reply(pattern: str, values: dict) -> str:
    """Fill a *simple* reply pattern (literal text and named groups) with ``values``: what a drive
    that speaks the command set sends. Raises ValueError for patterns that are not simple."""
    out, pos = [], 0
    for m in _GROUP_START.finditer(pattern):
        if m.start() < pos:
            continue
        out.append(_literal(pattern[pos:m.start()]))
        depth, i = 1, m.end()
        while i < len(pattern) and depth:
            c = pattern[i]
            if c == "\\":
                i += 2
                continue
            depth += c == "("
            depth -= c == ")"
            i += 1
        name = m.group(1)
        if name not in values:
            raise ValueError(f"no value for group {name!r} of {pattern!r}")
        out.append(str(values[name]))
        pos = i
    out.append(_literal(pattern[pos:]))
    return "".join(out)


def _literal(part: str) -> str:
    plain = _ESCAPED.sub("", part)
    if any(c in plain for c in "()[]{}*+?|^$."):
        raise ValueError(f"reply pattern part {part!r} is not literal text (the simulated drive renders only "
                         "literal text and named groups)")
    return _ESCAPED.sub(lambda m: m.group(1), part)

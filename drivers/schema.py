"""One configuration key's schema (:class:`Field`), the data every section of the configuration
is written in: ``hil.config``'s own sections and the backends' ``[canopen]`` and ``[serial]``,
which live beside the backends that read them (as python-can's interfaces own their arguments).
It sits at the drives' layer so that a backend states its section without importing ``hil``; the
loader, the validation and the docs generator are ``hil.config``'s.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["Field"]


@dataclass(frozen=True)
class Field:
    """One configuration key.

    ``kind`` is a unit kind of :mod:`hil.units`, or ``"str"``, ``"int"``, ``"bool"``,
    ``"floats"`` (a list of plain numbers). It may also be a callable ``kind(values) -> str``
    when the kind depends on another key (torque for a rotary actuator, force for a linear one).
    """
    kind: Any
    doc: str
    default: Any = None
    required: bool = False
    choices: tuple = ()
    positive: bool = False          # strictly > 0
    nonnegative: bool = False       # >= 0
    allow_inf: bool = False         # "inf" accepted (an integral time that switches the integral off)
    maximum: float | None = None    # largest accepted value (SI); every number is also within MAX_MAGNITUDE
    max_items: int = 64             # "floats": the longest list accepted
    minimum: float | None = None    # smallest accepted value other than 0 (SI); a time: at least TIME_RANGE[0]
    max_length: int = 1024          # "str": the longest text accepted (characters; MAX_STRING_CHARS)

    def kind_for(self, values: dict) -> str:
        return self.kind(values) if callable(self.kind) else self.kind

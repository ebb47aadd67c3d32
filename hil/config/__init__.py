"""Axis configuration: TOML files, validated against one schema, addressed by dotted names.

Every parameter has a dotted name (``plant.c2``, ``control.kv``) used to read it, to override it
from the command line (``--set plant.c2=33``) and to re-identify it (``parameter:plant.c2``).
Values are stored in SI; files may write them with units (``"10 mm"``).

The schema is data (:data:`SCHEMA`), so that validation, the documentation in
``config/SCHEMA.md`` and the command line all read the same table. The sections beside it are
listed here (:data:`SECTION_NAMES`), as data of this module: ``[supervisor]``, ``[noise]``,
``[effects.<name>]`` (the effect catalogue's parameters) and the backends' ``[canopen]`` and
``[serial]`` (the backends read them; nothing registers a section when it is imported).

The example configurations of ``config/`` ship in the package (``hil/examples`` in a wheel):
:func:`load` reads one by name (``paper_bench.toml``, or ``config/paper_bench.toml`` as the README
writes it) where no such file is in the working directory.

The package's modules: :mod:`hil.config.schema` (the fields and the conversion of a value),
:mod:`hil.config.loader` (:class:`Config`, :func:`load`, :func:`loads`) and
:mod:`hil.config.docs` (the generated documentation); the names below are the package's.
"""
from __future__ import annotations

from drivers.canopen.schema import SECTION as CANOPEN_SECTION
from drivers.schema import Field
from drivers.serial.schema import SECTION as SERIAL_SECTION
from hil.config.docs import schema_markdown
from hil.config.loader import (
    Config,
    _validate,
    example_names,
    examples_dir,
    load,
    loads,
    parse_assignment,
    shipped_example,
)
from hil.config.schema import (
    _SECTION_KEYS,
    LOOP_PERIOD_RANGE,
    NOISE_KINDS,
    SCHEMA,
    SECTION_NAMES,
    SUPERVISOR_SECTION,
    TIME_RANGE,
    did_you_mean,
    field_for,
    value_range,
)
from hil.errors import ConfigError

__all__ = ["ConfigError", "Field", "Config", "load", "loads", "SCHEMA", "field_for",
           "parse_assignment", "schema_markdown", "examples_dir", "example_names", "shipped_example",
           "did_you_mean", "value_range", "NOISE_KINDS", "SECTION_NAMES", "SUPERVISOR_SECTION",
           "CANOPEN_SECTION", "SERIAL_SECTION", "LOOP_PERIOD_RANGE", "TIME_RANGE", "_SECTION_KEYS", "_validate"]

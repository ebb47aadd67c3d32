"""Hardware-in-the-loop runtime for feed drives of large, compliant machine tools.

Importing the package imports nothing else, so that ``hil --help`` answers at once: ``Config``,
``load``, ``parse`` and the other names below come from their modules on first use.
"""
import importlib

__all__ = ["Config", "ConfigError", "load", "loads", "UnitError", "parse"]
__version__ = "0.1.0"

# public name -> the module that defines it
_LAZY = {"Config": "hil.config", "load": "hil.config", "loads": "hil.config",
         "ConfigError": "hil.errors", "UnitError": "hil.errors", "parse": "hil.units"}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'hil' has no attribute {name!r}")

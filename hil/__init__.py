"""Hardware-in-the-loop runtime for feed drives of large, compliant machine tools."""
from hil.config import Config, ConfigError, load, loads
from hil.units import UnitError, parse

__all__ = ["Config", "ConfigError", "load", "loads", "UnitError", "parse"]
__version__ = "0.1.0"

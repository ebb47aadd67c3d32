"""Hardware-in-the-loop runtime for feed drives of large, compliant machine tools."""
from .config import Config, ConfigError, load, loads
from .units import UnitError, parse

__all__ = ["Config", "ConfigError", "load", "loads", "UnitError", "parse"]
__version__ = "0.1.0"

"""The object dictionaries (EDS files) shipped with the package: a generic CiA 402 drive and a
CiA 406-like linear encoder for the tool tip. Loaded through importlib.resources, so they are
found in an installed wheel as well as in a clone.

:func:`load` reads the one a configuration names (``canopen.eds``, ``canopen.tip_eds``) or the
shipped one; a file that is missing, unreadable or not a dictionary of that kind of device is a
configuration (or installation) mistake, reported as :class:`hil.errors.ConfigError` naming the
key and the configuration file, before anything connects."""
from __future__ import annotations

import configparser
from importlib.resources import files

import canopen

from drivers.errors import ConfigError

__all__ = ["DEFAULT_EDS", "TIP_EDS", "load"]

DEFAULT_EDS = str(files(__name__).joinpath("cia402_generic.eds"))
TIP_EDS = str(files(__name__).joinpath("tip_encoder_cia406.eds"))

# config key -> (the shipped file, an object every such device has, what the device is)
_KINDS = {
    "canopen.eds": (DEFAULT_EDS, 0x6041, "a CiA 402 drive (no statusword 0x6041)"),
    "canopen.tip_eds": (TIP_EDS, 0x6004, "a CiA 406 encoder (no position value 0x6004)"),
}


def load(cfg, key: str, node_id: int, path: str | None = None) -> canopen.ObjectDictionary:
    """The object dictionary of node ``node_id``: the file ``path``, else the one the config key
    ``key`` (``canopen.eds`` or ``canopen.tip_eds``) names, else the shipped one.

    Parameters
    ----------
    cfg : hil.config.Config
        The axis configuration (its ``source`` names the file in the message of an error).
    key : str
        ``"canopen.eds"`` (the drive) or ``"canopen.tip_eds"`` (the tool-tip sensor node).
    node_id : int
        The node id ($NODEID in the file).
    path : str, optional
        A file given in code, before the configuration's.

    Raises
    ------
    hil.errors.ConfigError
        The file is missing, unreadable, not an EDS/DCF, or not the dictionary of that device.
    """
    shipped, needed, kind = _KINDS[key]
    path = path or cfg.get(key) or shipped
    where = f"{cfg.source}: {key}"
    hint = "" if path != shipped else " (the file shipped with the package: reinstall it)"
    try:
        od = canopen.import_od(path, node_id)
    except (OSError, ValueError, KeyError, configparser.Error) as exc:
        why = " ".join(str(exc).split())          # one line (configparser's messages span several)
        raise ConfigError(f"{where}: cannot read the object dictionary {path} ({why}){hint}") from None
    if needed not in od:
        raise ConfigError(f"{where}: {path} is not the object dictionary of {kind}")
    return od

"""The object dictionaries (EDS files) shipped with the package: a generic CiA 402 drive and a
CiA 406-like linear encoder for the tool tip. Loaded through importlib.resources, so they are
found in an installed wheel as well as in a clone."""
from importlib.resources import files

__all__ = ["DEFAULT_EDS", "TIP_EDS"]

DEFAULT_EDS = str(files(__name__).joinpath("cia402_generic.eds"))
TIP_EDS = str(files(__name__).joinpath("tip_encoder_cia406.eds"))

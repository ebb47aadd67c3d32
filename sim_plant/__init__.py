"""The physics of the compliant feed drive: lumped chains, modes, damping, transfer functions,
equivalents from component data, and the physical effects added to the plant."""
from .chain import Chain, StateSpace, zoh

"""The physics of the compliant feed drive: lumped chains, modes, damping, transfer functions,
equivalents from component data, and the physical effects added to the plant."""
from sim_plant.chain import Chain, StateSpace, zoh
from sim_plant.components import Equivalents, equivalents
from sim_plant.damping import c1_c2_from_ratio, c2_from_c1, c_2dof, modal_ratios_3dof, ratios_from_c
from sim_plant.modal import Frequencies3, frequencies_3dof, modal_matrix_2dof, modal_matrix_3dof, omega_2dof
from sim_plant.transfer import (
           TransferFunction,
           chain_tfs,
           drive_side,
           freqresp,
           table1_2dof,
           table1_3dof,
           to_control,
)

__all__ = ["Chain", "StateSpace", "zoh", "Frequencies3", "frequencies_3dof", "modal_matrix_2dof", "modal_matrix_3dof",
           "omega_2dof", "c1_c2_from_ratio", "c2_from_c1", "c_2dof", "modal_ratios_3dof", "ratios_from_c",
           "TransferFunction", "chain_tfs", "drive_side", "freqresp", "table1_2dof", "table1_3dof", "to_control",
           "Equivalents", "equivalents"]

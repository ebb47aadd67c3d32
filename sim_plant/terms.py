"""The codes of the plant's effect terms and the layout of each code's row: what an effect writes
into ``Plant.effects`` (a code and up to :data:`N_EFFECT_PARAMS` numbers), what the compiled loops
of :mod:`sim_plant.kernel` act on.

Plain numbers, apart from the kernel, so that the effects write their rows without importing numba
(0.12 s of ``hil model``, which builds a plant and never simulates it). The kernel's functions take
these values as constants when they are compiled: this file is hashed with the inlined sources
(``kernel.INLINED_SOURCES``), and a code changed here compiles the kernel and its callers anew.
"""
from __future__ import annotations

__all__ = ["N_EFFECT_PARAMS", "CONSTANT_FORCE", "BACKLASH", "PITCH_ERROR", "TORQUE_RIPPLE", "VISCOUS_ASYMMETRIC",
           "TIME_DELAY", "FEEDBACK_DELAY", "STIFFNESS_ALONG_TRAVEL", "LEAD_ERROR_LINEAR", "FORCE_ALONG_TRAVEL",
           "ENCODER_ERROR", "MOTOR_ENCODER", "TABLE_ENCODER", "LOAD_FRICTION"]

N_EFFECT_PARAMS = 8

# effect term codes
CONSTANT_FORCE = 1       # [mass, force N]
BACKLASH = 2             # [link i (between mass i and i+1), half gap m, stiffness N/m, damping N s/m]: dead zone in link i
PITCH_ERROR = 3          # [link, amplitude m, period m, phase rad, stiffness N/m]: lead error x1 -> nut
TORQUE_RIPPLE = 4        # [amplitude N, period m (of x1), phase rad]: cogging on mass 1
VISCOUS_ASYMMETRIC = 5   # [mass, extra damping for v>0 N s/m, extra for v<0 N s/m]
TIME_DELAY = 6           # [delay s]: the command reaches the motor late (drivers.control.loop_terms), no force here
FEEDBACK_DELAY = 7       # [delay s]: the position loop's feedback is late (drivers.control.loop_terms), no force here
# [link, its stiffness in the chain N/m, x_start m, x_end m, compliance at x_start, midway, at x_end m/N]:
# the link's stiffness as a function of the position of mass link+1 (the nut), kernel.link_compliance()
STIFFNESS_ALONG_TRAVEL = 8
LEAD_ERROR_LINEAR = 9    # [link, strain (lead error per m), x_ref m, stiffness N/m]: x1 -> nut x1 + eps (x1 - x_ref)
FORCE_ALONG_TRAVEL = 10  # [mass, force at x = 0 N, slope N/m]: f0 + f1 x on that mass (a cable carrier)
# [encoder (MOTOR_ENCODER, TABLE_ENCODER), signal period m, amplitude of 1 cycle per period m, its phase rad,
# amplitude of 2 cycles per period m, its phase rad]: the encoder reads x + e(x), no force (kernel.reading())
ENCODER_ERROR = 11
MOTOR_ENCODER = 0        # the motor's encoder (mass 1)
TABLE_ENCODER = 1        # the linear scale on the table (the plant's table mass)
# [link, coefficient (1/eta - 1), stiffness N/m, damping N s/m]: the motor's dry friction level grows by
# coefficient |k (x_i - x_i+1) + c (v_i - v_i+1)|, the link's force (a ball screw's load-dependent friction)
LOAD_FRICTION = 12

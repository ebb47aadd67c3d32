"""Backends behind one small contract (see drivers.base): the simulated plant, CANopen CiA 402, serial."""

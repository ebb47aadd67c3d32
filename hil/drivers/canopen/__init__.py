"""CANopen CiA 402 drives: the backend (``backend``), the protocol's tables as data
(``cia402``), a simulated drive and tool-tip sensor (``drive_sim``) and the shipped object
dictionaries (``eds``). Importing this package imports none of them: the backend registry in
``hil.drivers`` loads the backend when it is chosen."""

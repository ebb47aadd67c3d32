"""CANopen CiA 402 drives: the backend (``backend``, composing ``section``, ``codec``, ``startup``,
``link``, ``tracker``, ``heartbeat`` and ``statemachine``), the protocol's tables as data
(``cia402``), a simulated drive (``drive_sim``, with ``drive_guards``, ``drive_stop``, ``tip_sim``
and ``socketcand_server``), the bus trace (``canlog``) and the shipped object dictionaries
(``eds``). Importing this package imports none of them: the backend registry in ``drivers``
loads the backend when it is chosen."""

"""Servo drives on a serial line: the backend (``backend``), the command set and reply parser as
data (``protocol``), and a simulated drive on a pseudo-terminal (``drive_sim``). Importing this
package imports none of them: the backend registry in ``drivers`` loads the backend when it is
chosen."""

"""The progress callback of the identification (``progress(name)``: one step, a fit, with its
name), and :func:`expect`: telling it how many steps are coming, where the work is learnt as it goes
(each diagnosis of a chain, each combination fitted), so that the command's bar shows a total and
the time left (hil.commands.progress). A plain callable without ``expect`` is fine too."""
from __future__ import annotations

__all__ = ["expect"]


def expect(progress, n: int) -> None:
    """Add ``n`` steps to the total of ``progress``, when it keeps one."""
    if progress is not None and n > 0 and hasattr(progress, "expect"):
        progress.expect(n)

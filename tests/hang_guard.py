"""The hang guard of the fuzzers and the red-team tests: ``with no_hang(seconds):`` ends what takes
longer than ``seconds`` by SIGALRM, with :class:`Hang`. It is a BaseException, so that no ``except
Exception`` of the code under test (pint's, the unit parser's) turns a hang into an ordinary
one-line error and lets it pass as a clean refusal."""
import signal
from contextlib import contextmanager

__all__ = ["Hang", "no_hang"]


class Hang(BaseException):
    """No answer in time."""


@contextmanager
def no_hang(seconds: int):
    """Fail what takes longer than ``seconds`` (a hang), by SIGALRM (the main thread only)."""
    def boom(*_):
        raise Hang(f"no answer within {seconds} s (a hang)")
    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)

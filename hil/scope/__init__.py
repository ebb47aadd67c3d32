"""The live scope of the running axis (issue 27).

* :mod:`hil.scope.ring` (runtime layer): the preallocated ring buffer the cycle writes into;
  imported by :mod:`hil.loop` and :mod:`hil.runtime`, so this package's ``__init__`` imports nothing.
* :mod:`hil.scope.server` (figures layer): the Bokeh server that reads the ring and streams it
  to a page on 127.0.0.1, behind a per-run token.
"""

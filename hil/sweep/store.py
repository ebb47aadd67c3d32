"""The store of finished runs: ``runs.jsonl`` in a sweep's output folder, so a sweep resumes.

One JSON object per line, appended and flushed as each run finishes::

    {"key": RunSpec.key(fingerprint), "spec": dataclasses.asdict(RunSpec), "figures": {...}}

On opening, every readable line is taken (a later line with the same key wins); a line cut by
an interruption is ended with a newline and skipped. A run is reused when its key is in the
store, so runs of another configuration (another fingerprint) or another move never mix in.
This format and the key are read by older and newer versions alike: do not change them.
"""
from __future__ import annotations

import json
import os
from dataclasses import asdict
from pathlib import Path

from hil.errors import UserError
from hil.sweep.run import RunSpec

__all__ = ["ResultStore"]


def _open(path: Path, flags: int, mode: str):
    """``path`` opened with ``O_NOFOLLOW``: a symbolic link planted at the store's name (between
    two runs, or while one runs) is refused, never followed to append to its target."""
    try:
        fd = os.open(path, flags | getattr(os, "O_NOFOLLOW", 0), 0o666)
    except OSError as exc:
        if path.is_symlink():
            raise UserError(f"{path}: is a symbolic link; refusing to write through it") from None
        raise UserError(f"{path}: cannot write ({exc.strerror})") from None
    return os.fdopen(fd, mode)


class ResultStore:
    """Finished runs, one JSON line each, appended as they finish (``runs.jsonl``)."""

    def __init__(self, path: Path | None, resume: bool = True):
        self.path = None if path is None else Path(path)
        self.done: dict[str, dict] = {}
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if self.path.is_symlink():        # as every other output: never written through a planted link
                raise UserError(f"{self.path}: is a symbolic link; refusing to write through it")
            if not resume and self.path.exists():
                self.path.unlink()
            if self.path.exists():
                with _open(self.path, os.O_RDWR, "rb+") as fh:     # end a line cut by an interruption
                    fh.seek(0, os.SEEK_END)
                    if fh.tell() > 0:
                        fh.seek(-1, os.SEEK_END)
                        if fh.read(1) != b"\n":
                            fh.write(b"\n")
                with open(self.path) as fh:
                    for line in fh:
                        try:
                            row = json.loads(line)
                            self.done[row["key"]] = row["figures"]
                        except (ValueError, KeyError, TypeError):
                            continue       # a line cut by an interruption
        self.computed = 0
        self.reused = 0

    def add(self, key: str, figures: dict, spec: RunSpec) -> None:
        self.done[key] = figures
        self.computed += 1
        if self.path is not None:
            with _open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, "a") as fh:
                fh.write(json.dumps({"key": key, "spec": asdict(spec), "figures": figures}) + "\n")
                fh.flush()

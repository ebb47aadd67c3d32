"""Writing outputs safely: never through a planted symbolic link, never over an input, never
half-written.

* :func:`open_new`: a file streamed as it is written (the recorder's record), opened with
  ``O_NOFOLLOW`` (a symbolic link at its name is refused, not followed) and never an input of
  the command.
* :func:`write_atomic`: a whole file at once: written to a fresh temporary file in the target's
  folder (a new, unpredictable name, created exclusively, ``O_EXCL``) and renamed over the target
  (``os.replace``: a link at the target's name is replaced, its destination is not touched), so
  readers see the old file or the new one, never a part.

Both create files with mode 0666 less the umask, as any program that writes a file does
(``tempfile.mkstemp`` would give 0600 whatever the umask: colleagues on a shared lab machine could
not open the reports).

Both refuse a target that is one of the command's ``inputs`` (the same file, by device and
inode: a relative path, a hard link or a link to it included).
"""
from __future__ import annotations

import os
import re
import secrets
from pathlib import Path

from hil.errors import UserError

__all__ = ["open_new", "write_atomic", "refuse_inputs", "save_figure", "safe_name", "confined"]


_UNSAFE = re.compile(r"[^A-Za-z0-9._+-]+")


def safe_name(text: str, max_chars: int = 120) -> str:
    """``text`` as one file name made from data (an axis, a timestamp): every run of characters
    other than letters, digits, ``. _ + -`` is one ``-`` (no separator, no ``..`` left to climb
    out of the folder), at most ``max_chars`` long, never empty, never a leading dot."""
    name = _UNSAFE.sub("-", text).strip("-")[:max_chars].lstrip(".")
    return name or "-"


def confined(folder: str | Path, relative: str | Path) -> Path:
    """``folder / relative``, refused (UserError) where it would lie outside ``folder`` once resolved
    (``..`` or an absolute part in a name read from data, a link to elsewhere)."""
    base = Path(folder).resolve()
    path = (base / relative).resolve()
    if path != base and base not in path.parents:
        how = "is a link to" if (base / relative).is_symlink() else "resolves to"
        raise UserError(f"{relative}: {how} {path}, outside the output folder {folder}; refusing to write there")
    return Path(folder) / relative


def refuse_inputs(path: str | Path, inputs=()) -> None:
    """Raise UserError when ``path`` names one of ``inputs`` (an existing file)."""
    p = Path(path)
    if not p.exists():
        return
    for i in inputs:
        if i is None:
            continue
        try:
            if Path(i).exists() and os.path.samefile(p, i):
                raise UserError(f"{path}: is an input of this command ({i}); refusing to overwrite it, "
                                f"write the output elsewhere")
        except OSError:
            continue


def open_new(path: str | Path, inputs=(), encoding: str = "utf-8", binary: bool = False):
    """A text file opened for writing (truncated), refusing a symbolic link at ``path`` and any of
    ``inputs``; ``binary``: an unbuffered binary file instead (every ``write()`` reaches the
    file at once: what a record killed with its process keeps)."""
    refuse_inputs(path, inputs)
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(path, flags, 0o666)         # the umask takes its bits off
    except OSError as exc:
        if Path(path).is_symlink():
            raise UserError(f"{path}: is a symbolic link; refusing to write through it") from None
        raise UserError(f"{path}: cannot write ({exc.strerror})") from None
    if binary:
        return os.fdopen(fd, "wb", buffering=0)
    return os.fdopen(fd, "w", encoding=encoding, newline="")


def _create_temporary(folder: Path, name: str) -> tuple[int, str]:
    """A new file ``.NAME.<random>.tmp`` in ``folder``, created exclusively (``O_EXCL``: never an
    existing file or a link) with mode 0666 less the umask: what ``tempfile.mkstemp`` does, but
    with the mode every other output gets (mkstemp's is 0600)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = str(folder / f".{name}.{secrets.token_hex(6)}.tmp")
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary name in {folder}")


def write_atomic(path: str | Path, data: str | bytes, inputs=(), encoding: str = "utf-8", sync: bool = True) -> Path:
    """Write ``data`` to ``path`` at once (a temporary file in the same folder, renamed over it).
    ``sync``: on the disk before the rename (False: a file rewritten often, e.g. a running
    record's status, where the page cache is enough: it survives the process, not the power)."""
    path = Path(path)
    refuse_inputs(path, inputs)
    if path.is_dir() and not path.is_symlink():
        raise UserError(f"{path}: is a folder, expected a file name")
    folder = path.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = _create_temporary(folder, path.name)
    except OSError as exc:
        raise UserError(f"{path}: cannot write ({exc.strerror})") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode(encoding) if isinstance(data, str) else data)
            fh.flush()
            if sync:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def save_figure(fig, path: str | Path, inputs=(), **kw) -> Path:
    """A matplotlib figure saved as :func:`write_atomic` writes (the format from the suffix)."""
    import io
    path = Path(path)
    buf = io.BytesIO()
    fig.savefig(buf, format=path.suffix.lstrip(".") or "png", **kw)
    return write_atomic(path, buf.getvalue(), inputs)

"""Writing files safely: atomically (a reader never sees half a file), never replacing a user's
file unless asked, and with the permissions a normally created file would have."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
import threading
from pathlib import Path
from typing import Any

from .errors import FileFormatError, InputError
from .interrupt import stage

_UMASK_LOCK = threading.Lock()


def default_file_mode() -> int:
    """0o666 less the process umask: what ``open(path, "w")`` would give a new file
    (temporary files are created 0o600)."""
    with _UMASK_LOCK:  # os.umask can only be read by setting it
        mask = os.umask(0o022)
        os.umask(mask)
    return 0o666 & ~mask


def check_output_path(path, overwrite: bool) -> Path:
    """Refuse to replace an existing file unless asked; create the folder if it is missing."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{p}: is a folder, not a file")
    if p.exists() and not overwrite:
        raise FileExistsError(errno.EEXIST, f"{p}: exists; pass overwrite=True (CLI: --overwrite) to replace it", str(p))
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():  # create missing folders, as `make demo` users expect of out/x.png
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError):
            raise InputError(f"{p}: {parent} is not a folder") from None
        except OSError as exc:
            raise InputError(f"{p}: cannot create folder {parent}: {exc.strerror}") from None
    return p


def _publish(tmp: str, p: Path, overwrite: bool) -> None:
    os.chmod(tmp, default_file_mode())
    if overwrite:
        os.replace(tmp, p)
        return
    try:  # a hard link fails atomically if the path appeared meanwhile
        os.link(tmp, p)
    except FileExistsError:
        raise FileExistsError(errno.EEXIST, f"{p}: exists; pass overwrite=True (CLI: --overwrite) to replace it", str(p)) from None
    except OSError:  # file systems without hard links: check, then rename
        if p.exists():
            raise FileExistsError(errno.EEXIST, f"{p}: exists; pass overwrite=True (CLI: --overwrite) to replace it", str(p)) from None
        os.replace(tmp, p)


@contextlib.contextmanager
def atomic_output(path, overwrite: bool = False, suffix: str = ".part"):
    """Yield a temporary file name beside ``path``; on success it becomes ``path``.

    On any error (or KeyboardInterrupt, or a cancel: :func:`pointviz.interrupt.stage`
    "writing" is checked just before the rename) the temporary file is removed and ``path``
    untouched.
    """
    p = check_output_path(path, overwrite)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=suffix, dir=p.parent if str(p.parent) else ".")
    os.close(fd)
    try:
        yield tmp
        stage("writing")  # Ctrl-C here (or before) leaves neither the file nor the temporary
        _publish(tmp, p, overwrite)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def atomic_write_bytes(path, data: bytes, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically (fsync'd temporary file, then rename or link)."""
    with atomic_output(path, overwrite) as tmp, open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    return Path(path)


def atomic_write_text(path, text: str, overwrite: bool = False) -> Path:
    """UTF-8 text version of :func:`atomic_write_bytes`."""
    return atomic_write_bytes(path, text.encode("utf-8"), overwrite)


def read_json_file(path: str | os.PathLike) -> Any:
    """Parse a JSON file, raising FileFormatError naming the file when it is missing or invalid."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileFormatError(f"{os.fspath(path)}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FileFormatError(f"{os.fspath(path)}: cannot read: {exc}") from exc
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise FileFormatError(f"{os.fspath(path)}: invalid JSON: {exc}") from exc


def json_text(data) -> str:
    """``data`` as the project's JSON files hold it: indented, NaN refused, newline-terminated."""
    return json.dumps(data, indent=2, allow_nan=False) + "\n"

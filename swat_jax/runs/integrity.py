"""The record of what a checkpoint wrote, kept in its folder and checked before anything reads it.

When a save completes, :func:`write_record` lists every file of the checkpoint's step folder with its
size and SHA-256 in ``RECORD``, written last and atomically. :func:`damage` checks that record before a
checkpoint is read: a folder without one (a save that never finished), a file missing or of another size
(truncated, deleted), or a file whose bytes hash to another digest (changed on disk) is damaged, and
nothing of it is read.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Collection
from pathlib import Path

RECORD = "swat_jax_record.json"
"""The record's file in a checkpoint's step folder."""
RECORD_FORMAT = 1
"""Version of the record's layout, stored in it."""
HASH = "sha256"


def write_record(folder: Path) -> None:
    """Write ``folder``'s RECORD: ``{"format": 1, "files": {relative path: [bytes, sha256]}}`` for every
    file under it, through a temporary file renamed into place (a record is whole or absent)."""
    files = {
        path.relative_to(folder).as_posix(): [path.stat().st_size, _digest(path)]
        for path in sorted(folder.rglob("*"))
        if path.is_file() and path.name != RECORD
    }
    temporary = folder / f".{RECORD}.tmp"
    with temporary.open("w") as file:
        json.dump({"format": RECORD_FORMAT, "files": files}, file)
        file.flush()
        os.fsync(file.fileno())
    temporary.replace(folder / RECORD)


def damage(folder: Path, items: Collection[str] | None = None) -> str | None:
    """Why the checkpoint in ``folder`` cannot be trusted, in a few words, or None if its record checks out.

    Every recorded file must exist with its recorded size. The digests are checked of the files at the top
    of ``folder`` and of those in the folders of ``items`` (Orbax items such as ``actor``; every file when
    None), so reading one small item does not hash the replay buffers.
    """
    try:
        record = json.loads((folder / RECORD).read_text())
        files = record["files"]
    except FileNotFoundError:
        return (
            f"it has no {RECORD}: its save never finished (or it was written by a swat_jax that did not "
            "record its checkpoints)"
        )
    except (OSError, ValueError, KeyError, TypeError) as error:
        return f"its {RECORD} is unreadable ({error})"
    for name, (size, _) in files.items():
        path = folder / name
        if not path.is_file():
            return f"{name} is missing"
        if (actual := path.stat().st_size) != size:
            return f"{name} has {actual:,} bytes where {size:,} were written"
    for name, (_, digest) in files.items():
        top = name.split("/")[0]
        checked = items is None or "/" not in name or top in items
        if checked and _digest(folder / name) != digest:
            return f"the bytes of {name} changed after it was written"
    return None


def _digest(path: Path) -> str:
    """The hex SHA-256 of the file at ``path``."""
    with path.open("rb") as file:
        return hashlib.file_digest(file, HASH).hexdigest()

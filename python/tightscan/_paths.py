"""Input paths: a file, a directory, a glob, or a list of them, to a list of files."""

from __future__ import annotations

import glob
import os
from pathlib import Path
from typing import Sequence, Union

from .exceptions import DataFileError

PathLike = Union[str, "os.PathLike[str]"]


def expand_paths(source: PathLike | Sequence[PathLike], pattern: str, *, recursive: bool) -> list[str]:
    """Files named by ``source``: a directory gives its files matching ``pattern`` (sorted; in
    sub-directories too when ``recursive``), a glob its matches (sorted), a file itself; a list
    keeps its order. Nothing found, or a path that does not exist: ``DataFileError`` naming it."""
    items = [source] if isinstance(source, (str, os.PathLike)) else list(source)
    files: list[str] = []
    for item in items:
        text = os.fspath(item)
        path = Path(text)
        if path.is_dir():
            matches = path.rglob(pattern) if recursive else path.glob(pattern)
            found = sorted(str(p) for p in matches if p.is_file())
            if not found:
                raise DataFileError(f"no {pattern.lstrip('*')} files in directory {text}", text)
            files.extend(found)
        elif path.is_file():
            files.append(text)
        elif glob.has_magic(text):
            found = sorted(glob.glob(text, recursive=True))
            if not found:
                raise DataFileError(f"no files match {text}", text)
            files.extend(found)
        else:
            raise DataFileError(f"no such file or directory: {text}", text)
    return files

"""Files a scenario names beside it (``[site] stations_geojson``, ``[radio] terrain``): read and decoded,
with the loader's one-line errors."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable


def read_beside(name: str, base_dir: Path | None, where: str, decode: Callable[[str], Any], kind: str,
                expected_file: str, expected_doc: str, error) -> tuple[Path, Any]:
    """``(path, decode(text))`` of the file ``name`` relative to ``base_dir`` (the scenario's folder; None:
    the working directory). A file that cannot be read, or that ``decode`` refuses (``ValueError``, bad UTF-8),
    raises ``error("WHERE: cannot read PATH: why (expected EXPECTED_FILE)")`` or ``error("WHERE: PATH: not KIND
    (why) (expected EXPECTED_DOC)")``."""
    path = Path(name) if base_dir is None or Path(name).is_absolute() else Path(base_dir) / name
    try:
        return path, decode(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise error(f"{where}: cannot read {path}: {e.strerror or e} (expected {expected_file})") from None
    except (UnicodeDecodeError, ValueError) as e:
        raise error(f"{where}: {path}: not {kind} ({e}) (expected {expected_doc})") from None

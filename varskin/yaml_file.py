"""Reading a YAML config file a user wrote: every way it can fail is one ``ConfigError``
naming the file (and the line, for bad YAML). Patch configs and launch files both come in
this way, so they fail alike."""

from __future__ import annotations

from pathlib import Path

import yaml

from varskin.errors import ConfigError


def read_yaml(path: Path, kind: str) -> object:
    """The parsed contents of ``path``; ``kind`` ("a patch config") names it in messages."""
    try:
        text = path.read_text()
    except OSError as e:
        raise ConfigError(f"{path}: cannot read ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: is not a text file ({kind} is YAML)") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{path}{where}: is not valid YAML") from None
